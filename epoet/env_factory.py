"""A robot's terrain env and task configs built from the YAML defaults, for code outside a run:
gymnasium's ids (`epoet/Hexapod-v0`, `epoet/Ant-v0`), notebooks, tests and benches.

They compose conf/ (epoet.config), so they live above it: the env itself (epoet.envs) takes
validated configs and knows nothing of Hydra. `import epoet` registers the ids (epoet/__init__.py)
with this module's `make_terrain_env` as their entry point:

    import gymnasium as gym, epoet
    env = gym.make("epoet/Hexapod-v0", terrain="cppn")
"""

from __future__ import annotations

from dataclasses import asdict
from functools import cache
from typing import Any, cast

import numpy as np
from omegaconf import DictConfig, OmegaConf

from epoet import ENV_IDS
from epoet.config import CONF_DIR, compose
from epoet.envs.config import HEXAPOD, AgentConfig
from epoet.envs.model import Layout, action_to_ctrl, build_model, layout
from epoet.envs.terrain_env import TerrainEnv
from epoet.terrain.config import TerrainConfig

ROBOT_ENV_IDS = ENV_IDS  # registered by `import epoet`
ENV_ID = ENV_IDS[HEXAPOD]


def task_configs(
    agent: Any = None, terrain: Any = None, robot: str = HEXAPOD
) -> tuple[AgentConfig, TerrainConfig]:
    """A robot's task configs for code that builds an env outside a run (gym.make, notebooks,
    tests): dataclasses as they are; dicts or DictConfigs as overrides of the paper budget's
    agent (conf/agent/<robot>.yaml) and of the terrain file their `kind` names (or a kind's
    name), range-checked."""
    if isinstance(agent, AgentConfig) and isinstance(terrain, TerrainConfig):
        return agent, terrain
    terrain = {"kind": terrain} if isinstance(terrain, str) else _plain(terrain)
    kind = terrain.get("kind", "bowl")
    base = compose(
        [
            "budget=paper",
            f"agent={robot}",
            f"terrain={kind}"
            if (CONF_DIR / "terrain" / f"{kind}.yaml").exists()
            else "terrain=bowl",
        ]
    )
    OmegaConf.resolve(base)  # agent.max_episode_steps interpolates the budget's episode length

    def build(value: Any, node: DictConfig, schema: type) -> Any:
        return (
            value
            if isinstance(value, schema)
            else OmegaConf.to_object(OmegaConf.merge(node, _plain(value)))
        )

    return build(agent, base.agent, AgentConfig), build(terrain, base.terrain, TerrainConfig)


def _plain(value: Any) -> dict:
    if value is None:
        return {}
    if isinstance(value, DictConfig):
        return cast(dict, OmegaConf.to_container(value, resolve=True))  # a DictConfig's: a dict
    if isinstance(value, TerrainConfig):  # a dataclass terrain with a dict agent
        return asdict(value)
    return dict(value)


def make_terrain_env(
    agent: Any = None, terrain: Any = None, robot: str = HEXAPOD, **kwargs: Any
) -> TerrainEnv:
    """`gym.make("epoet/Hexapod-v0", agent=..., terrain=...)` (`epoet/Ant-v0`: robot="ant"):
    configs as dataclasses, or as dicts of overrides of the YAML defaults of `robot`
    (`task_configs`); `kwargs` go to the env."""
    return TerrainEnv(*task_configs(agent, terrain, robot), **kwargs)


@cache
def _hexapod_layout() -> Layout:
    return layout(build_model(*task_configs()))


def action_to_targets(action: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The hexapod's position targets of actions (18,) or (B, 18): `action_to_ctrl` of its
    model, for code that drives the hexapod by hand (its tests and benches)."""
    return action_to_ctrl(_hexapod_layout(), action, out)
