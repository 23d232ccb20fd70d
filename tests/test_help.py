"""`--help` and `-h` on every entry point: the commands are found by walking the packages
(a module with `if __name__ == "__main__":`, or a package's `__main__.py`), so a new command
cannot be left out. Each help exits 0 and lists every option the command reads, each with a
description, and shows examples; `python -m epoet --help` lists only the choices a user has."""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import io
import os
import re
import runpy
import subprocess
import sys
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from epoet.cli import KeyValueCommand
from epoet.registry import names

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("epoet", "analysis", "pipeline")
WIDTH = "100"  # the terminal the helps are printed for


def entry_points() -> list[str]:
    """Every `python -m <module>` command of the packages."""
    found = set()
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__main__":
                found.add(".".join(parts[:-1]))
            elif 'if __name__ == "__main__":' in path.read_text():
                found.add(".".join(parts))
    return sorted(found)


def run(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": WIDTH},
        timeout=240,
    )


def run_here(module: str, *args: str) -> subprocess.CompletedProcess:
    """`python -m <module> <args>` inside this process, the way `python -m` runs it (runpy, as
    `__main__`), its output captured: an argparse or key=value command's help needs no process of
    its own, only its parser (what each command imports is this process's already)."""
    out, err = io.StringIO(), io.StringIO()
    argv, columns, code = sys.argv, os.environ.get("COLUMNS"), 0
    sys.argv, os.environ["COLUMNS"] = [module, *args], WIDTH
    try:
        with (
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            warnings.catch_warnings(),
        ):
            # runpy's note that the module was imported before (by another command): it is run
            # afresh as __main__ all the same
            warnings.filterwarnings("ignore", "'.*' found in sys.modules", RuntimeWarning)
            runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as done:
        code = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    finally:
        sys.argv = argv
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns
    return subprocess.CompletedProcess([module, *args], code, out.getvalue(), err.getvalue())


# `-h` is `--help` by the parser each kind of command shares (Hydra's, KeyValueCommand's,
# HelpParser's): it is run on one command of each kind, as its own process, and compared with
# the `--help` run in this one, so the in-process help is the one a user sees.
SHORT = ("epoet", "epoet.eval.evaluate", "analysis.tables")
pytestmark = pytest.mark.timeout(600)  # a few commands' imports on a shared machine


@pytest.fixture(scope="module")
def helps() -> dict[tuple[str, str], subprocess.CompletedProcess]:
    """Each entry point's `--help` (and `-h` of SHORT). Hydra's (`python -m epoet`) composes in
    its own process, as do the `-h` calls, two at a time (each waits on its imports); every
    other `--help` runs here."""
    apart = [("epoet", "--help")] + [(m, "-h") for m in SHORT]
    with ThreadPoolExecutor(2) as pool:
        found = dict(zip(apart, pool.map(lambda call: run(*call), apart)))
        found |= {(m, "--help"): run_here(m, "--help") for m in entry_points() if m != "epoet"}
    return found


def run_unread(module: str, *args: str) -> subprocess.CompletedProcess:
    """The command with a stdout nobody reads (`--help | head -1` once head has gone): a pipe
    whose reading end is closed before the command starts, so every write to it fails."""
    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run(
            [sys.executable, "-m", module, *args],
            cwd=ROOT,
            stdout=write,
            stderr=subprocess.PIPE,
            text=True,
            timeout=240,
        )
    finally:
        os.close(write)


@pytest.fixture(scope="module")
def unread() -> dict[tuple[str, ...], subprocess.CompletedProcess]:
    """`--help` of one command of each kind (SHORT: each kind prints its help through its
    parser's one writer, and `helps` checks that every command's stdout is that help alone),
    `python -m epoet --version` and `--cfg job`, unread."""
    calls = [(module, "--help") for module in SHORT]
    calls += [("epoet", "--version"), ("epoet", "--cfg", "job")]
    with ThreadPoolExecutor(2) as pool:
        return dict(zip(calls, pool.map(lambda call: run_unread(*call), calls)))


def key_value_command(module: str) -> KeyValueCommand | None:
    """The command's KeyValueCommand, if it is one (the reference's is in its convert module)."""
    imported = importlib.import_module(
        module if module != "epoet.eval.reference" else f"{module}.convert"
    )
    return getattr(imported, "COMMAND", None)


def kind_of(module: str) -> str:
    """Which parser reads the command's arguments: Hydra's, KeyValueCommand's or HelpParser's."""
    if module == "epoet":
        return "hydra"
    return "key=value" if key_value_command(module) is not None else "argparse"


def test_short_holds_one_command_of_each_kind():
    assert sorted(kind_of(m) for m in SHORT) == sorted({kind_of(m) for m in entry_points()})


def options_of(module: str, text: str) -> list[str]:
    """What the command's help must list: the run's groups and top-level keys (`python -m
    epoet`), a KeyValueCommand's schema fields, or every option of an argparse command's usage
    line (argparse builds it from the parser's own options)."""
    from epoet.config import Config

    if module == "epoet":
        return [f"{f.name}=" for f in dataclasses.fields(Config)]
    if (command := key_value_command(module)) is not None:
        return [f"{f.name}" for f in dataclasses.fields(command.schema)]
    usage = text.split("\n\n")[0]
    options = re.findall(r"\[(--[\w-]+)|\s(--[\w-]+) ", usage)
    positional = re.findall(r"\[([a-z_]+) \.\.\.\]", usage)  # metavars are upper case
    return [a or b for a, b in options if (a or b) != "--help"] + positional


def entry(text: str, option: str) -> str:
    """The help's entry of an option: its line and the lines wrapped below it."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.strip().startswith(option)), None)
    assert start is not None, f"no entry for {option}"
    block = [lines[start]]
    for line in lines[start + 1 :]:
        if not line.startswith("    ") or not line.strip():  # the next entry, or the end
            break
        block.append(line)
    return " ".join(" ".join(block).split())


def test_the_walk_finds_every_kind_of_command():
    found = entry_points()
    for module in ("epoet", "epoet.eval.evaluate", "epoet.eval.reference", "analysis.tables"):
        assert module in found
    assert "pipeline.paper" in found and len(found) >= 13


@pytest.mark.parametrize("module", entry_points())
def test_help_lists_every_option_with_a_description_and_examples(helps, module):
    for flag in ("--help", "-h") if module in SHORT else ("--help",):
        done = helps[(module, flag)]
        assert done.returncode == 0, (module, flag, done.stderr[-2000:])
        assert not done.stderr.strip(), (module, flag, done.stderr[-2000:])
        assert done.stdout == helps[(module, "--help")].stdout
    text = helps[(module, "--help")].stdout
    assert text.startswith("usage: ")
    assert "examples:\n" in text and f"python -m {module} " in text.split("examples:\n")[1]
    for option in options_of(module, text):
        described = entry(text, option)
        assert re.search(r"\(default: .+\)|\(required\)", described), (module, described)
        assert len(described.split()) >= 5, (module, described)  # the option and what it is


def test_the_run_help_lists_only_what_a_user_chooses(helps):
    text = helps[("epoet", "--help")].stdout
    for internal in ("_schema", "algo_budget", "learner", "hydra/job_logging"):
        assert internal not in text, internal
    assert f"algo={'|'.join(sorted(names()))}" in text  # every registered algorithm
    assert "budget=laptop|paper|smoke|workstation" in text
    assert "check=" in text and "python -m epoet check=true" in text


def test_evaluate_says_it_writes_into_the_working_directory(helps):
    text = helps[("epoet.eval.evaluate", "--help")].stdout
    assert "./evaluation/<run>/<suite> in the working directory" in " ".join(text.split())


def test_help_whose_reader_leaves_ends_quietly_with_exit_0(unread):
    """A reader that stops early (`| head -1`) chose to: no BrokenPipeError traceback, no
    "Exception ignored" at exit, exit 0."""
    for call, done in unread.items():
        assert done.returncode == 0 and not done.stderr, (call, done.returncode, done.stderr)
