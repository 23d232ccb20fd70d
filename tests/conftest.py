"""Shared fixtures: small configs and terrains that exercise the real code paths quickly."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from epoet.config import AgentConfig, TerrainConfig
from epoet.terrain import Terrain

torch.set_num_threads(1)


@pytest.fixture
def terrain_cfg() -> TerrainConfig:
    return TerrainConfig(kind="cppn", grid=40, size=20.0, max_height=0.3, bowl_weight=0.3)


@pytest.fixture
def flat() -> Terrain:
    return Terrain(np.zeros((40, 40)), 0.0, 20.0, "bowl", 0)


@pytest.fixture
def short_agent() -> AgentConfig:
    return AgentConfig(max_episode_steps=60)


CONF_DIR = str(__import__("pathlib").Path(__file__).resolve().parent.parent / "conf")


@pytest.fixture
def compose():
    """Compose the real Hydra config (as `python -m epoet` would) from overrides."""
    from hydra import compose as hydra_compose, initialize_config_dir

    from epoet.config import register_configs

    register_configs()

    def _compose(overrides: list[str]):
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            return hydra_compose(config_name="config", overrides=overrides)
    return _compose


@pytest.fixture
def mlflow_uri(tmp_path, monkeypatch) -> str:
    """A private sqlite store for the test (never the project's mlflow.db)."""
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return uri
