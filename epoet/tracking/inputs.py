"""What callers hand a tracker, checked and made MLflow-valid before anything is sent: metric
keys, steps and values, artifact paths. A bad input is a TrackingError at the call that made it,
not an MLflow error at some later flush."""

from __future__ import annotations

import numbers
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mlflow.utils.validation import MAX_ENTITY_KEY_LENGTH

from epoet.tracking.errors import TrackingError

_BAD_KEY_CHARS = re.compile(r"[^A-Za-z0-9_.\- /]")


def metric_key(name: str) -> str:
    """Map a metric or param name to an MLflow-valid key, deterministically.

    MLflow allows alphanumerics, `_ - . /` and spaces (plus `:` off Windows; we drop it so a store
    stays portable), and the key must be a normalised relative path: no empty, `.` or `..`
    segments, no leading or trailing slash. "pair/0/return_mean" passes unchanged.
    """
    segments = [s for s in _BAD_KEY_CHARS.sub("_", str(name)).split("/") if s]
    segments = ["_" * len(s) if s in (".", "..") else s for s in segments]
    key = "/".join(segments)[:MAX_ENTITY_KEY_LENGTH].rstrip("/")
    if not key:
        raise TrackingError(f"name {name!r} has no characters MLflow accepts in a key.")
    return key


def metric_points(step: int, metrics: Mapping[str, Any]) -> tuple[int, list[tuple[str, float]]]:
    """Validate one `log_metrics` call.

    numpy integers count as steps: iteration counters often are.
    """
    if isinstance(step, bool) or not isinstance(step, numbers.Integral) or step < 0:
        raise TrackingError(f"step must be a non-negative int, got {step!r}.")
    points = []
    for name, value in metrics.items():
        key = metric_key(name)
        try:
            points.append((key, float(value)))
        except (TypeError, ValueError) as exc:
            raise TrackingError(f"metric {name!r} must be a number, got {value!r}.") from exc
    return int(step), points


def existing_path(path: str | Path) -> Path:
    """The artifact's path, or a one-sentence error if there is nothing to upload."""
    path = Path(path)
    if not path.exists():
        raise TrackingError(f"artifact {path} does not exist.")
    return path
