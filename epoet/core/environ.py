"""Environment variables set for a while: libraries that read their timeouts from the environment
(MLflow's HTTP client, Ray's GCS client in a child process) are told to give up fast where this
product knows a slow answer means no answer."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def environ_defaults(defaults: dict[str, str]) -> Iterator[None]:
    """os.environ with `defaults` for the keys it lacks (a user's own values win), as it was
    again on exit."""
    added = {key: value for key, value in defaults.items() if key not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)
