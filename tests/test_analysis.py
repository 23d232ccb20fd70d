"""Learning curves from a real MLflow store: ePOET smoke runs and tracked baseline runs."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import mlflow
import pandas as pd
import pytest

from analysis.curves import BASELINE_COLUMNS, EPOET_COLUMNS, EVAL_KEY, main
from conftest import new_store
from epoet.run import run
from epoet.tracking import MlflowTracker

ROOT = Path(__file__).resolve().parent.parent
SMOKE = ["budget=smoke", "workers.num=1", "algo.es.hidden=[8]", "terrain.grid=40"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _is_png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == PNG_MAGIC


def _tracked(
    algo: str | None,
    seed: int,
    evals: list[tuple[int, float]],
    status: str = "FINISHED",
    parent: str | None = None,
) -> str:
    """A run in the store with a baseline's evaluation (`eval/return_mean` and `score`, its
    curve) at the given frames; algo None = sweep parent."""
    tags = {} if algo is None else {"algo": algo, "seed": str(seed), "budget": "smoke"}
    with MlflowTracker(None, "epoet") as tracker:
        run_id = tracker.start(f"{algo}-s{seed}", tags=tags, parent_run_id=parent)
        for frames, value in evals:
            tracker.log_metrics(frames, {"eval/return_mean": value, "score": value})
        tracker.close(status)
    return run_id


def test_epoet_curves_equal_the_metric_history(
    compose, mlflow_uri: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    for seed in (0, 1):
        run(compose(SMOKE + [f"seed={seed}"]), tmp_path / f"s{seed}")
    out = tmp_path / "figures"
    capsys.readouterr()
    assert main(["--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out / 'epoet_curves.png'}" in printed
    assert "skipped" in printed and "baseline_curves.png" in printed
    assert _is_png(out / "epoet_curves.png") and not (out / "baseline_curves.png").exists()

    table = pd.read_csv(out / "epoet_curves.csv", dtype={"run_id": str})
    assert list(table.columns) == EPOET_COLUMNS
    client = mlflow.MlflowClient(mlflow_uri)
    runs = {
        r.info.run_id: r
        for r in client.search_runs([client.get_experiment_by_name("epoet").experiment_id])
    }
    assert set(table.run_id) == set(runs) and len(runs) == 2
    assert sorted(table.groupby("run_id").seed.first()) == [0, 1]
    assert set(table.algo) == {"epoet"}
    for run_id in runs:
        pair0 = table[(table.run_id == run_id) & (table.pair == 0)]
        assert list(pair0.iteration) == [0, 1, 2]
    for (run_id, pair), rows in table.groupby(["run_id", "pair"]):
        logged = client.get_metric_history(run_id, f"pair{pair}/return_mean")
        assert [(m.step, m.value) for m in sorted(logged, key=lambda m: m.step)] == list(
            zip(rows.iteration, rows.return_mean)
        )


def test_baseline_curves_skip_parents_unfinished_runs_and_resumed_duplicates(
    mlflow_uri: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    parent = _tracked(None, 0, [(0, 99.0)])
    ppo = _tracked("ppo", 1, [(0, 1.0), (200, 2.5), (400, 4.0)], parent=parent)
    sac = _tracked("sac", 2, [(0, -1.0), (200, 3.0)], parent=parent)
    _tracked("vmpo", 3, [(0, 7.0)], status="FAILED")
    time.sleep(0.01)
    # A store from before resumed runs skipped logged steps holds frames 200 twice: the later
    # value must win.
    mlflow.MlflowClient(mlflow_uri).log_metric(sac, EVAL_KEY, 5.0, step=200)
    out = tmp_path / "figures"
    capsys.readouterr()
    assert main(["--out", str(out)]) == 0
    assert "skipped" in capsys.readouterr().out
    assert _is_png(out / "baseline_curves.png") and not (out / "epoet_curves.png").exists()
    table = pd.read_csv(out / "baseline_curves.csv", dtype={"run_id": str})
    assert list(table.columns) == BASELINE_COLUMNS
    got = {(r.run_id, r.algo, r.seed, r.frames, r.return_mean) for r in table.itertuples()}
    assert got == {
        (ppo, "ppo", 1, 0, 1.0),
        (ppo, "ppo", 1, 200, 2.5),
        (ppo, "ppo", 1, 400, 4.0),
        (sac, "sac", 2, 0, -1.0),
        (sac, "sac", 2, 200, 5.0),
    }


def test_run_selection_and_unknown_run(
    mlflow_uri: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    ppo = _tracked("ppo", 1, [(0, 1.0), (200, 2.0)])
    _tracked("sac", 2, [(0, 3.0)])
    failed = _tracked("vmpo", 3, [(0, 7.0)], status="FAILED")
    out = tmp_path / "figures"
    capsys.readouterr()
    assert main(["--out", str(out), "--run", ppo, failed]) == 0
    table = pd.read_csv(out / "baseline_curves.csv", dtype={"run_id": str})
    assert set(table.run_id) == {ppo, failed}  # an explicit id is plotted whatever its status
    capsys.readouterr()
    assert main(["--out", str(out), "--run", ppo, "0123456789abcdef"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "0123456789abcdef" in err[0]


def test_store_without_usable_runs_exits_2_in_one_line(
    mlflow_uri: str, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    missing = tmp_path / "nowhere.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{missing}")
    capsys.readouterr()
    assert main(["--out", str(tmp_path / "f")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(missing) in err[0] and not missing.exists()

    monkeypatch.setenv("MLFLOW_TRACKING_URI", mlflow_uri)
    _tracked(None, 0, [(0, 1.0)])  # only a sweep parent: nothing to plot
    env = {**os.environ, "MLFLOW_TRACKING_URI": mlflow_uri}
    out = subprocess.run(
        [sys.executable, "-m", "analysis.curves", "--out", str(tmp_path / "f")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "no ePOET/ePOET-SAC runs" in lines[0], out.stderr
    assert not (tmp_path / "f").exists()


def test_tables_refuse_runs_evaluated_at_different_course_scales(
    tmp_path: Path, empty_store
) -> None:
    """A laptop run's "solved" (a fifth of the course) is not a paper run's: never one table."""
    from analysis.store import AnalysisError
    from analysis.tables import course_scale
    from epoet.eval.suite import load_suite

    suite = load_suite()
    client = mlflow.MlflowClient(new_store(empty_store, tmp_path))
    exp = client.create_experiment("scales")
    runs = []
    for scale, other in (("0.2", "1"), ("1", "0.2"), ("0.2", "1")):
        run_id = client.create_run(exp).info.run_id
        client.set_tag(run_id, "eval_suite/shipped", suite.fingerprint)
        client.set_tag(run_id, "eval_course_scale/shipped", scale)
        client.set_tag(run_id, "eval_course_scale/paper", other)  # another suite's: not read
        runs.append(client.get_run(run_id))
    assert course_scale([runs[0], runs[2]], suite) == "0.2"
    with pytest.raises(AnalysisError, match=r"different course scales \(0.2, 1\)"):
        course_scale(runs, suite)
    # a run logged before evaluations were keyed by suite: its unkeyed tags
    legacy = client.create_run(exp).info.run_id
    client.set_tag(legacy, "eval_suite", suite.fingerprint)
    client.set_tag(legacy, "eval_course_scale", "0.2")
    assert course_scale([runs[0], client.get_run(legacy)], suite) == "0.2"


def test_tables_only_read_the_store_and_name_the_command_for_unevaluated_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, empty_store
) -> None:
    """A finished run with no evaluation on the suite is one sentence naming the run and the
    command, and nothing is evaluated, logged or written."""
    from analysis.store import AnalysisError
    from analysis.tables import make_tables

    uri = new_store(empty_store, tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    run_id = _tracked("ppo", 1, [(0, 1.0)])
    before = mlflow.MlflowClient(uri).get_run(run_id)
    with pytest.raises(AnalysisError) as err:
        make_tables("epoet", tmp_path / "results")
    message = str(err.value)
    assert "1 run(s) have no evaluation" in message and run_id in message
    assert "python -m epoet.eval.evaluate run=" in message and "\n" not in message
    after = mlflow.MlflowClient(uri).get_run(run_id)
    assert after.data.tags == before.data.tags and after.data.metrics == before.data.metrics
    assert not (tmp_path / "results").exists()


def test_make_paper_jobs_split_the_cores(capsys: pytest.CaptureFixture) -> None:
    """JOBS=k: k jobs at a time through the joblib launcher, k x workers <= cores."""
    from pipeline.paper import main as paper_main
    from pipeline.paper import parallel_overrides

    assert parallel_overrides(1, 2) == []
    assert parallel_overrides(2, 2) == [
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        "workers.num=1",
    ]
    assert parallel_overrides(2, 8)[-1] == "workers.num=4"
    assert paper_main(["--budget", "smoke", "--jobs", "0"]) == 2
    assert "--jobs must be between 1" in capsys.readouterr().err


def test_make_paper_overrides_reach_every_job_last() -> None:
    """OVERRIDES=...: appended after the budget, so a value such as budget.hours wins over it."""
    from pipeline.paper import train_command

    command = train_command(
        "workstation",
        "1",
        ["epoet", "sac"],
        "paper-workstation",
        Path("multirun/x"),
        overrides=["budget.hours=0.4"],
    )
    assert command[-1] == "budget.hours=0.4"
    assert command.index("budget=workstation") < command.index("budget.hours=0.4")
