"""Shared fixtures: small configs and terrains that exercise the real code paths quickly."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
import torch
from filelock import FileLock

from epoet.config import compose as compose_config
from epoet.config import load
from epoet.core.algorithm import AXES, SCORE, Family
from epoet.envs.config import AgentConfig
from epoet.registry import algorithm
from epoet.rollout.policy import policy_sizes
from epoet.terrain import Terrain
from epoet.terrain.config import TerrainConfig
from epoet.tracking.store import open_store

if TYPE_CHECKING:
    import mlflow

torch.set_num_threads(1)

# The test files that take longest (their share of `make test`, measured with --durations=0 on 2
# cores), in that order. `make test` gives each worker whole files (--dist loadfile) in collection
# order (--no-loadscope-reorder), so these go first and the short files fill the gaps at the
# end: both workers finish at about the same time.
LONGEST_FIRST = (
    "test_scale_out.py",
    "test_paper_report.py",
    "test_evaluation.py",
    "test_faults.py",
    "test_bad_input.py",
    "test_baselines.py",
    "test_epoet_sac.py",
    "test_checkpoint.py",
    "test_bad_agents.py",
    "test_algorithms.py",
    "test_reference.py",
    "test_authors_files.py",
    "test_render.py",
    "test_epoet.py",
    "test_records.py",
    "test_tracking.py",
    "test_help.py",
    "test_robots.py",
    "test_analysis.py",
    "test_golden.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # A renamed file would silently fall to the end of the order (test_poet.py did).
    missing = [name for name in LONGEST_FIRST if not (Path(__file__).parent / name).exists()]
    assert not missing, f"LONGEST_FIRST names test files that do not exist: {missing}"
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable within a file


# The ES policy's layer sizes of the default config's robot (the hexapod) and hidden layers.
_DEFAULT = load([])
ES_SIZES = policy_sizes(_DEFAULT.agent, _DEFAULT.algo.es.hidden)
OBS_DIM, ACT_DIM = ES_SIZES[0], ES_SIZES[-1]  # the hexapod's observation and action sizes

# ePOET's tiny run (small network and grid, one worker), and the settings that make every step
# of its loop happen within a few iterations: transfers every iteration, reproduction every 2,
# every child passing.
TINY_EPOET = ["budget=smoke", "workers.num=1", "algo.es.hidden=[8]", "terrain.grid=40"]
BUSY_LOOP = [
    "algo.iterations_before_transfer=1",
    "algo.adjust_interval=2",
    "algo.num_children=2",
    "algo.repro_threshold=-100000",
    "algo.mc_lower=-100000",
    "algo.mc_upper=100000",
]

# A baseline's tiny run: 30-step episodes, 60-frame batches, 4 batches, evaluations every 2
# batches, with each algorithm's own small sizes (tiny_baseline); tests/golden.json pins it.
TINY_BASELINE = [
    "budget=smoke",
    "workers.num=1",
    "terrain.grid=40",
    "budget.episode_steps=30",
    "budget.frames=240",
    "budget.eval_every=120",
    "budget.eval_episodes=1",
    "algo.frames_per_batch=60",
    "checkpoint_every=2",
]
TINY_FAMILY = {Family.BASELINE: TINY_BASELINE, Family.OPEN_ENDED: TINY_EPOET}
# Each algorithm's own small sizes on its family's tiny run; an algorithm without an entry runs
# its own sizes there.
TINY_SIZES = {
    "ppo": ["algo.epochs=2", "algo.minibatch=30"],
    "vmpo": ["algo.epochs=2", "algo.minibatch=30"],
    "sac": [
        "algo.hidden=[32,32]",
        "algo.batch_size=32",
        "algo.updates_per_batch=8",
        "algo.init_random_frames=60",
    ],
    "epoet_sac": [
        "algo.frames_per_iteration=40",
        "algo.sac.hidden=[32,32]",
        "algo.sac.batch_size=32",
        "algo.sac.init_random_frames=40",
    ],
}


def tiny_run(algo: str) -> list[str]:
    """The overrides of any registered algorithm's tiny run: its family's, with its sizes."""
    return [f"algo={algo}", *TINY_FAMILY[algorithm(algo).family], *TINY_SIZES.get(algo, [])]


tiny_baseline = tiny_run  # a baseline's tiny run, by the name the baselines' tests use


@pytest.fixture(autouse=True)
def _authors_setting_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    """A command run in-process takes `epoet_3d=` / `source=` into the environment, as a real
    command does for its workers; each test starts from the session's setting again."""
    from epoet.eval.reference.files import ENV

    monkeypatch.setenv(ENV, os.environ.get(ENV, ""))  # restored on teardown; empty: unset


def authors(*parts: str) -> Path:
    """A file of the authors' files' conversion (epoet.eval.reference, made on first use); the
    test is skipped where their files are absent (the tests that need them run in CI, which has
    ../shared/ePOET_3D beside the clone)."""
    from epoet.eval.reference import folder
    from epoet.eval.reference.files import MissingReferenceFiles

    try:
        return folder().joinpath(*parts)
    except MissingReferenceFiles as err:
        pytest.skip(str(err))


@pytest.fixture
def terrain_cfg() -> TerrainConfig:
    return replace(
        load(["budget=paper", "terrain.rendering=clean"]).terrain,
        grid=40,
        size=40.0,
        max_height=0.3,
        bowl_weight=0.3,
    )


@pytest.fixture
def flat() -> Terrain:
    return Terrain(np.zeros((40, 40)), 0.0, 40.0, "bowl", 0)


@pytest.fixture
def short_agent() -> AgentConfig:
    return replace(load(["budget=paper"]).agent, max_episode_steps=60)


def without_evaluation(args: list[str]) -> list[str]:
    """`python -m epoet` arguments with `evaluate=false` among the overrides (Hydra's overrides
    must be one run of arguments: before the first one, after any flags)."""
    at = next((i for i, a in enumerate(args) if "=" in a and not a.startswith("-")), len(args))
    return [*args[:at], "evaluate=false", *args[at:]]


def run_epoet(
    args: list[str], cwd: Path, uri: str, timeout: float = 300, **env: str
) -> subprocess.CompletedProcess:
    """`python -m epoet <args>` without its evaluation, in `cwd`, tracked in the store `uri`."""
    return subprocess.run(
        [sys.executable, "-m", "epoet", *without_evaluation(args)],
        cwd=cwd,
        env={**os.environ, "MLFLOW_TRACKING_URI": uri, **env},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture
def compose():
    """Compose the real Hydra config (as `python -m epoet` would) from overrides; without the
    end-of-run suite evaluation unless a test asks for it (tests/test_evaluation.py checks it),
    so each training test pays for its training only."""

    def compose_training(overrides=(), config_name: str = "config"):
        if config_name == "config" and not any(o.startswith("evaluate=") for o in overrides):
            overrides = [*overrides, "evaluate=false"]
        return compose_config(overrides, config_name)

    return compose_training


@pytest.fixture(scope="session")
def empty_store(tmp_path_factory) -> Path:
    """A new MLflow sqlite store, made once for the whole session by the product's
    `open_store` (the xdist workers share it through a lock): MLflow builds a store by running
    its schema migrations, seconds each time, and the suite's tests start dozens of stores.
    Each test's store is a copy of this file (`new_store`)."""
    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # this session's folder, common to its workers
    db = shared / "empty_mlflow.db"
    with FileLock(str(shared / "empty_mlflow.lock")):
        if not db.exists():
            building = shared / "building_mlflow.db"
            open_store(f"sqlite:///{building}")
            building.rename(db)
    return db


def new_store(empty: Path, folder: Path, name: str = "mlflow.db") -> str:
    """The URI of an empty MLflow store at folder/name: a copy of the session's `empty_store`."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(empty, folder / name)
    return f"sqlite:///{folder / name}"


@pytest.fixture
def store_in_tmp_path(tmp_path, empty_store) -> str:
    """An empty store at tmp_path/mlflow.db, for tests whose subprocesses write there."""
    return new_store(empty_store, tmp_path)


@pytest.fixture
def mlflow_uri(tmp_path, monkeypatch, empty_store) -> str:
    """A private sqlite store for the test (never the project's mlflow.db)."""
    uri = new_store(empty_store, tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return uri


def one_terrain_suite(
    folder: Path,
    episode_steps: int,
    episode_ratio: float,
    *,
    name: str = "bumps",
    heights: np.ndarray | None = None,
    finish_x: float = 6.0,
    max_height: float = 0.2,
) -> Path:
    """A suite folder in the documented format (epoet/eval/suite.py) with one 20 m terrain
    (default: bumps of 0.2 m) and a course from x = -6 m to `finish_x` (default: 12 m) made for
    `episode_steps`-step training episodes."""
    folder.mkdir()
    if heights is None:
        heights = np.random.default_rng(0).uniform(0.0, 1.0, (40, 40))
    np.savez(folder / "heights.npz", **{name: heights})
    (folder / "suite.json").write_text(
        json.dumps(
            {
                "format": "epoet-suite/2",
                "size": 20.0,
                "grid": 40,
                "course": {
                    "start_x": -6.0,
                    "finish_x": finish_x,
                    "half_width": 0.35,
                    "episode_steps": episode_steps,
                    "episode_ratio": episode_ratio,
                },
                "terrains": [{"name": name, "max_height": max_height}],
            }
        )
    )
    return folder


def subset_suite(folder: Path, picks: list[tuple[str, int]], source: str = "shipped") -> Path:
    """A suite folder of the k-th terrain of each (level, k) in `picks` of the suite `source`
    (a name of `SUITES`), in the same format."""
    from epoet.eval.suite import SUITES, load_suite  # imports mujoco: not at collection

    whole, whole_folder = load_suite(source), SUITES[source]()
    names = [[t.name for t in whole.terrains if t.level == level][k] for level, k in picks]
    index = json.loads((whole_folder / "suite.json").read_text())
    index["terrains"] = [e for e in index["terrains"] if e["name"] in names]
    folder.mkdir(parents=True)
    (folder / "suite.json").write_text(json.dumps(index))
    with np.load(whole_folder / "heights.npz") as heights:
        np.savez(folder / "heights.npz", **{name: heights[name] for name in names})
    return folder


def serial_loop(
    algo: Any,
    agent: AgentConfig,
    terrain: TerrainConfig,
    sizes: tuple[int, ...],
    *,
    seed: int,
    n_pairs: int,
    eval_episodes: int = 1,
) -> Any:
    """An ePOET loop on an in-process evaluator, at the paper's score scale: the loop a test
    drives step by step."""
    from epoet.open_ended.loop import Epoet
    from epoet.rollout.backends.serial import SerialEvaluator

    return Epoet(
        algo,
        terrain,
        SerialEvaluator(agent, terrain, batch=8, layer_sizes=sizes),
        seed=seed,
        n_pairs=n_pairs,
        eval_episodes=eval_episodes,
        score_scale=1.0,
    )


def unmet_metrics(client: mlflow.MlflowClient, run_id: str, family: Family) -> list[str]:
    """What the run misses of its family's metrics (`Family.metrics`): each it never logged,
    and each step with a `score` that lacks an axis (a point the learning curves would lose)."""
    logged = client.get_run(run_id).data.metrics
    unmet = [key for key in family.metrics if key not in logged]
    scored = {m.step for m in client.get_metric_history(run_id, SCORE)}
    for axis in AXES:
        have = {m.step for m in client.get_metric_history(run_id, axis)}
        unmet += [f"{axis} at step {step}" for step in sorted(scored - have)]
    return unmet
