"""`budget.hours`: the paper's comparison after a fixed wall-clock time. The stop falls at an
iteration (ePOET) or collector-batch (baselines) boundary with a checkpoint, the hours add up
over resumes, and a resume with more hours goes on."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mlflow
import numpy as np
import pytest

from conftest import TINY_EPOET, tiny_baseline
from epoet.config import load
from epoet.core.checkpoint import load_checkpoint
from epoet.core.schema import ConfigError
from epoet.run import run

ROOT = Path(__file__).resolve().parent.parent
TINY = "budget.hours=1e-9"  # used up by the first iteration or batch
EPOET = [*TINY_EPOET, "budget.iterations=4"]
# the baselines' tiny run, checkpointing less often than its every 2 batches
PPO = [a for a in tiny_baseline("ppo") if not a.startswith("checkpoint_every=")]
PPO.append("checkpoint_every=10")


def _stop_reason(uri: str, run_id: str) -> str:
    return mlflow.MlflowClient(uri).get_run(run_id).data.tags["stop_reason"]


def _history(uri: str, run_id: str, key: str) -> dict[int, float]:
    return {m.step: m.value for m in mlflow.MlflowClient(uri).get_metric_history(run_id, key)}


def _assert_summed_over_the_resume(uri: str, run_id: str, step_time: str, total: float) -> None:
    """`elapsed` at each logged step is the sum of every step's own time (`step_time`) up to it,
    before the resume and after it (a sum that restarted at 0 on resume breaks this at the first
    step after it), and the checkpoint's total is the last sum."""
    times = _history(uri, run_id, step_time)
    elapsed = _history(uri, run_id, "elapsed")
    steps = sorted(times)
    np.testing.assert_allclose(
        [elapsed[s] for s in steps], np.cumsum([times[s] for s in steps]), rtol=1e-9
    )
    assert total == pytest.approx(elapsed[steps[-1]], rel=1e-9)


def test_epoet_stops_at_the_wall_clock_budget_and_a_resume_goes_on(
    compose, mlflow_uri: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    folder = tmp_path / "run"
    run(compose(EPOET + [TINY]), folder)
    first = load_checkpoint(folder / "checkpoint.pkl")
    assert first["open_ended"]["iteration"] == 1  # the first boundary, with a checkpoint
    assert (
        "stopped at the wall-clock budget (budget.hours=1e-09) after 1 iterations"
        in capsys.readouterr().out
    )
    assert _stop_reason(mlflow_uri, first["run_id"]) == "hours"
    run(compose(EPOET + ["budget.hours=1", f"resume={folder}"]), folder)
    second = load_checkpoint(folder / "checkpoint.pkl")
    assert second["run_id"] == first["run_id"] and second["open_ended"]["iteration"] == 4
    assert (
        second["open_ended"]["elapsed"] > first["open_ended"]["elapsed"]
    )  # summed over the resume
    assert _stop_reason(mlflow_uri, first["run_id"]) == "iterations"
    assert len(_history(mlflow_uri, first["run_id"], "time/iteration")) == 4
    _assert_summed_over_the_resume(
        mlflow_uri, first["run_id"], "time/iteration", second["open_ended"]["elapsed"]
    )


def test_a_baseline_stops_at_a_batch_boundary_and_a_resume_goes_on(
    compose, mlflow_uri: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    folder = tmp_path / "run"
    run(compose(PPO + [TINY]), folder)
    first = load_checkpoint(folder / "checkpoint.pkl")
    assert (first["loop"]["frames"], first["loop"]["batches"]) == (60, 1)
    assert "after 60 frames" in capsys.readouterr().out
    assert _stop_reason(mlflow_uri, first["run_id"]) == "hours"
    run(compose(PPO + ["budget.hours=1", f"resume={folder}"]), folder)
    second = load_checkpoint(folder / "checkpoint.pkl")
    assert second["loop"]["frames"] == 240
    assert second["loop"]["wall_time"] > first["loop"]["wall_time"]
    assert _stop_reason(mlflow_uri, first["run_id"]) == "frames"
    assert sorted(_history(mlflow_uri, first["run_id"], "time/batch")) == [60, 120, 180, 240]
    _assert_summed_over_the_resume(
        mlflow_uri, first["run_id"], "time/batch", second["loop"]["wall_time"]
    )


def test_the_paper_budget_is_24_hours_with_the_references_baseline_frames() -> None:
    job = subprocess.run(
        [sys.executable, "-m", "epoet", "budget=paper", "--cfg", "job"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert job.returncode == 0 and "hours: 24.0" in job.stdout
    # ml-tue/ePOET_3D torchrl/config/{ppo,sac,vmpo}_hex.json: epochs x frames per epoch
    frames = {"ppo": 3000 * 2000, "sac": 500 * 2048, "vmpo": 488 * 2000}
    for algo, expected in frames.items():
        assert load([f"algo={algo}", "budget=paper"]).budget.frames == expected
    assert load(["budget=laptop"]).budget.hours is None


def test_epoet_sac_runs_as_the_paper_at_the_paper_budget() -> None:
    paper = load(["algo=epoet_sac", "budget=paper"]).algo
    assert (paper.pretrain_iterations, paper.mapping) == (500, "random")
    laptop = load(["algo=epoet_sac", "budget=laptop"]).algo
    assert (laptop.pretrain_iterations, laptop.mapping) == (0, "dagger")


def test_bad_hours_are_one_sentence() -> None:
    with pytest.raises(ConfigError, match=r"budget.hours must be > 0 or null, got -1"):
        load(["budget.hours=-1"])
