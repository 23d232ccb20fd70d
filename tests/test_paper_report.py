"""`make paper` at a budget that ends runs by CPU hours: each job's snapshots are recorded as the
job ends, and the report (Tables 1 and 2, each seed with its interval, success against compute,
the paper's claims) comes from the records alone, the same bytes every time; every committed
report rebuilds byte for byte from the records beside it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from analysis.paper_report import write_report
from conftest import new_store, subset_suite

ROOT = Path(__file__).resolve().parent.parent
COMMITTED = sorted(p for p in (ROOT / "docs" / "results").glob("*/report") if p.is_dir())


def files_of(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_cpu_hour_paper_records_each_run_and_reports_from_records(
    tmp_path: Path, empty_store: Path
) -> None:
    suite = subset_suite(tmp_path / "suite", [("easy", 0), ("medium", 0)])
    command = [
        sys.executable,
        "-m",
        "pipeline.paper",
        "--budget",
        "smoke",
        "--seeds",
        "1",
        "--algos",
        "epoet,sac",
        "--suites",
        str(suite),
        "--episodes",
        "1",
        "--out",
        str(tmp_path / "results"),
        "--runs",
        str(tmp_path / "runs"),
        "terrain.grid=40",
        "budget.cpu_hours=0.0003",  # about a CPU second
        "snapshot_cpu_minutes=[0.002,0.004]",
    ]
    env = {**os.environ, "MLFLOW_TRACKING_URI": new_store(empty_store, tmp_path, "m.db")}
    proc = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "2 at a time" in proc.stdout  # one job per core by default (the tests run on 2)
    records = tmp_path / "results" / "records"
    for algo in ("epoet", "sac"):
        info = json.loads((records / f"{algo}_s1" / "run.json").read_text())
        assert info["snapshots"], algo  # recorded when its job ended, from its snapshots
        for snapshot in info["snapshots"].values():
            evaluation = snapshot["evaluations"]["suite"]
            assert list(evaluation["agents"]) == [snapshot["best_agent"]]  # the exported only
    report = tmp_path / "results" / "suite"
    seeds = pd.read_csv(report / "table1_seeds_suite.csv")
    assert list(seeds.seed) == ["1", "mean [95 % CI]"] * 2
    claims = (report / "claims.md").read_text()
    assert "| epoet | sac |" in claims.replace("  ", " ")  # ePOET against SAC, the paper's claim
    for name in ("table1_suite.md", "table2_suite.md", "success_vs_compute.png"):
        assert (report / name).stat().st_size > 0
    # Called again, it resumes: the finished jobs are skipped and their records, complete,
    # are not evaluated again, nor is a process started to find that out; a record that lost
    # its run.json is written again, from the evaluations it holds.
    summaries = sorted(records.glob("*/cpu*/*/*/summary.json"))
    stamps = [p.stat().st_mtime_ns for p in summaries]
    (records / "sac_s1" / "run.json").unlink()
    again = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, env=env)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "already finished" in again.stdout + again.stderr
    assert [p.stat().st_mtime_ns for p in summaries] == stamps
    assert f"epoet_s1 is recorded in {records / 'epoet_s1'} already" in again.stdout
    assert "[paper] recording epoet_s1" not in again.stdout
    assert "[paper] recording sac_s1" in again.stdout
    assert json.loads((records / "sac_s1" / "run.json").read_text())["snapshots"]
    # From the records alone (runs and store gone), the same bytes.
    for path in [*(tmp_path / "runs").rglob("*"), tmp_path / "m.db"]:
        if path.is_file():
            path.unlink()
    write_report(records, [str(suite)], tmp_path / "again")
    assert files_of(tmp_path / "again" / "suite") == files_of(report)


@pytest.mark.parametrize("report", COMMITTED, ids=[p.parent.name for p in COMMITTED])
def test_a_committed_report_rebuilds_byte_for_byte(report: Path, tmp_path: Path) -> None:
    from conftest import authors

    if (report / "paper").is_dir():
        authors()  # the paper suite is read from the authors' files
    suites = sorted(p.name for p in report.iterdir() if p.is_dir())
    write_report(report.parent, suites, tmp_path)
    assert files_of(tmp_path) == files_of(report)
