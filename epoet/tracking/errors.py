"""The one error tracking raises, and how an MLflow failure becomes one line of it."""

from __future__ import annotations

import re

from epoet.core.errors import first_line


class TrackingError(ValueError):
    """A tracking store or call that cannot work; the message is one sentence."""


_ROOT_CAUSE = re.compile(r"\[Errno -?\d+\][^\"')\n]*|(?:Read|Connect) timed out")


def reason(exc: BaseException) -> str:
    """The gist of an exception for a one-line error: its root cause if found, else first line.

    MLflow's HTTP errors bury e.g. "[Errno 111] Connection refused" or "Read timed out" deep in
    a long message.
    """
    text = str(exc).strip()
    if found := _ROOT_CAUSE.search(text):
        return found.group(0).strip()
    text = first_line(exc)
    return text if len(text) <= 300 else text[:297] + "..."
