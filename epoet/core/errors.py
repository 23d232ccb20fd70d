"""One-line errors: every command reports bad input as one sentence, whatever raised it."""

from __future__ import annotations


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its type's name if it has none."""
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]
