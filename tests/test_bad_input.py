"""The bad-input table of docs/runs.md, row by row, through `python -m epoet` as users type it: each bad
input ends in one line on stderr and exit 2, before any training, and destroys nothing (the good
run's checkpoint and MLflow run stay as they were, no other run is finished or deleted).

The evaluation and analysis commands' rows are tested where those commands are
(tests/test_evaluation.py::test_bad_inputs_are_one_line_errors, tests/test_analysis.py).
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import mlflow
import pytest

from conftest import new_store, without_evaluation
from epoet.eval.reference.files import ENV

SMOKE = [
    "budget=smoke",
    "workers.num=1",
    "algo.es.hidden=[8]",
    "terrain.grid=40",
    "budget.iterations=1",
]

# (row id, overrides ({good}: the good run's folder, {tmp}: a scratch folder), stderr must hold)
ROWS = [
    ("unknown algo", ["algo=foo"], "Could not find 'algo/foo' (available: epoet, epoet_sac"),
    ("misspelt algo", ["algo=epot"], "vmpo); did you mean algo=epoet?"),
    ("unknown agent", ["agent=foo"], "Could not find 'agent/foo'"),
    ("unknown terrain", ["terrain=foo"], "Could not find 'terrain/foo'"),
    ("unknown budget", ["budget=foo"], "Could not find 'budget/foo'"),
    ("unknown workers", ["workers=foo"], "Could not find 'workers/foo'"),
    ("unknown tracking", ["tracking=foo"], "Could not find 'tracking/foo'"),
    ("unknown launcher", ["hydra/launcher=foo"], "Could not find 'hydra/launcher/foo'"),
    (
        "unknown key",
        ["budget.iteration=3"],
        "key budget.iteration: did you mean budget.iterations?",
    ),
    # `+` adds a key Hydra does not check: refused all the same
    (
        "added unknown key",
        ["+budget.cpu_hour=1"],
        "key budget.cpu_hour: did you mean budget.cpu_hours?",
    ),
    ("added top-level key", ["+sed=1"], "unknown key sed: did you mean seed?"),
    (
        "renamed config path",
        ["algo_budget/poet=laptop"],
        "algo_budget/poet is now algo_budget/open_ended: override algo_budget/open_ended=<budget>.",
    ),
    (
        "another algorithm's budget key",
        ["algo=ppo", "budget.n_pairs=4"],
        "unknown key budget.n_pairs: budget's keys are name, episode_steps,",
    ),
    (
        "wrong type",
        ["seed=abc"],
        "seed=abc: Value 'abc' of type 'str' could not be converted to Integer",
    ),
    ("out of range", ["budget.n_pairs=-1"], "budget.n_pairs must be > 0"),
    ("no workers", ["workers.num=0"], "workers.num must be > 0"),
    # the key typed, not the one that follows it (agent.max_episode_steps: ${budget...})
    (
        "episode length",
        ["budget.episode_steps=0"],
        "budget.episode_steps (agent.max_episode_steps) must be > 0",
    ),
    ("terrain for ePOET", ["terrain=bowl"], "needs terrain=cppn"),
    (
        "ePOET-SAC buffer",
        ["algo=epoet_sac", "algo.sac.buffer_size=8"],
        "algo.sac.buffer_size (8) must hold at least one batch",
    ),
    (
        "ePOET-SAC start from another algorithm's run",
        ["algo=epoet_sac", "algo.sac_init={good}"],
        "is an algo=epoet run; a warm start takes the actor and critics of an algo=sac run",
    ),
    (
        "ePOET-SAC start from the authors' PPO",
        ["algo=epoet_sac", "algo.sac_init=reference:ppo/0"],
        "is the authors' ppo agent; a warm start takes a SAC actor with its critics",
    ),
    (
        "ePOET-SAC start of other layer sizes",
        ["algo=epoet_sac", "algo.sac_init=reference:sac/42", "algo.sac.hidden=[64,64]"],
        "has a [256, 256] relu actor, but algo.sac.hidden=[64, 64]",
    ),
    ("ray for a baseline", ["algo=ppo", "workers=ray"], "use workers=local"),
    ("address without ray", ["workers.address=127.0.0.1:6379"], "needs workers=ray"),
    (
        "unreachable ray",
        ["workers=ray", "workers.address=127.0.0.1:9"],
        "no Ray cluster answers at workers.address=127.0.0.1:9",
    ),
    ("resume missing", ["resume={tmp}/missing"], "does not exist"),
    # the good checkpoint cut in half (the test writes it)
    (
        "resume corrupt",
        ["resume={tmp}/corrupt.pkl"],
        "checkpoint {tmp}/corrupt.pkl is truncated or padded: payload is",
    ),
    (
        "resume other algo",
        ["algo=epoet_sac", "resume={good}"],
        "is from algo=epoet, so it cannot resume algo=epoet_sac",
    ),
    ("resume changed config", ["resume={good}", "seed=1"], "seed (0 -> 1)"),
    ("unreachable tracking", ["tracking.uri=http://127.0.0.1:9"], "http://127.0.0.1:9"),
    (
        "resume=auto on an unreadable DONE",
        ["resume=auto", "hydra.run.dir={tmp}/done_garbage"],
        "DONE is no finished run's mark (",
    ),
    (
        "resume=auto on a DONE without a checkpoint",
        ["resume=auto", "hydra.run.dir={tmp}/done_only"],
        "holds no checkpoint.pkl: there is nothing to continue; remove",
    ),
    ("store in a missing folder", ["tracking.uri=sqlite:///{tmp}/nowhere/m.db"], "does not exist"),
    ("output folder not a folder", ["hydra.run.dir={tmp}/a_file/run"], "Not a directory"),
]


def _epoet(args: list[str], cwd: Path, uri: str, **env: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "epoet", *without_evaluation(args)],
        cwd=cwd,
        env={**os.environ, "MLFLOW_TRACKING_URI": uri, **env},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _runs(uri: str) -> dict[str, str]:
    client = mlflow.MlflowClient(uri)
    return {
        r.info.run_id: r.info.status
        for r in client.search_runs([e.experiment_id for e in client.search_experiments()])
    }


@pytest.fixture(scope="module")
def good(tmp_path_factory, empty_store) -> tuple[Path, str]:
    """A finished smoke run with its checkpoint, which no bad input may touch."""
    tmp = tmp_path_factory.mktemp("bad_input")
    uri = new_store(empty_store, tmp)
    proc = _epoet([*SMOKE, f"hydra.run.dir={tmp / 'good'}"], tmp, uri)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    return tmp, uri


@pytest.mark.timeout(600)  # about 35 commands' imports at once, on a shared machine
def test_every_row_of_the_table_is_one_line_exit_2_and_destroys_nothing(good) -> None:
    tmp, uri = good
    checkpoint = tmp / "good" / "checkpoint.pkl"
    saved = checkpoint.read_bytes()
    (tmp / "corrupt.pkl").write_bytes(saved[: len(saved) // 2])
    (tmp / "a_file").write_text("not a folder")
    marks = {"done_garbage": b"\xff\xfe not a mark", "done_only": b"0123abcd\n{}\n"}
    for folder, mark in marks.items():
        (tmp / folder).mkdir()
        (tmp / folder / "DONE").write_bytes(mark)
    before = _runs(uri)
    procs = {}
    for i, (name, overrides, _) in enumerate(ROWS):  # all at once: each waits on imports
        args = [a.format(good=tmp / "good", tmp=tmp) for a in overrides]
        if not any(a.startswith("hydra.run.dir") for a in args):
            args.append(f"hydra.run.dir={tmp / 'bad' / str(i)}")
        # a baseline's config has neither ES settings nor an ES budget (iterations, pairs)
        base = (
            SMOKE
            if "algo=ppo" not in args
            else [a for a in SMOKE if not a.startswith(("algo.es", "budget.iterations"))]
        )
        procs[name] = _epoet([*base, *args], tmp, uri)
    for name, _, message in ROWS:
        _, err = procs[name].communicate(timeout=300)
        assert procs[name].returncode == 2, (name, err[-2000:])
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), (name, err[-2000:])
        assert message.format(tmp=tmp) in lines[0], (name, lines[0])
    assert checkpoint.read_bytes() == saved
    assert all((tmp / folder / "DONE").read_bytes() == mark for folder, mark in marks.items())
    assert _runs(uri) == before  # no run created, finished, failed or deleted
    assert not list((tmp / "bad").rglob("checkpoint.pkl"))
    # a refused run leaves no folder: Hydra's (new, holding only its .hydra/) is removed
    assert not (tmp / "bad").exists() or not list((tmp / "bad").iterdir())


def test_check_validates_a_run_as_it_would_start_and_writes_nothing(good) -> None:
    """`check=true` makes the run's checks (ranges, combinations, the checkpoint to resume, the
    store) and prints one line, creating no folder, MLflow run or store; a refused run removes
    only the folder Hydra made for it, never one that held anything before."""
    tmp, uri = good
    checkpoint = tmp / "good" / "checkpoint.pkl"
    saved = checkpoint.read_bytes()
    (tmp / "fresh").mkdir()
    (tmp / "existing").mkdir()
    (tmp / "existing" / "notes.txt").write_text("mine")
    new_store = f"tracking.uri=sqlite:///{tmp}/fresh/mlflow.db"
    cases = [  # (overrides, exit code, the one line holds)
        ([new_store, f"hydra.run.dir={tmp}/checked/run"], 0, f"would start a new run in {tmp}"),
        ([f"resume={tmp / 'good'}"], 0, f"would resume {checkpoint}"),
        ([f"resume={tmp / 'good'}", "seed=1"], 2, "seed (0 -> 1)"),
        (["+budget.cpu_hour=1"], 2, "unknown key budget.cpu_hour: did you mean budget.cpu_hours?"),
        (["terrain=bowl", f"hydra.run.dir={tmp}/checked/bowl"], 2, "needs terrain=cppn"),
    ]
    refused = [  # runs (not checks) refused after Hydra made their folder
        ([f"hydra.run.dir={tmp}/new/deep/run", "workers.num=0"], 2, "workers.num must be > 0"),
        ([f"hydra.run.dir={tmp}/existing", "terrain=bowl"], 2, "needs terrain=cppn"),
    ]
    before = _runs(uri)
    # the first with a headless machine's MUJOCO_GL=egl: still one line (PyOpenGL's import
    # notice is not printed)
    procs = [
        _epoet([*SMOKE, "check=true", *args], tmp, uri, **({"MUJOCO_GL": "egl"} if i == 0 else {}))
        for i, (args, _, _) in enumerate(cases)
    ]
    procs += [_epoet([*SMOKE, *args], tmp, uri) for args, _, _ in refused]
    for proc, (args, code, message) in zip(procs, cases + refused):
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == code, (args, err[-2000:])
        lines = (out if code == 0 else err).strip().splitlines()
        assert len(lines) == 1 and message in lines[0], (args, out, err[-2000:])
        assert code == 0 or lines[0].startswith("error: ")
        assert code != 0 or lines[0].startswith("[epoet] config OK: algo=epoet seed=0 budget=smoke")
    assert not (tmp / "checked").exists() and not (tmp / "new").exists()
    assert not (tmp / "fresh" / "mlflow.db").exists()  # a check makes no store
    assert (tmp / "existing" / "notes.txt").read_text() == "mine"
    assert checkpoint.read_bytes() == saved
    assert _runs(uri) == before


def _mount(point: Path, options: str) -> None:
    point.mkdir()
    if (
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(point)], capture_output=True
        ).returncode
        != 0
    ):
        pytest.skip("mounting a tmpfs needs CAP_SYS_ADMIN")


def test_a_read_only_output_folder_and_a_full_disk_are_one_line_errors(good) -> None:
    tmp, uri = good
    read_only, full = tmp / "read_only", tmp / "full"
    _mount(read_only, "size=1m,ro")
    _mount(full, "size=64k")  # room for Hydra's files, not for the first checkpoint
    try:
        before = _runs(uri)
        proc = _epoet([*SMOKE, f"hydra.run.dir={read_only}/run"], tmp, uri)
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 2 and err.strip().splitlines() == [err.strip()], err[-2000:]
        assert "Read-only file system" in err
        assert _runs(uri) == before

        # The default network: a checkpoint (~110 kB) larger than the disk.
        proc = _epoet(
            [
                *[a for a in SMOKE if not a.startswith("algo.es")],
                "checkpoint_every=1",
                f"hydra.run.dir={full}/run",
            ],
            tmp,
            uri,
        )
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 2 and err.strip().splitlines() == [err.strip()], err[-2000:]
        assert "cannot save checkpoint" in err and "No space left on device" in err
        assert not [p for p in (full / "run").iterdir() if "checkpoint" in p.name]
        new = {k: v for k, v in _runs(uri).items() if k not in before}
        assert list(new.values()) == ["FAILED"]  # its own new run, nobody else's
        assert {k: _runs(uri)[k] for k in before} == before
    finally:
        for point in (read_only, full):
            subprocess.run(["umount", "-l", str(point)], check=False)


# Every other command's bad input, as users type it: per command a missing file, a wrong type
# (or a malformed value) and an unknown key, set and `+`added; a misspelt suite where one is
# read (SUITE_TYPO: the suites there are, and the one meant). {tmp}: a scratch folder.
RECORDS = Path(__file__).resolve().parent.parent / "docs" / "results"
SUITE_TYPO = "there is no suite papre: a suite is shipped, paper, admitted or a suite folder; did you mean paper?"
COMMAND_ROWS = [
    ("epoet.eval.evaluate", "missing", ["run={tmp}/missing"], "missing: there is no such file"),
    ("epoet.eval.evaluate", "type", ["run=x", "episodes=abc"], "converted to Integer"),
    ("epoet.eval.evaluate", "key", ["run=x", "episode=3"], "key episode: did you mean episodes?"),
    ("epoet.eval.evaluate", "added", ["run=x", "+episode=3"], "did you mean episodes?"),
    ("epoet.eval.evaluate", "unknown", ["run=x", "bogus=1"], "bogus: the top-level keys are run,"),
    ("epoet.eval.evaluate", "suite", ["run=reference:sac/42", "suite=papre"], SUITE_TYPO),
    (
        "epoet.eval.render",
        "missing",
        ["run={tmp}/missing", "terrain=r0l0"],
        "no such file or folder",
    ),
    ("epoet.eval.render", "type", ["run=x", "terrain=r0l0", "width=abc"], "converted to Integer"),
    ("epoet.eval.render", "key", ["run=x", "widht=3"], "unknown key widht: did you mean width?"),
    ("epoet.eval.render", "added", ["run=x", "+widht=3"], "unknown key widht: did you mean width?"),
    (
        "epoet.eval.suite",
        "missing",
        ["check=true", "out={tmp}/missing"],
        "no folder {tmp}/missing exists",
    ),
    ("epoet.eval.suite", "type", ["seed=abc"], "converted to Integer"),
    ("epoet.eval.suite", "key", ["sed=1"], "unknown key sed: did you mean seed?"),
    ("epoet.eval.suite", "added", ["+sed=1", "check=true"], "unknown key sed: did you mean seed?"),
    ("epoet.eval.gallery", "missing", ["out={tmp}/a_file/gallery"], "Not a directory"),
    ("epoet.eval.gallery", "type", ["n=abc"], "converted to Integer"),
    ("epoet.eval.gallery", "key", ["terain=bowl"], "unknown key terain: did you mean terrain?"),
    ("epoet.eval.gallery", "added", ["+terain=bowl"], "unknown key terain: did you mean terrain?"),
    ("epoet.eval.reference", "missing", ["source={tmp}/missing"], "is not a copy of the authors'"),
    ("epoet.eval.reference", "type", ["source=x", "check=maybe"], "'maybe' is not a valid bool"),
    ("epoet.eval.reference", "key", ["sorce=x"], "unknown key sorce: did you mean source?"),
    ("epoet.eval.reference", "added", ["+sorce=x"], "unknown key sorce: did you mean source?"),
    ("analysis.tables", "suite", ["--suite", "papre"], SUITE_TYPO),
    ("analysis.success_vs_compute", "suite", ["--records", "r", "--suite", "papre"], SUITE_TYPO),
    ("analysis.figures", "suite", ["--suite", "papre"], SUITE_TYPO),
    ("analysis.paper_report", "suite", ["--records", "r", "--suites", "papre"], SUITE_TYPO),
    (
        "analysis.paper_report",
        "missing",
        ["--records", "{tmp}/missing", "--suites", "shipped"],
        "there is no records folder",
    ),
    ("analysis.paper_report", "type", ["--records"], "expected one argument"),
    ("analysis.paper_report", "key", ["--records", "r", "--bogus"], "unrecognized arguments"),
    ("pipeline.paper", "suite", ["--suites", "papre"], SUITE_TYPO),
    ("pipeline.reference", "suite", ["--suite", "papre"], SUITE_TYPO),
    ("analysis.tables", "missing", ["--records", "{tmp}/missing"], "there is no records folder"),
    ("analysis.tables", "type", ["--run"], "expected at least one argument"),
    ("analysis.tables", "key", ["--bogus"], "unrecognized arguments: --bogus"),
    (
        "analysis.success_vs_compute",
        "missing",
        ["--records", "{tmp}/missing"],
        "there is no records folder",
    ),
    ("analysis.success_vs_compute", "type", ["--records"], "expected one argument"),
    (
        "analysis.success_vs_compute",
        "key",
        ["--records", "r", "--bogus"],
        "unrecognized arguments: --bogus",
    ),
    (
        "analysis.figures",
        "missing",
        ["--suite", "{tmp}/missing"],
        "there is no suite {tmp}/missing",
    ),
    ("analysis.figures", "type", ["--run"], "expected at least one argument"),
    ("analysis.figures", "key", ["--bogus"], "unrecognized arguments: --bogus"),
    ("analysis.curves", "missing", [], "there is no MLflow store"),
    ("analysis.curves", "type", ["--run"], "expected at least one argument"),
    ("analysis.curves", "key", ["--bogus"], "unrecognized arguments: --bogus"),
    ("pipeline.paper", "missing", ["--suites", "{tmp}/missing"], "there is no suite {tmp}/missing"),
    ("pipeline.paper", "type", ["--jobs", "abc"], "invalid int value: 'abc'"),
    # (checked per job: a baseline's budget has no iterations)
    ("pipeline.paper", "key", ["budget.iteration=3"], "unknown key budget.iteration: "),
    ("pipeline.paper", "added", ["+budget.iteration=3"], "unknown key budget.iteration: "),
    ("pipeline.records", "missing", ["--experiment", "e", "--out", "o"], "no MLflow store"),
    ("pipeline.records", "type", ["--experiment", "e", "--out", "o", "--run"], "expected at"),
    ("pipeline.records", "key", ["--experiment", "e", "--out", "o", "--bogus"], "unrecognized"),
    (
        "pipeline.snapshots",
        "missing",
        ["--runs", "{tmp}/missing", "--out", "o"],
        "not a run folder",
    ),
    ("pipeline.snapshots", "type", ["--runs", "r", "--out", "o", "--episodes", "x"], "invalid int"),
    ("pipeline.snapshots", "key", ["--runs", "r", "--out", "o", "--bogus"], "unrecognized"),
    ("pipeline.choose", "missing", ["--records", "{tmp}/missing"], "is not a record"),
    ("analysis.levers", "missing", ["--base", "{tmp}/missing"], "holds no records of epoet"),
    ("analysis.levers", "type", ["--base"], "expected one argument"),
    ("analysis.levers", "key", ["--base", "b", "--bogus"], "unrecognized arguments: --bogus"),
    (
        "analysis.levers",
        "suite",
        ["--base", str(RECORDS / "levers" / "reference"), "--suite", "papre"],
        "no snapshot of reference is evaluated on suite papre",
    ),
    ("pipeline.choose", "type", ["--records", "r", "--episodes", "x"], "invalid int"),
    ("pipeline.choose", "key", ["--records", "r", "--bogus"], "unrecognized"),
    ("pipeline.stamp", "missing", ["--records", "{tmp}/missing"], "there is no records folder"),
    ("pipeline.stamp", "type", ["--records"], "expected one argument"),
    ("pipeline.stamp", "key", ["--records", "r", "--bogus"], "unrecognized"),
    (
        "pipeline.reference",
        "missing",
        ["--suite", "{tmp}/missing"],
        "there is no suite {tmp}/missing",
    ),
    ("pipeline.reference", "type", ["--episodes", "abc"], "invalid int value: 'abc'"),
    ("pipeline.reference", "key", ["--bogus"], "unrecognized arguments: --bogus"),
    (
        "pipeline.epoet_sac_starts",
        "missing",
        ["--sac-run", "{tmp}/missing"],
        "missing: there is no such folder",
    ),
    ("pipeline.epoet_sac_starts", "type", ["--jobs", "abc"], "invalid int value: 'abc'"),
    # (its first job is the SAC run, whose algo has no sac_init)
    ("pipeline.epoet_sac_starts", "key", ["algo.sac_int=null"], "unknown key algo.sac_int: "),
    ("pipeline.epoet_sac_starts", "added", ["+algo.sac_int=null"], "unknown key algo.sac_int: "),
]


def test_every_command_answers_bad_input_in_one_line(tmp_path, monkeypatch, capsys) -> None:
    """Each command (every entry point but `python -m epoet`, whose rows are above) refuses a
    missing file, a wrong type and an unknown key in one line on stderr with exit 2, writing
    nothing. Called in this process (each command's `main(argv)`, as `python -m` calls it):
    an exception other than the exit would fail the test with its traceback."""
    from test_help import entry_points

    commands = {module for module, *_ in COMMAND_ROWS}
    assert commands | {"epoet"} == set(entry_points())  # a new command needs its rows
    for module in commands:
        kinds = {kind: args for m, kind, args, _ in COMMAND_ROWS if m == module}
        assert {"key", "missing", "type"} <= kinds.keys(), module
        if "=" in kinds["key"][-1]:  # key=value settings: a `+key` typo is refused too
            assert "+" + kinds["key"][-1] in kinds["added"], module
    (tmp_path / "a_file").write_text("not a folder")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path}/no_store/mlflow.db")
    monkeypatch.chdir(tmp_path)
    for module, kind, args, message in COMMAND_ROWS:
        main = importlib.import_module(MAINS.get(module, module)).main
        with monkeypatch.context() as each:  # `source=` sets EPOET_3D: undone on leaving
            each.setenv(ENV, os.environ.get(ENV, ""))  # empty: unset
            with pytest.raises(SystemExit) as exited:
                raise SystemExit(main([a.format(tmp=tmp_path) for a in args]))
        lines = capsys.readouterr().err.strip().splitlines()
        assert exited.value.code == 2, (module, kind, lines)
        assert len(lines) == 1 and lines[0].startswith("error: "), (module, kind, lines)
        assert message.format(tmp=tmp_path) in lines[0], (module, kind, lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]  # nothing written


MAINS = {"epoet.eval.reference": "epoet.eval.reference.convert"}  # its __main__.py calls it
