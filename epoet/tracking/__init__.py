"""Experiment tracking: the only package that imports mlflow.

- writer.py: `Tracker`, what algorithms report to, and `MlflowTracker`, the run that records it
- stored_run.py: `StoredRun`, a finished run read and added to by evaluation, videos, analysis
- store.py: where the store is (`resolve_tracking_uri`) and proof that it works (`open_store`,
  `check_store`)
- provenance.py: the config as params, the git commit, the sweep's parent run
- inputs.py: metric keys, steps, values and artifact paths, checked before anything is sent
- errors.py: `TrackingError`, one sentence

Importers use `from epoet.tracking import X`. Each name is imported from its module when first
asked for (PEP 562), so `TrackingError` costs nothing while `MlflowTracker` brings mlflow (a slow
import): a command that fails on bad input before it tracks anything never waits for mlflow.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # `X as X`: re-exported names (for the type checker; __getattr__ at run time)
    from mlflow.entities import Run as Run

    from epoet.tracking.errors import TrackingError as TrackingError
    from epoet.tracking.inputs import metric_key as metric_key
    from epoet.tracking.provenance import PARENT_RUN_ENV as PARENT_RUN_ENV
    from epoet.tracking.provenance import flatten as flatten
    from epoet.tracking.provenance import git_commit as git_commit
    from epoet.tracking.provenance import parent_run_id as parent_run_id
    from epoet.tracking.store import PROJECT_ROOT as PROJECT_ROOT
    from epoet.tracking.store import check_store as check_store
    from epoet.tracking.store import default_tracking_uri as default_tracking_uri
    from epoet.tracking.store import open_store as open_store
    from epoet.tracking.store import resolve_tracking_uri as resolve_tracking_uri
    from epoet.tracking.store import sqlite_path as sqlite_path
    from epoet.tracking.store import ui_hint as ui_hint
    from epoet.tracking.stored_run import StoredRun as StoredRun
    from epoet.tracking.writer import MlflowTracker as MlflowTracker
    from epoet.tracking.writer import Tracker as Tracker
    from epoet.tracking.writer import close_killed as close_killed

_HOME = {
    "TrackingError": "epoet.tracking.errors",
    "metric_key": "epoet.tracking.inputs",
    "PARENT_RUN_ENV": "epoet.tracking.provenance",
    "flatten": "epoet.tracking.provenance",
    "git_commit": "epoet.tracking.provenance",
    "parent_run_id": "epoet.tracking.provenance",
    "default_tracking_uri": "epoet.tracking.store",
    "PROJECT_ROOT": "epoet.tracking.store",
    "check_store": "epoet.tracking.store",
    "open_store": "epoet.tracking.store",
    "resolve_tracking_uri": "epoet.tracking.store",
    "sqlite_path": "epoet.tracking.store",
    "ui_hint": "epoet.tracking.store",
    "StoredRun": "epoet.tracking.stored_run",
    "MlflowTracker": "epoet.tracking.writer",
    "close_killed": "epoet.tracking.writer",
    "Tracker": "epoet.tracking.writer",
    "Run": "mlflow.entities",
}  # for type hints in modules that do not import mlflow

__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(_HOME[name]), name)
    globals()[name] = value  # once
    return value
