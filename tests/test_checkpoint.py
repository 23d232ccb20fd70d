"""Checkpoints: exact round trip, atomic replacement, one-sentence errors for bad files, and
older checkpoints (their configs, their renamed classes and keys) read in today's layout."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
import torch

import epoet.open_ended.pairs
from conftest import tiny_run
from epoet.config import compose, load
from epoet.core.algorithm import Family
from epoet.core.checkpoint import (
    CHECKPOINT_NAME,
    CheckpointError,
    find_checkpoint,
    load_checkpoint,
    save_checkpoint,
)
from epoet.eval.agents import policy_in
from epoet.migration import config_changes
from epoet.registry import algorithm, names
from epoet.run import run
from epoet.tracking import MlflowTracker

ROOT = Path(__file__).resolve().parent.parent


class _Unpicklable:
    """Fails while being pickled, i.e. in the middle of writing the checkpoint."""

    def __reduce__(self):
        raise RuntimeError("boom")


def _state() -> dict:
    rng = np.random.default_rng(7)
    rng.normal(size=3)  # advance so the saved state is not the seed's initial state
    net = torch.nn.Linear(4, 2)
    return {
        "iteration": 12,
        "theta": np.arange(10, dtype=np.float32),
        "pairs": {"0": {"scores": np.ones((2, 3)), "name": "flat"}, "1": [1, 2.5, None]},
        "rng": rng.bit_generator.state,
        "policy": net.state_dict(),
    }


def test_round_trip_restores_arrays_nested_dicts_rng_and_torch(tmp_path):
    state = _state()
    path = tmp_path / "run" / CHECKPOINT_NAME
    save_checkpoint(path, state)
    loaded = load_checkpoint(path)

    assert loaded["iteration"] == 12
    np.testing.assert_array_equal(loaded["theta"], state["theta"])
    assert loaded["theta"].dtype == np.float32
    np.testing.assert_array_equal(loaded["pairs"]["0"]["scores"], np.ones((2, 3)))
    assert loaded["pairs"]["1"] == [1, 2.5, None]
    for key, tensor in state["policy"].items():
        assert torch.equal(loaded["policy"][key], tensor)
    # The restored generator continues exactly where the saved one would.
    original, restored = np.random.default_rng(), np.random.default_rng()
    original.bit_generator.state = state["rng"]
    restored.bit_generator.state = loaded["rng"]
    np.testing.assert_array_equal(original.normal(size=5), restored.normal(size=5))


def test_failed_write_keeps_previous_checkpoint_and_leaves_no_temp_file(tmp_path):
    path = tmp_path / CHECKPOINT_NAME
    save_checkpoint(path, {"iteration": 1})
    before = path.read_bytes()

    with pytest.raises(CheckpointError, match="cannot save checkpoint.*boom"):
        save_checkpoint(path, {"iteration": 2, "bad": _Unpicklable()})

    assert path.read_bytes() == before
    assert load_checkpoint(path) == {"iteration": 1}
    assert [p.name for p in tmp_path.iterdir()] == [CHECKPOINT_NAME]


def test_overwrite_replaces_content(tmp_path):
    path = tmp_path / CHECKPOINT_NAME
    save_checkpoint(path, {"iteration": 1})
    save_checkpoint(path, {"iteration": 2})
    assert load_checkpoint(path) == {"iteration": 2}


def test_run_folder_resolves_to_its_checkpoint(tmp_path):
    save_checkpoint(tmp_path / CHECKPOINT_NAME, {"iteration": 3})
    assert find_checkpoint(tmp_path) == tmp_path / CHECKPOINT_NAME
    assert load_checkpoint(tmp_path) == {"iteration": 3}


def test_missing_file_and_empty_run_folder_are_named(tmp_path):
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.pkl")
    with pytest.raises(CheckpointError, match=f"no checkpoint in run folder {tmp_path}"):
        load_checkpoint(tmp_path)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda b: b[: len(b) // 2], "truncated"),
        (lambda b: b[:10], "shorter than its header"),
        (lambda b: b[:-1] + bytes([b[-1] ^ 0xFF]), "CRC mismatch"),
        (lambda b: b"NOTEPOET" + b[8:], "not an epoet checkpoint"),
        (lambda b: b[:8] + (99).to_bytes(4, "little") + b[12:], "format version 99"),
    ],
)
def test_damaged_files_raise_checkpoint_error(tmp_path, damage, message):
    path = tmp_path / CHECKPOINT_NAME
    save_checkpoint(path, {"theta": np.arange(1000.0)})
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(CheckpointError, match=message):
        load_checkpoint(path)


def test_a_checkpoint_from_before_the_open_ended_rename_loads(tmp_path, monkeypatch):
    """ePOET's state under its old key, its pairs' environments pickled from the old package
    (epoet.poet, as checkpoints written before issue 47 hold them): they load under today's."""
    pairs = epoet.open_ended.pairs
    env = pairs.Environment(index=0, genome=None, generation=0, parent=None, created_at=0)
    with monkeypatch.context() as old:  # pickle finds the class where that code had it
        old.setitem(sys.modules, "epoet.poet.pairs", pairs)
        old.setattr(pairs.Environment, "__module__", "epoet.poet.pairs")
        save_checkpoint(tmp_path / CHECKPOINT_NAME, {"algo": "epoet", "poet": {"active": [env]}})
    assert b"epoet.poet.pairs" in (tmp_path / CHECKPOINT_NAME).read_bytes()
    state = load_checkpoint(tmp_path)
    assert state.keys() == {"algo", "open_ended"}
    (loaded,) = state["open_ended"]["active"]
    assert type(loaded) is pairs.Environment and loaded == env


def test_state_must_be_a_dict(tmp_path):
    with pytest.raises(CheckpointError, match="state must be a dict"):
        save_checkpoint(tmp_path / CHECKPOINT_NAME, [1, 2])  # type: ignore[arg-type]


# Configs as checkpoints stored them before the budgets owned their integrator and S schedule and
# the algorithm x budget values lived in conf/algo_budget/ (written by that code, commit 28f1848),
# each with today's overrides for the same run (ePOET-SAC then had no SAC warm start and mapped by
# distillation; the smoke
# and laptop budgets' S then started at 0.1 m).
BEFORE_ALGO_BUDGET = Path(__file__).with_name("configs_before_algo_budget.json")
OLD_START = "budget.max_height=0.1"
TODAY = {
    "algo=epoet budget=smoke algo.later_reproduce_interval=15": [
        "algo=epoet",
        "budget=smoke",
        "algo.later_adjust_interval=1",
        OLD_START,
    ],
    "algo=epoet budget=laptop": ["algo=epoet", "budget=laptop", OLD_START],
    "algo=epoet_sac budget=laptop": [
        "algo=epoet_sac",
        "budget=laptop",
        "algo.sac_init=null",
        "algo.mapping=distill",
        OLD_START,
    ],
}


@pytest.mark.parametrize("overrides", sorted(json.loads(BEFORE_ALGO_BUDGET.read_text())))
def test_a_checkpoint_from_before_the_algo_budget_files_resumes(overrides: str) -> None:
    """Its config reads as today's for the same run (laptop's intervals, ePOET-SAC's frames,
    the baselines' paper frames), so `resume` does not refuse it; another setting still shows."""
    saved = json.loads(BEFORE_ALGO_BUDGET.read_text())[overrides]
    today = TODAY.get(overrides, overrides.split())
    cfg = load(today)
    assert config_changes(saved, dataclasses.asdict(cfg), cfg.unused_keys()) == []
    seven = load(today + ["seed=7"])
    changed = config_changes(saved, dataclasses.asdict(seven), seven.unused_keys())
    assert changed == ["seed (0 -> 7)"]


# The commit the final paper runs train from, before the one training driver: each algorithm's
# checkpoint as its code writes it must load and continue today.
BEFORE_THE_DRIVER = "c5d3739"
# How each tiny run is cut short there, and what continues it: a baseline stopped by a tiny CPU
# budget after its first batch, then no CPU limit; the pool family after its iterations, then one
# more.
STOPPED = {Family.BASELINE: ["budget.cpu_hours=0.00001"], Family.OPEN_ENDED: []}
CONTINUED = {Family.BASELINE: ["budget.cpu_hours=null"], Family.OPEN_ENDED: ["budget.iterations=4"]}


TRAIN_ALL = """
import json, sys
from pathlib import Path
from epoet.config import compose
from epoet.run import run
for folder, overrides in json.loads(sys.argv[1]).items():
    Path(folder).mkdir()
    run(compose(overrides), Path(folder))
"""


@pytest.fixture(scope="module")
def old_checkpoints(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """<folder>/<algo>/checkpoint.pkl: each algorithm's tiny run, trained by the code of
    BEFORE_THE_DRIVER (taken from the repository's history) and cut short (STOPPED)."""
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT,
                             capture_output=True, text=True).stdout.strip()  # fmt: skip
    if shallow != "false":
        pytest.skip("needs the repository's history (a full git clone)")
    folder = tmp_path_factory.mktemp("before_the_driver")
    code = folder / "code"
    archive = subprocess.run(["git", "archive", BEFORE_THE_DRIVER], cwd=ROOT, capture_output=True,
                             check=True).stdout  # fmt: skip
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(code, filter="data")
    env = {**os.environ, "PYTHONPATH": str(code), "MLFLOW_TRACKING_URI": f"sqlite:///{folder}/m.db"}
    runs = {
        str(folder / algo): [*tiny_run(algo), *STOPPED[algorithm(algo).family], "seed=1",
                             "evaluate=false"]
        for algo in names()
    }  # fmt: skip
    # one interpreter runs them all, as `python -m epoet` runs one (its imports paid once)
    trained = subprocess.run([sys.executable, "-c", TRAIN_ALL, json.dumps(runs)], cwd=code,
                             env=env, capture_output=True, text=True)  # fmt: skip
    assert trained.returncode == 0, trained.stderr[-2000:]
    return folder


@pytest.mark.parametrize("algo", names())
def test_a_checkpoint_from_before_the_driver_resumes_and_finishes(
    algo: str, old_checkpoints: Path, tmp_path: Path, mlflow_uri: str
) -> None:
    """Loaded by today's code, it continues from where it stopped to the end of the larger
    budget, and the run exports its agent."""
    run_dir = tmp_path / algo
    run_dir.mkdir()
    before = load_checkpoint(old_checkpoints / algo)
    # its MLflow run is in the store it was written with: one of this store's stands for it
    with MlflowTracker(mlflow_uri, "Default") as tracker:
        before["run_id"] = tracker.start(f"{algo}-s1")
    save_checkpoint(run_dir / CHECKPOINT_NAME, before)
    family = algorithm(algo).family
    overrides = [*tiny_run(algo), *CONTINUED[family], "seed=1", "evaluate=false"]
    run(compose([*overrides, f"resume={run_dir}"]), run_dir)
    after = load_checkpoint(run_dir)
    assert after["run_id"] == before["run_id"]
    if family is Family.BASELINE:
        assert before["loop"]["frames"] < after["loop"]["frames"] == 240
    else:
        assert (before["open_ended"]["iteration"], after["open_ended"]["iteration"]) == (3, 4)
    assert policy_in(run_dir) is not None
