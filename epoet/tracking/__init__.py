"""Experiment tracking: the only package that imports mlflow.

- writer.py: `Tracker`, what algorithms report to, and `MlflowTracker`, the run that records it
- stored_run.py: `StoredRun`, a finished run read and added to by evaluation, videos, analysis
- store.py: where the store is (`resolve_tracking_uri`) and proof that it works (`open_store`)
- provenance.py: the config as params, the git commit, the sweep's parent run
- inputs.py: metric keys, steps, values and artifact paths, checked before anything is sent
- errors.py: `TrackingError`, one sentence

Importers use `from epoet.tracking import X`: importing a submodule runs this file anyway.
"""
from mlflow.entities import Run  # for type hints in modules that do not import mlflow

from epoet.tracking.errors import TrackingError
from epoet.tracking.inputs import metric_key
from epoet.tracking.provenance import PARENT_RUN_ENV, flatten, git_commit, parent_run_id
from epoet.tracking.store import (
    DEFAULT_TRACKING_URI,
    PROJECT_ROOT,
    open_store,
    resolve_tracking_uri,
    sqlite_path,
    ui_hint,
)
from epoet.tracking.stored_run import StoredRun
from epoet.tracking.writer import MlflowTracker, Tracker

__all__ = [
    "DEFAULT_TRACKING_URI", "PARENT_RUN_ENV", "PROJECT_ROOT", "MlflowTracker", "Run", "StoredRun",
    "Tracker", "TrackingError", "flatten", "git_commit", "metric_key", "open_store",
    "parent_run_id", "resolve_tracking_uri", "sqlite_path", "ui_hint",
]
