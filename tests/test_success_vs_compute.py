"""Success against compute (pipeline.snapshots): a run's CPU-time snapshots become a record that
holds each snapshot's agents and their evaluations, the run's curves and config, and that
evaluates anywhere as `run=<record>`; a second export evaluates only what is new."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from conftest import BUSY_LOOP, TINY_EPOET, TINY_FAMILY, subset_suite
from epoet.core.algorithm import Family
from epoet.eval.agents import resolve_run
from epoet.run import run
from pipeline.snapshots import main

EPOET = [*TINY_EPOET, "budget.iterations=4", *BUSY_LOOP, "snapshot_cpu_minutes=[1e-6,1e-5,1000]"]


def test_a_runs_snapshots_become_a_record_with_curves_and_agents(
    compose, mlflow_uri: str, tmp_path: Path
) -> None:
    folder, out = tmp_path / "run", tmp_path / "records"
    run(compose(EPOET), folder)
    suite = subset_suite(tmp_path / "suite", [("easy", 0), ("hard", 0)])
    args = ["--runs", str(folder), "--out", str(out), "--episodes", "2", "--suites", str(suite)]
    assert main(args) == 0
    record = out / "epoet_s0"
    info = json.loads((record / "run.json").read_text())
    assert list(info["snapshots"]) == ["1e-06", "1e-05"]  # 1000 minutes never came
    assert info["training"]["cpu_time_s"] > 0 and info["training"]["iterations"] == 4
    assert info["command"].startswith("python -m epoet algo=epoet budget=smoke seed=0 ")
    for minutes, snapshot in info["snapshots"].items():
        pool = sorted(p.stem for p in (record / f"cpu{minutes}" / "policies").glob("*.npz"))
        evaluation = snapshot["evaluations"][suite.name]
        assert sorted(evaluation["agents"]) == pool and snapshot["best_agent"] in pool
        assert evaluation["episodes_per_terrain"] == 2 and len(evaluation["commit"]) == 40
        rates = list(evaluation["agents"].values())
        assert evaluation["success_rate_mean"] == pytest.approx(sum(rates) / len(rates))
        episodes = pd.read_csv(record / f"cpu{minutes}" / pool[0] / suite.name / "episodes.csv")
        assert len(episodes) == 2 * 2  # two terrains, two episodes each
    curves = pd.read_csv(record / "curves.csv")
    assert list(curves.step) == [0, 1, 2, 3]
    assert curves.cpu_time.is_monotonic_increasing and curves.max_height.iloc[0] == 1.0
    # The record is an agent anywhere: the latest snapshot's pool, with the run's rules.
    agent = resolve_run(str(record))
    assert agent.algo == "epoet" and agent.score_scale == 0.025
    assert (
        agent.agent.path == record / "policies" / f"{info['snapshots']['1e-05']['best_agent']}.npz"
    )
    # Again: nothing is evaluated twice.
    summaries = sorted(record.glob("cpu*/*/*/summary.json"))
    stamps = [p.stat().st_mtime_ns for p in summaries]
    assert main(args) == 0
    assert [p.stat().st_mtime_ns for p in summaries] == stamps
    # The record read on another suite (pipeline.choose: how records meet the validation
    # suite), one mark and the exported agent only: the other mark and the niches untouched.
    from pipeline.choose import main as choose

    other = subset_suite(tmp_path / "other", [("medium", 0)])
    mark = ["--minutes", "1e-5", "--exported-only", "--episodes", "1", "--suites", str(other)]
    assert choose(["--records", str(record), *mark]) == 0
    again = json.loads((record / "run.json").read_text())["snapshots"]
    best = again["1e-05"]["best_agent"]
    evaluation = again["1e-05"]["evaluations"][other.name]
    assert list(evaluation["agents"]) == [best] and "success_rate_mean" not in evaluation
    assert evaluation["success_rate"] == evaluation["agents"][best]
    assert other.name not in again["1e-06"]["evaluations"]
    assert [p.parent.name for p in record.glob(f"cpu*/*/{other.name}")] == [best]
    assert suite.name in again["1e-05"]["evaluations"]  # the earlier reading is kept


def test_a_folder_without_a_checkpoint_is_one_line(tmp_path: Path, capsys) -> None:
    assert main(["--runs", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a run folder with a checkpoint" in err[0]


def test_success_against_compute_is_drawn_from_records_alone(
    compose, mlflow_uri: str, tmp_path: Path
) -> None:
    """The figure, table and learning curves come from the records (the run folder and the
    store removed first), an ePOET pool read both ways."""
    import shutil

    from analysis.success_vs_compute import main as figures

    folder, out = tmp_path / "run", tmp_path / "records"
    run(compose(EPOET), folder)
    suite = subset_suite(tmp_path / "suite", [("easy", 0)])
    assert (
        main(["--runs", str(folder), "--out", str(out), "--episodes", "1", "--suites", str(suite)])
        == 0
    )
    shutil.rmtree(folder)
    Path(mlflow_uri.removeprefix("sqlite:///")).unlink()
    assert (
        figures(["--records", str(out), "--suite", str(suite), "--out", str(tmp_path / "fig")]) == 0
    )
    figs = tmp_path / "fig" / "records" / "suite"  # <out>/<records folder name>/<suite name>
    table = pd.read_csv(figs / "success_vs_compute.csv")
    assert sorted(set(zip(table.algo, table.reading))) == [
        ("epoet", "best"),  # the exported agent (chosen on held-out terrains)
        ("epoet", "niches"),
        ("epoet", "own"),  # the pool's best on its own terrain
    ]
    assert list(table[table.reading == "best"].minutes) == [1e-6, 1e-5]
    assert list(table.columns[6:9]) == ["mean", "ci_low", "ci_high"]  # the paper's statistic first
    record = json.loads((out / "epoet_s0" / "run.json").read_text())
    for snapshot in record["snapshots"].values():
        assert snapshot["best_agent"] == "agent" and snapshot["choice"]["rule"] == "validation"
        assert "success_rate_own" in snapshot["evaluations"][suite.name]
    for name in ("success_vs_compute.png", "success_vs_compute.md", "learning_curves.png"):
        assert (figs / name).stat().st_size > 0
    curves = pd.read_csv(figs / "learning_curves.csv")
    assert set(curves.axis) == {"env_steps", "cpu_time"}


def test_comparisons_pair_the_algorithms_at_the_marks_both_reached() -> None:
    """P(X > Y) per mark with X after Y in table order, from the best agents only; a mark one
    algorithm never reached has no row."""
    from analysis.comparisons import claims, comparisons

    rows = [
        {"algo": algo, "seed": seed, "minutes": minutes, "reading": reading, "terrains": terrains}
        for algo, minutes_reached in (("ppo", (15.0,)), ("epoet", (15.0, 30.0)))
        for minutes in minutes_reached
        for seed in ("1", "2")
        for reading, terrains in (
            ("best", pd.Series([1.0 if algo == "epoet" else 0.0] * 4)),
            ("niches", pd.Series([0.0] * 4)),  # not read
        )
    ]
    assert comparisons(pd.DataFrame(rows)).to_dict("records") == [
        {
            "minutes": 15.0,
            "x": "epoet",
            "y": "ppo",
            "runs": "2 / 2",
            "X - Y (mean success, pts)": "+100.0 [+100.0, +100.0]",
            "P(X > Y)": "1.00 [1.00, 1.00]",
            "P ceiling (ties)": "1.00",
        }
    ]
    # The paper's claims keep their own order: no claim pairs PPO with ePOET.
    assert comparisons(pd.DataFrame(rows), claims()).empty
    sac = [{**row, "algo": "sac"} for row in rows if row["algo"] == "ppo"]
    claimed = comparisons(pd.DataFrame(rows + sac), claims())
    assert list(zip(claimed.x, claimed.y)) == [("epoet", "sac"), ("sac", "ppo")]
    assert list(claimed["X - Y (mean success, pts)"]) == [
        "+100.0 [+100.0, +100.0]",
        "+0.0 [+0.0, +0.0]",
    ]


@pytest.mark.parametrize("family", [Family.OPEN_ENDED, Family.BASELINE])
def test_the_last_snapshots_choice_counts_in_the_runs_cpu_time(
    family: Family, compose, mlflow_uri: str, tmp_path: Path
) -> None:
    """A run ended by its CPU hours at its last snapshot mark: the held-out choice made there
    (after the last iteration's CPU reading) is in the run's CPU time and in snapshot.json."""
    from epoet.core.checkpoint import load_checkpoint

    mark = 1e-3  # CPU minutes: the budget below ends the run at its first step past it
    overrides = [
        *TINY_FAMILY[family],
        f"budget.cpu_hours={mark / 60}",
        f"snapshot_cpu_minutes=[{mark}]",
    ]
    algo = "epoet" if family is Family.OPEN_ENDED else "ppo"
    run(compose([f"algo={algo}", *overrides, "evaluate=false"]), tmp_path)
    snapshot = json.loads((tmp_path / "snapshots" / f"cpu{mark:g}" / "snapshot.json").read_text())
    state = load_checkpoint(tmp_path)
    cpu_time = state["open_ended" if family is Family.OPEN_ENDED else "loop"]["cpu_time"]
    assert snapshot["choice_cpu_s"] > 0  # eight held-out terrains walked
    assert snapshot["cpu_time"] - snapshot["choice_cpu_s"] >= mark * 60
    assert cpu_time >= snapshot["cpu_time"]
