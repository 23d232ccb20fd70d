"""The authors' files are read where the user keeps them (epoet/eval/reference/files.py): none
of them, nor a file converted from them, is in the repository; their conversion, made on use
into a cache, gives the numbers of the committed records; without them, the commands that need
them stop at start-up with one line, and the rest run."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from conftest import authors
from epoet.eval.reference import convert, files

ROOT = Path(__file__).resolve().parent.parent
RECORDS = ROOT / "docs" / "results" / "reference"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_no_tracked_file_is_the_authors_or_converted_from_theirs():
    converted = authors()
    theirs = {
        _digest(p): f"their {p.relative_to(files.source())}"
        for p in (files.source() / files.MODELS).rglob("*")
        if p.is_file()
    }
    theirs |= {
        _digest(p): f"converted {p.relative_to(converted)}"
        for p in converted.rglob("*")
        if p.is_file()
    }
    tracked = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    found = [
        f"{name.decode()} ({theirs[digest]})"
        for name in tracked
        if name and (ROOT / name.decode()).is_file()
        if (digest := _digest(ROOT / name.decode())) in theirs
    ]
    assert not found, found


def test_the_conversion_gives_the_committed_records_numbers(mlflow_uri):
    """The conversion is, byte for byte, the files the committed records were evaluated with
    (their hashes, recorded when those files left the repository); the paper suite's
    fingerprint is the one those records carry; and the authors' ES agents replay an episode of
    their committed evaluation to the same return. (Their torch agents replay to within float
    noise only, before this conversion moved too: docs/authors.md.)"""
    from epoet.eval.agents import resolve_run
    from epoet.eval.episodes import COLUMNS, Task, episode_seeds, run_task
    from epoet.eval.suite import load_suite, terrain_config_for

    converted = authors()
    recorded = json.loads(files.SOURCE.read_text())["outputs"]
    made = {str(p.relative_to(converted)): _digest(p) for p in converted.rglob("*") if p.is_file()}
    assert made == recorded
    suite = load_suite("paper")
    summary = json.loads((RECORDS / "epoet_flat" / "paper" / "summary.json").read_text())
    assert suite.fingerprint == summary["suite_fingerprint"]
    terrain_cfg = terrain_config_for(suite.terrains)
    index = {t.name: k for k, t in enumerate(suite.terrains)}
    for record, spec in (
        ("epoet_flat", "reference:poet_hexA8/flat"),
        ("epoet_sac_sac_58", "reference:poet_twin22/sac_58"),
    ):
        info = json.loads((RECORDS / record / "paper" / "summary.json").read_text())
        episodes = pd.read_csv(RECORDS / record / "paper" / "episodes.csv")
        row = episodes.sort_values("length").iloc[0]  # the shortest: seconds of physics
        k = index[row.terrain]
        seeds = episode_seeds(info["eval_seed"], k, info["episodes_per_terrain"])
        assert seeds[row.episode] == row.start_seed
        run = resolve_run(spec, mlflow_uri)
        task = Task(
            k,
            suite.terrains[k],
            run.agent,
            suite.course.rules(run.agent_config(None)),
            terrain_cfg,
            (int(row.start_seed),),
            0.0,  # what "solved" needs is not compared here
            0,
        )
        _, rows, _, _ = run_task(task)
        replayed = dict(zip(COLUMNS, rows[0]))
        assert replayed["return"] == pytest.approx(row["return"], rel=1e-12), record
        assert replayed["length"] == row.length, record


def test_the_cache_is_keyed_by_the_inputs_and_rebuilt_when_the_converter_changes(
    tmp_path, monkeypatch
):
    authors()
    monkeypatch.setenv(files.CACHE_ENV, str(tmp_path / "cache"))
    convert.converted.cache_clear()
    try:
        first = convert.converted()
        assert first.parent == tmp_path / "cache" / "reference"
        assert (first / "suite" / "suite.json").is_file() and (first / files.MANIFEST).is_file()
        convert.converted.cache_clear()
        assert convert.converted() == first  # found, not converted again
        monkeypatch.setattr(convert, "CONVERTER_VERSION", convert.CONVERTER_VERSION + 1)
        convert.converted.cache_clear()
        second = convert.converted()
        assert second != first and (second / files.MANIFEST).is_file()
        assert (second / "manifest.json").read_bytes() == (first / "manifest.json").read_bytes()
    finally:
        convert.converted.cache_clear()


def test_inputs_that_are_not_the_recorded_commits_are_refused(tmp_path):
    authors()
    source = files.source()
    copy = tmp_path / "ePOET_3D"
    inputs = json.loads(files.SOURCE.read_text())["inputs"]
    for name in inputs:
        (copy / name).parent.mkdir(parents=True, exist_ok=True)
        (copy / name).write_bytes((source / name).read_bytes())
    assert files.checked_inputs(copy) == inputs
    changed = copy / next(iter(inputs))
    changed.write_bytes(changed.read_bytes() + b" ")
    with pytest.raises(files.ReferenceFileError, match="is not the file of ePOET_3D at the commit"):
        files.checked_inputs(copy)
    changed.unlink()
    with pytest.raises(files.ReferenceFileError, match="lacks 1 of the authors' files"):
        files.checked_inputs(copy)


def _without_files(tmp_path: Path) -> dict[str, str]:
    return {
        **os.environ,
        files.ENV: str(tmp_path / "nowhere"),
        files.CACHE_ENV: str(tmp_path / "cache"),
        "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}",
    }


@pytest.mark.parametrize(
    "command",
    [
        ["epoet.eval.evaluate", "run=reference:sac/42"],
        ["epoet.eval.evaluate", "run=epoet/suite", "suite=paper"],
        ["epoet.eval.render", "run=reference:ppo/0", "terrain=r0c0"],
        ["epoet", "algo=epoet_sac", "budget=smoke", "algo.sac_init=reference:sac/42"],
        ["epoet.eval.reference"],
        ["pipeline.reference"],
    ],
    ids=["evaluate-agent", "evaluate-suite", "render", "sac-init", "convert", "tables"],
)
def test_without_the_files_a_command_that_needs_them_stops_in_one_line(tmp_path, command):
    work = tmp_path / "work"
    work.mkdir()
    done = subprocess.run(
        [sys.executable, "-m", *command],
        cwd=work,
        env={**_without_files(tmp_path), "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "ePOET_3D" in lines[0] and "e760e17" in lines[0], lines
    assert not any(work.iterdir()) and not (tmp_path / "mlflow.db").exists()


def test_without_the_files_epoet_sacs_default_run_checks_out(tmp_path):
    """The defaults need none of the authors' files: ePOET-SAC starts cold at every budget."""
    from epoet.config import load

    for budget in ("smoke", "laptop", "workstation", "paper"):
        assert load(["algo=epoet_sac", f"budget={budget}"]).algo.sac_init is None
    done = subprocess.run(
        [sys.executable, "-m", "epoet", "algo=epoet_sac", "budget=workstation", "check=true"],
        cwd=tmp_path,
        env={**_without_files(tmp_path), "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0 and "config OK" in done.stdout, done.stderr
