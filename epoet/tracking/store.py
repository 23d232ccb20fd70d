"""Where the MLflow store is and whether it works: a bad store fails before any training.

The store is the explicit `tracking_uri`, else env MLFLOW_TRACKING_URI, else
`sqlite:///<folder the command started in>/mlflow.db` as an absolute path: beside the run folders
(outputs/, multirun/ are made there too), wherever the package is installed (an editable clone
elsewhere, or site-packages), and the same for every job of a sweep (Hydra's original working
directory), so per-job folders never scatter stores.
"""

from __future__ import annotations

import functools
import os
import random
import sqlite3
import time
from contextlib import closing
from pathlib import Path
from typing import Any

from mlflow import MlflowClient

from epoet.core.environ import environ_defaults
from epoet.tracking.errors import TrackingError, reason

PROJECT_ROOT = Path(__file__).resolve().parents[2]  # the code's checkout (its git commit)
STORE_FILE = "mlflow.db"
# The start-up probe must fail in seconds: MLflow's defaults retry for minutes.
_PROBE_ENV = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0", "MLFLOW_HTTP_REQUEST_TIMEOUT": "5"}


def started_in() -> Path:
    """The folder the command was started from: Hydra's original working directory inside a
    Hydra job (a launcher may run a job elsewhere), else the working directory."""
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.cwd)
    return Path.cwd()


def default_tracking_uri() -> str:
    """sqlite:///<the folder the command started in>/mlflow.db, as an absolute path."""
    return f"sqlite:///{started_in().absolute() / STORE_FILE}"


def resolve_tracking_uri(tracking_uri: str | None = None) -> str:
    """Explicit URI, else env MLFLOW_TRACKING_URI, else the default store (`default_tracking_uri`)."""
    return tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()


def sqlite_path(uri: str) -> Path | None:
    """The database file of a `sqlite:///` URI (relative paths are relative to the cwd)."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///") :].split("?", 1)[0]
    return None if path in ("", ":memory:") else Path(path).absolute()


def _check_sqlite(uri: str, db: Path) -> None:
    """Fail fast on a local database MLflow cannot use.

    MLflow would silently create missing directories (a typo in the URI must not start a new
    store somewhere unexpected) and retries a bad database file for ~100 s before giving up.
    """
    problem = None
    if not db.parent.exists():
        problem = f"directory {db.parent} does not exist"
    elif not db.parent.is_dir():
        problem = f"{db.parent} is not a directory"
    elif not os.access(db.parent, os.W_OK):
        problem = f"directory {db.parent} is not writable"
    elif db.is_dir():
        problem = f"{db} is a directory, not a database file"
    elif db.exists():
        try:
            with closing(sqlite3.connect(f"{db.as_uri()}?mode=rw", uri=True, timeout=5)) as con:
                con.execute("PRAGMA schema_version")
        except sqlite3.Error as exc:
            problem = f"{db} is not a usable sqlite database ({exc})"
    if problem:
        raise TrackingError(f"cannot open MLflow store {uri}: {problem}.")


class RetryingClient:
    """An MlflowClient whose calls retry, with jittered exponential backoff, while sqlite says
    "database is locked": the parallel jobs of a sweep (hydra/launcher=joblib) write one store,
    and sqlite lets one writer in at a time. A locked call rolled back, so trying it again is
    safe; any other error is raised at once."""

    ATTEMPTS = 10
    FIRST_DELAY = 0.05  # seconds; doubles per attempt (about 50 s in all, beyond sqlite's own 5 s)

    def __init__(self, client: MlflowClient) -> None:
        self._client = client

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "_client":  # e.g. while a launcher unpickles it
            raise AttributeError(name)
        attr = getattr(self._client, name)
        if not callable(attr):
            return attr

        @functools.wraps(attr)
        def call(*args: Any, **kwargs: Any) -> Any:
            delay = self.FIRST_DELAY
            for attempt in range(1, self.ATTEMPTS + 1):
                try:
                    return attr(*args, **kwargs)
                except Exception as exc:
                    if "database is locked" not in str(exc) or attempt == self.ATTEMPTS:
                        raise
                    time.sleep(delay * (1.0 + random.random()))
                    delay *= 2

        return call


def open_store(tracking_uri: str | None = None) -> MlflowClient:
    """Connect to the store and prove it answers, so a bad store fails before any training."""
    uri = resolve_tracking_uri(tracking_uri)
    db = sqlite_path(uri)
    if db is not None:
        _check_sqlite(uri, db)
    try:
        with environ_defaults(_PROBE_ENV):  # MLflow gives up fast, unless the user tuned it
            client = RetryingClient(MlflowClient(uri))
            client.search_experiments(max_results=1)
    except Exception as exc:  # any failure here means the store is unusable
        raise TrackingError(f"cannot open MLflow store {uri}: {reason(exc)}") from exc
    return client  # type: ignore[return-value]  # an MlflowClient in all but retries


def check_store(tracking_uri: str | None = None) -> str:
    """What `open_store` proves, without creating anything (`check=true`): a sqlite file that
    does not exist yet is checked for the folder it would be made in, not made. The URI."""
    uri = resolve_tracking_uri(tracking_uri)
    db = sqlite_path(uri)
    if db is not None and not db.exists():
        _check_sqlite(uri, db)
    else:
        open_store(uri)
    return uri


def ui_hint(tracking_uri: str, experiment_id: str) -> str:
    """The command that serves the store and the URL of the experiment's runs table (MLflow
    3's UI opens on a GenAI overview without `workflowType`)."""
    return (
        f"mlflow ui --backend-store-uri {tracking_uri}  then open http://127.0.0.1:5000/"
        f"#/experiments/{experiment_id}/runs?workflowType=machine_learning"
    )
