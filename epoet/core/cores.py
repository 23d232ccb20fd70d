"""How many cores this process may use (the default worker count of every pool)."""

from __future__ import annotations

import os


def default_workers() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0))
