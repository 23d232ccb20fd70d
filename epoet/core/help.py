"""`--help` for every command, built from what the command already states once: its module
docstring (the first paragraph says what it does, an `Examples:` block shows it in use), its
options (a schema's field comments, or argparse's help strings) and their defaults (the
command's YAML, or argparse's defaults). Nothing is written twice, so help cannot drift from
the code.

Two kinds of command share it: key=value commands composed by Hydra (`python -m epoet`,
`epoet.eval.*`: `options_table` and `field_comments`) and flag commands (`analysis.*`,
`pipeline.*`: `HelpParser`, an argparse parser whose errors are one line and exit 2 too).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import inspect
import os
import re
import sys
import textwrap
from collections.abc import Iterator, Sequence
from typing import Any, NoReturn

HELP_FLAGS = ("-h", "--help")
_FIELD = re.compile(r"^    (\w+):[^#]*?(?:#\s*(.*))?$")  # `    name: type [= default]  # comment`
_CONTINUED = re.compile(r"^    #\s*(.*)$")  # a comment line right below a field continues it


def asks_for_help(argv: Sequence[str]) -> bool:
    return any(arg in HELP_FLAGS for arg in argv)


@contextlib.contextmanager
def reader_may_leave() -> Iterator[None]:
    """Output a reader may stop reading early (`--help | head -1`): its closed pipe ends the
    command quietly with exit 0, as the reader chose, instead of a BrokenPipeError traceback
    (or Python's "Exception ignored" when it flushes stdout at exit)."""
    try:
        yield
        sys.stdout.flush()
    except BrokenPipeError:
        _drop_stdout()
        sys.exit(0)
    except SystemExit:  # the command's own exit: flush what it printed before it goes
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _drop_stdout()
        raise


def _drop_stdout() -> None:
    """Point stdout at /dev/null, so the flush at exit finds no closed pipe."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def print_and_exit(text: str) -> NoReturn:
    """Print a help page (or a version) and exit 0, whether or not the reader reads it all."""
    with reader_may_leave():
        print(text)
    sys.exit(0)


def summary(doc: str | None) -> str:
    """The first paragraph of a docstring, joined into one text."""
    paragraphs = inspect.cleandoc(doc or "").split("\n\n")
    return " ".join(line.strip() for line in paragraphs[0].splitlines())


def examples(doc: str | None) -> list[str]:
    """The indented lines of the docstring's `Examples:` block."""
    lines = inspect.cleandoc(doc or "").splitlines()
    if "Examples:" not in lines:
        return []
    found: list[str] = []
    for line in lines[lines.index("Examples:") + 1 :]:
        if line.startswith("    ") and line.strip():
            found.append(line.strip())
        elif line.strip() and found:
            break
    return found


def field_comments(schema: type) -> dict[str, str]:
    """Each dataclass field's trailing comment (continued on comment-only lines below it), over
    the schema and its dataclass bases: the one-line description a user reads in `--help`."""
    comments: dict[str, str] = {}
    for cls in reversed(schema.__mro__):
        if not dataclasses.is_dataclass(cls):
            continue
        current = None
        for line in inspect.getsource(cls).splitlines():
            if (more := _CONTINUED.match(line)) and current is not None:
                comments[current] = f"{comments[current]} {more.group(1)}".strip()
            elif match := _FIELD.match(line):
                current = match.group(1)
                comments[current] = (match.group(2) or "").strip()
            else:
                current = None
    names = {f.name for f in dataclasses.fields(schema)}
    return {name: text for name, text in comments.items() if name in names}


WIDTH = 100  # the summary's lines
NAME_WIDTH = 24  # a longer option name puts its description on the next line


def options_table(rows: Sequence[tuple[str, str, str]]) -> str:
    """`name  description (default: value)` lines, the descriptions aligned in one column."""
    width = min(max((len(name) for name, _, _ in rows), default=0), NAME_WIDTH) + 2
    lines = []
    for name, text, default in rows:
        described = f"{text} (default: {default})" if default else text
        if len(name) + 2 > width:
            lines += [f"  {name}", f"  {' ' * width}{described}"]
        else:
            lines.append(f"  {name.ljust(width)}{described}")
    return "\n".join(lines)


def page(usage: str, doc: str | None, sections: Sequence[tuple[str, str]]) -> str:
    """A help page: usage, what the command does, the given sections, then its examples."""
    parts = [
        f"usage: {usage}",
        textwrap.fill(summary(doc), WIDTH, break_on_hyphens=False),
        *(f"{title}:\n{body}" for title, body in sections),
    ]
    if found := examples(doc):
        parts.append("examples:\n" + "\n".join(f"  {line}" for line in found))
    return "\n\n".join(parts)


class _Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """The epilog (examples) keeps its lines; every option's help ends with its default (a
    required option's says so instead)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.required and action.option_strings:
            return f"{action.help} (required)"
        return super()._get_help_string(action)


class HelpParser(argparse.ArgumentParser):
    """argparse for the flag commands: help says what the command does (the docstring's first
    paragraph), each option with its default, and the docstring's examples; a bad argument is
    one line on stderr and exit code 2, as every error a user can cause."""

    def __init__(self, prog: str, doc: str | None) -> None:
        found = examples(doc)
        super().__init__(
            prog=prog,
            description=textwrap.fill(summary(doc), WIDTH, break_on_hyphens=False),
            epilog="examples:\n" + "\n".join(f"  {line}" for line in found) if found else None,
            formatter_class=_Formatter,
        )

    def print_help(self, file: Any = None) -> None:
        with reader_may_leave():
            super().print_help(file)

    def error(self, message: str) -> NoReturn:
        print(f"error: {message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(2)
