"""What a finished sweep leaves in MLflow, read back from the store: the metrics mean one thing
(`best_score` is the best so far), the params are the values the jobs ran with and only those
that apply to them, and the sweep's parent run reads as the sweep's result."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import mlflow
import numpy as np
import pytest

from epoet.es.workers import default_workers

SWEEP = ["-m", "algo=epoet,sac", "seed=1", "budget=smoke",
         "terrain.grid=40", "budget.iterations=4", "tracking.experiment=records"]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> tuple[str, dict[str, mlflow.entities.Run], str]:
    """One smoke sweep (ePOET and SAC, each ending with its suite evaluation) into a private
    store: (store uri, runs by algo tag, parent under "parent"), and its stdout."""
    tmp = tmp_path_factory.mktemp("records")
    uri = f"sqlite:///{tmp}/mlflow.db"
    proc = subprocess.run([sys.executable, "-m", "epoet", *SWEEP, f"hydra.sweep.dir={tmp}/sweep"],
                          cwd=tmp, env={**os.environ, "MLFLOW_TRACKING_URI": uri},
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("records")
    runs = {r.data.tags.get("algo", "parent"): r for r in client.search_runs([exp.experiment_id])}
    return uri, runs, proc.stdout


def _history(uri: str, run: mlflow.entities.Run, key: str) -> list[float]:
    points = mlflow.MlflowClient(uri).get_metric_history(run.info.run_id, key)
    return [p.value for p in sorted(points, key=lambda p: p.step)]


@pytest.mark.parametrize("algo", ["epoet", "sac"])
def test_best_score_is_the_running_best_of_score(sweep, algo: str) -> None:
    uri, runs, _ = sweep
    score, best = _history(uri, runs[algo], "score"), _history(uri, runs[algo], "best_score")
    assert len(best) == len(score) >= 2
    assert best == list(np.maximum.accumulate(score))


def test_time_metrics_have_one_meaning(sweep) -> None:
    """`elapsed` is cumulative training seconds everywhere; per-step times have their own names."""
    uri, runs, _ = sweep
    for algo, step_time in (("epoet", "time/iteration"), ("sac", "time/batch")):
        metrics = runs[algo].data.metrics
        assert "wall_time" not in metrics and step_time in metrics, algo
        elapsed = _history(uri, runs[algo], "elapsed")
        assert elapsed == sorted(elapsed) and elapsed[-1] > 0


def test_params_are_the_values_the_run_used(sweep) -> None:
    uri, runs, _ = sweep
    for algo in ("epoet", "sac"):
        params = runs[algo].data.params
        assert params["workers.num"] == str(default_workers()), algo  # not "None"
        assert params["tracking.uri"] == uri, algo
        assert "resume" not in params


def test_only_the_settings_a_run_reads_are_params(sweep) -> None:
    _, runs, _ = sweep
    sac, epoet = runs["sac"].data.params, runs["epoet"].data.params
    assert sac["terrain.kind"] == "bowl"
    assert not [k for k in sac if k.startswith(("terrain.cppn", "terrain.mutation"))]
    assert "budget.iterations" not in sac and "budget.frames" in sac
    assert "terrain.cppn.activation_options" in epoet and "terrain.mutation.max_tries" in epoet
    assert "budget.iterations" in epoet and "budget.frames" not in epoet
    assert "budget.sac_frames_per_iteration" not in epoet


def test_the_sweep_parent_reads_as_the_sweep(sweep) -> None:
    uri, runs, stdout = sweep
    parent = runs["parent"]
    assert parent.data.tags["algos"] == "epoet,sac" and parent.data.tags["seeds"] == "1"
    assert parent.data.tags["budget"] == "smoke"
    assert len(parent.data.tags["mlflow.source.git.commit"]) == 40
    assert parent.data.params["algo"] == "epoet,sac" and parent.data.params["seed"] == "1"
    for algo in ("epoet", "sac"):
        assert parent.data.metrics[f"sweep/{algo}/finished"] == 1
        assert parent.data.metrics[f"sweep/{algo}/score_mean"] == runs[algo].data.metrics["score"]
        assert (parent.data.metrics[f"sweep/{algo}/success_rate_mean"]
                == runs[algo].data.metrics["suite/success_rate"])
        line = next(li for li in stdout.splitlines() if li.startswith(f"[sweep] {algo} seed=1"))
        assert "FINISHED" in line and runs[algo].info.run_id in line
