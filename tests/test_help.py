"""`--help` and `-h` on every entry point: the commands are found by walking the packages
(a module with `if __name__ == "__main__":`, or a package's `__main__.py`), so a new command
cannot be left out. Each help exits 0 and lists every option the command reads, each with a
description, and shows examples; `python -m epoet --help` lists only the choices a user has."""

from __future__ import annotations

import dataclasses
import importlib
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("epoet", "analysis", "pipeline")


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
        env={**os.environ, "COLUMNS": "100"},
        timeout=240,
    )


# `-h` is `--help` by the parser each kind of command shares (Hydra's, KeyValueCommand's,
# HelpParser's): it is run on one command of each kind.
SHORT = ("epoet", "epoet.eval.evaluate", "analysis.tables")
pytestmark = pytest.mark.timeout(900)  # about 16 commands' imports on a shared machine


@pytest.fixture(scope="module")
def helps() -> dict[tuple[str, str], subprocess.CompletedProcess]:
    """Each entry point's `--help` (and `-h` of SHORT), two at a time (each waits on its
    imports)."""
    calls = [(module, "--help") for module in entry_points()] + [(m, "-h") for m in SHORT]
    with ThreadPoolExecutor(2) as pool:
        return dict(zip(calls, pool.map(lambda call: run(*call), calls)))


def options_of(module: str) -> list[str]:
    """What the command's help must list: its argparse options (module.parser() or
    parse_args's parser), its schema's fields (a KeyValueCommand), or the run's groups and
    top-level keys (`python -m epoet`)."""
    from epoet.cli import RUN_GROUPS
    from epoet.config import COMMAND_SCHEMAS, Config

    if module == "epoet":
        return [f"{f.name}=" for f in dataclasses.fields(Config) if f.name not in RUN_GROUPS] + [
            f"{group}=" for group in RUN_GROUPS
        ]
    imported = importlib.import_module(
        module if module != "epoet.eval.reference" else f"{module}.convert"
    )
    command = getattr(imported, "COMMAND", None)
    if command is not None:
        return [f.name for f in dataclasses.fields(COMMAND_SCHEMAS[command.name])]
    parser = _argparse_parser(imported)
    return [a.option_strings[0] if a.option_strings else a.dest for a in parser._actions]


def _argparse_parser(module):
    """The command's HelpParser, caught as its main builds it (`--help` makes it exit)."""
    from epoet.core.help import HelpParser

    made = []
    original = HelpParser.parse_args

    def catch(self, *args, **kwargs):
        made.append(self)
        raise SystemExit(0)

    HelpParser.parse_args = catch  # type: ignore[method-assign]
    try:
        with pytest.raises(SystemExit):
            module.main(["--help"])
    finally:
        HelpParser.parse_args = original  # type: ignore[method-assign]
    assert made, f"{module.__name__} does not build its parser with epoet.core.help.HelpParser"
    return made[0]


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
    for option in options_of(module):
        lines = [line for line in text.splitlines() if line.strip().startswith(option)]
        assert lines, f"{module} --help does not list {option}"
    # each option line has its description and default (argparse may wrap them below it)
    said = len(re.findall(r"\(default:\s|\(required\)", text))  # argparse may wrap them
    assert said >= len(options_of(module)) - 1  # -h/--help has none


def test_the_run_help_lists_only_what_a_user_chooses(helps):
    text = helps[("epoet", "--help")].stdout
    for internal in ("_schema", "algo_budget", "learner", "hydra/job_logging"):
        assert internal not in text, internal
    assert "algo=epoet|epoet_sac|ppo|sac|vmpo" in text
    assert "budget=laptop|paper|smoke|workstation" in text
    assert "check=" in text and "python -m epoet check=true" in text


def test_evaluate_says_it_writes_into_the_working_directory(helps):
    text = helps[("epoet.eval.evaluate", "--help")].stdout
    assert "./evaluation/<run>/<suite> in the working directory" in " ".join(text.split())
