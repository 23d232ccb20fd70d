"""Experiment tracking: the only module that imports mlflow.

Algorithms report through the small `Tracker` protocol, which `MlflowTracker` sends to an MLflow
store. Metrics are buffered and sent with `log_batch` because per-point `log_metric` on sqlite
(~195 points/s) would dominate a run.

Store: the explicit `tracking_uri`, else env MLFLOW_TRACKING_URI, else
`sqlite:///<project root>/mlflow.db` as an absolute path, so Hydra's per-job working directories
never scatter stores. A sweep's parent run id reaches each job through EPOET_PARENT_RUN_ID
(set by `epoet.sweep.MlflowSweepCallback`).
"""
from __future__ import annotations

import functools
import logging
import numbers
import os
import random
import re
import sqlite3
import subprocess
import tempfile
import time
import warnings
from collections.abc import Iterator, Mapping
from contextlib import closing, contextmanager
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, runtime_checkable

import numpy as np
from mlflow import MlflowClient
from mlflow.entities import Metric, Param, Run, RunTag
from mlflow.exceptions import MlflowException
from mlflow.utils.mlflow_tags import MLFLOW_GIT_COMMIT, MLFLOW_PARENT_RUN_ID
from mlflow.utils.validation import (
    MAX_ENTITY_KEY_LENGTH,
    MAX_METRICS_PER_BATCH,
    MAX_PARAM_VAL_LENGTH,
    MAX_TAG_VAL_LENGTH,
)

from epoet.errors import first_line
from epoet.lifecycle import Stopped

PROJECT_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_TRACKING_URI = f"sqlite:///{PROJECT_ROOT / 'mlflow.db'}"
PARENT_RUN_ENV = "EPOET_PARENT_RUN_ID"
# The start-up probe must fail in seconds: MLflow's defaults retry for minutes.
_PROBE_ENV = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0", "MLFLOW_HTTP_REQUEST_TIMEOUT": "5"}

log = logging.getLogger(__name__)


class TrackingError(ValueError):
    """A tracking store or call that cannot work; the message is one sentence."""


@runtime_checkable
class Tracker(Protocol):
    """What algorithms report to (implemented by `MlflowTracker`), so they need no mlflow."""

    run_id: str | None

    def log_metrics(self, step: int, metrics: Mapping[str, float]) -> None: ...

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None: ...

    def log_dict(self, obj: Any, artifact_file: str) -> None: ...

    def set_tags(self, tags: Mapping[str, str]) -> None: ...

    def flush(self) -> None: ...

    def close(self, status: str = "FINISHED") -> None: ...


# --- input checks --------------------------------------------------------------------------------

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


def _metric_points(step: int,
                   metrics: Mapping[str, Any]) -> tuple[int, list[tuple[str, float]]]:
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


def _existing_path(path: str | Path) -> Path:
    path = Path(path)
    if not path.exists():
        raise TrackingError(f"artifact {path} does not exist.")
    return path


def flatten(cfg: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Flatten a nested config (e.g. `OmegaConf.to_container(cfg, resolve=True)`) into params.

    Keys are dotted paths; values are str()'d and cut to MLflow's param value limit. Lists stay
    one param (their str()), which keeps long option lists from flooding the params table.
    """
    flat: dict[str, str] = {}
    for key, value in cfg.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            flat.update(flatten(value, prefix=f"{name}."))
        else:
            flat[name] = str(value)[:MAX_PARAM_VAL_LENGTH]
    return flat


def git_commit() -> str:
    """The project's HEAD commit for the run's tags; "unknown" outside a repository."""
    try:
        result = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_ROOT,
                                capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    commit = result.stdout.strip()
    return commit if result.returncode == 0 and commit else "unknown"


def parent_run_id() -> str | None:
    """The sweep's parent run id when this job runs inside a Hydra multirun, else None."""
    return os.environ.get(PARENT_RUN_ENV) or None


def resolve_tracking_uri(tracking_uri: str | None = None) -> str:
    """Explicit URI, else env MLFLOW_TRACKING_URI, else the project's absolute sqlite store."""
    return tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or DEFAULT_TRACKING_URI


def sqlite_path(uri: str) -> Path | None:
    """The database file of a `sqlite:///` URI (relative paths are relative to the cwd)."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///"):].split("?", 1)[0]
    return None if path in ("", ":memory:") else Path(path).absolute()


@contextmanager
def _quick_http() -> Iterator[None]:
    """Temporarily make MLflow's HTTP client give up fast, unless the user tuned it."""
    added = {k: v for k, v in _PROBE_ENV.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


_ROOT_CAUSE = re.compile(r"\[Errno -?\d+\][^\"')\n]*|(?:Read|Connect) timed out")


def _reason(exc: BaseException) -> str:
    """The gist of an exception for a one-line error: its root cause if found, else first line.

    MLflow's HTTP errors bury e.g. "[Errno 111] Connection refused" or "Read timed out" deep in
    a long message.
    """
    text = str(exc).strip()
    if found := _ROOT_CAUSE.search(text):
        return found.group(0).strip()
    text = first_line(exc)
    return text if len(text) <= 300 else text[:297] + "..."


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


class _RetryingClient:
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
        with _quick_http():
            client = _RetryingClient(MlflowClient(uri))
            client.search_experiments(max_results=1)
    except Exception as exc:  # any failure here means the store is unusable
        raise TrackingError(f"cannot open MLflow store {uri}: {_reason(exc)}") from exc
    return client  # type: ignore[return-value]  # an MlflowClient in all but retries


class MlflowTracker:
    """One MLflow run: buffered metrics, params from the flattened config, tags, artifacts.

    Use as a context manager so an exception closes the run as FAILED (KILLED on Ctrl-C):
        with MlflowTracker(experiment="epoet") as tracker:
            tracker.start("ppo-seed1", params=flatten(cfg_dict), parent_run_id=parent_run_id())
    """

    def __init__(self, tracking_uri: str | None = None, experiment: str = "epoet",
                 flush_every: int = MAX_METRICS_PER_BATCH, flush_seconds: float = 10.0) -> None:
        self.tracking_uri = resolve_tracking_uri(tracking_uri)
        self.experiment = experiment
        self.flush_every = flush_every
        self.flush_seconds = flush_seconds
        self.client = open_store(self.tracking_uri)
        self.run_id: str | None = None
        self.experiment_id: str | None = None
        self._buffer: list[Metric] = []
        self._last_flush = time.monotonic()
        self._closed = False
        # A resumed run's last logged step per metric: a run killed after logging some steps
        # resumes from an earlier checkpoint and recomputes them (identically); they are not
        # sent twice.
        self._logged: dict[str, int] = {}

    def __enter__(self) -> MlflowTracker:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self.run_id is None or self._closed:
            return
        if exc_type is None:
            self.close("FINISHED")
        else:
            stopped = issubclass(exc_type, (KeyboardInterrupt, Stopped))
            self.close("KILLED" if stopped else "FAILED")

    def _experiment_id(self) -> str:
        """Get or create the experiment; local stores keep artifacts next to the database."""
        exp = self.client.get_experiment_by_name(self.experiment)
        if exp is None:
            db = sqlite_path(self.tracking_uri)
            # MLflow's default artifact root is ./mlruns of whatever cwd (a Hydra job folder)
            # first creates the experiment; pin it beside the database instead.
            location = None
            if db is not None:
                slug = re.sub(r"[^A-Za-z0-9_.-]", "_", self.experiment)
                location = (db.parent / "mlartifacts" / slug).as_uri()
            try:
                return self.client.create_experiment(self.experiment, artifact_location=location)
            except MlflowException:
                exp = self.client.get_experiment_by_name(self.experiment)  # a parallel job won
                if exp is None:
                    raise
        if exp.lifecycle_stage != "active":
            raise TrackingError(f"MLflow experiment {self.experiment!r} is deleted; restore it "
                                "or choose another experiment name.")
        return exp.experiment_id

    def start(self, run_name: str | None = None, params: Mapping[str, str] | None = None,
              tags: Mapping[str, str] | None = None, parent_run_id: str | None = None,
              resume_run_id: str | None = None) -> str:
        """Create a run (or continue `resume_run_id`) and log its params and tags; returns its id.

        The git commit is tagged unless `tags` sets it. On resume, params already in the run
        keep their first value (MLflow refuses to change a param); new keys are added; metric
        points at or before a metric's last logged step are not sent again.
        """
        if self.run_id is not None:
            raise TrackingError(f"this tracker already started run {self.run_id}.")
        all_tags = {MLFLOW_GIT_COMMIT: git_commit(), **(tags or {})}
        if parent_run_id:
            all_tags[MLFLOW_PARENT_RUN_ID] = parent_run_id
        all_tags = {k: str(v)[:MAX_TAG_VAL_LENGTH] for k, v in all_tags.items()}
        params = {metric_key(k): str(v)[:MAX_PARAM_VAL_LENGTH] for k, v in (params or {}).items()}
        try:
            if resume_run_id:
                params = self._resume(resume_run_id, run_name, params)
            else:
                run = self.client.create_run(self._experiment_id(), run_name=run_name,
                                             tags=all_tags)
                self.run_id, self.experiment_id = run.info.run_id, run.info.experiment_id
                all_tags = {}  # already written by create_run
            self._log_params_and_tags(params, all_tags)
        except MlflowException as exc:
            raise TrackingError(f"cannot start MLflow run in {self.tracking_uri}: "
                                f"{_reason(exc)}") from exc
        return self.run_id

    def _resume(self, run_id: str, run_name: str | None,
                params: dict[str, str]) -> dict[str, str]:
        """Reopen `run_id`; return the params it does not have yet."""
        try:
            run = self.client.get_run(run_id)
        except MlflowException as exc:
            raise TrackingError(f"cannot resume MLflow run {run_id}: it is not in "
                                f"{self.tracking_uri}.") from exc
        self.run_id, self.experiment_id = run_id, run.info.experiment_id
        self.client.update_run(run_id, status="RUNNING", name=run_name)
        self._logged = {key: max(m.step for m in self.client.get_metric_history(run_id, key))
                        for key in run.data.metrics}
        old = run.data.params
        changed = sorted(k for k, v in params.items() if k in old and old[k] != v)
        if changed:
            log.warning("resumed run %s keeps its original values of changed params %s",
                        run_id, changed)
        return {k: v for k, v in params.items() if k not in old}

    def _log_params_and_tags(self, params: dict[str, str], tags: dict[str, str]) -> None:
        """One `log_batch`, which MLflow splits into calls of its limit (100 params or tags)."""
        self.client.log_batch(self.run_id, params=[Param(k, v) for k, v in params.items()],
                              tags=[RunTag(k, v) for k, v in tags.items()])

    def children(self) -> list[Run]:
        """This run's children (a sweep's jobs), oldest first."""
        if self.run_id is None:
            raise TrackingError("the MLflow run has not been started.")
        children: list[Run] = []
        token = None
        while True:
            page = self.client.search_runs(
                [self.experiment_id], f"tags.`{MLFLOW_PARENT_RUN_ID}` = '{self.run_id}'",
                max_results=1000, page_token=token, order_by=["attributes.start_time ASC"])
            children.extend(page)
            token = page.token
            if not token:
                return children

    def child_runs(self) -> dict[str, str]:
        """Run id -> status of this run's children (a sweep's jobs)."""
        return {run.info.run_id: run.info.status for run in self.children()}

    def _require_open(self) -> str:
        if self.run_id is None or self._closed:
            raise TrackingError("the MLflow run is not open: call start() first and not after "
                                "close().")
        return self.run_id

    def log_metrics(self, step: int, metrics: Mapping[str, float]) -> None:
        """Buffer one step's metrics; sent every `flush_every` points or `flush_seconds`.

        The time check runs here (no background thread), so at most one call's worth of points
        waits beyond `flush_seconds`.
        """
        self._require_open()
        now_ms = int(time.time() * 1000)
        step, points = _metric_points(step, metrics)
        self._buffer.extend(Metric(key, value, now_ms, step) for key, value in points
                            if step > self._logged.get(key, -1))
        if (len(self._buffer) >= self.flush_every
                or time.monotonic() - self._last_flush >= self.flush_seconds):
            self.flush()

    def flush(self) -> None:
        """Send the buffered metrics now; MLflow's `log_batch` splits them into calls of 1000.

        If that fails the points stay buffered for the next flush: those of MLflow's calls that
        succeeded are sent again, and a SQL store keeps an identical point (key, step, value,
        timestamp) once.
        """
        # Our buffer and a synchronous call, not `log_batch(..., synchronous=False)`: MLflow's
        # async queue writes each call as its own transaction (on sqlite, 500 calls of 8 points
        # took 9 s against 0.4 s as one batch) unless the process-wide
        # MLFLOW_ASYNC_LOGGING_BUFFERING_SECONDS is set; its worker threads bypass
        # `_RetryingClient`; and a failure only logs an error and drops the points, raising
        # nothing until someone waits on the call's future. A checkpoint needs its metrics in the
        # store before it exists (`epoet.checkpoint.save_run_state`), and a failure must be one
        # TrackingError here.
        run_id = self._require_open()
        self._last_flush = time.monotonic()
        try:
            self.client.log_batch(run_id, metrics=self._buffer)
        except MlflowException as exc:
            raise TrackingError(f"cannot send metrics to {self.tracking_uri}: "
                                f"{_reason(exc)}") from exc
        self._buffer.clear()

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """Upload a file, or a directory's contents, under `artifact_path`."""
        run_id = self._require_open()
        path = _existing_path(path)
        try:
            if path.is_dir():
                self.client.log_artifacts(run_id, str(path), artifact_path)
            else:
                self.client.log_artifact(run_id, str(path), artifact_path)
        except (MlflowException, OSError) as exc:
            raise TrackingError(f"cannot upload artifact {path}: {_reason(exc)}") from exc

    def log_dict(self, obj: Any, artifact_file: str) -> None:
        """Upload `obj` as JSON or YAML (by the file's extension), e.g. the resolved config."""
        run_id = self._require_open()
        try:
            self.client.log_dict(run_id, obj, artifact_file)
        except (MlflowException, OSError, TypeError) as exc:
            raise TrackingError(f"cannot upload {artifact_file}: {_reason(exc)}") from exc

    def log_agent(self, policy: Path, loader_module: str, obs_dim: int, act_dim: int) -> None:
        """Log the trained agent as this run's MLflow model `agent` (a pyfunc whose data is the
        policy file and whose loader is `loader_module`), with the signature observation
        (n, obs_dim) -> action (n, act_dim): the UI's Models column links it and
        `mlflow.pyfunc.load_model("runs:/<run id>/agent")` loads it.

        Through the client (create, upload, finalize, link as the run's output), not
        `mlflow.pyfunc.log_model`, which writes to the fluent API's global store and experiment.
        """
        import mlflow.pyfunc  # the model API is only needed here, once per run
        from mlflow.entities import LoggedModelOutput, LoggedModelStatus
        from mlflow.models import ModelSignature
        from mlflow.types import Schema, TensorSpec
        run_id = self._require_open()
        float64 = np.dtype(np.float64)
        # unnamed tensors: predict gets the observation array itself
        signature = ModelSignature(inputs=Schema([TensorSpec(float64, (-1, obs_dim))]),
                                   outputs=Schema([TensorSpec(float64, (-1, act_dim))]))
        try:
            model = self.client.create_logged_model(self.experiment_id, name="agent",
                                                    source_run_id=run_id)
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                # the signature says what an input example would; MLflow asks for one anyway
                warnings.filterwarnings("ignore", message=".*An input example was not provided")
                mlflow.pyfunc.save_model(
                    f"{tmp}/agent", loader_module=loader_module,
                    data_path=str(_existing_path(policy)), signature=signature,
                    # stated, not inferred: inference loads the model in a subprocess
                    pip_requirements=[f"mlflow=={mlflow.__version__}", f"numpy=={np.__version__}"])
                self.client.log_model_artifacts(model.model_id, f"{tmp}/agent")
            self.client.finalize_logged_model(model.model_id, LoggedModelStatus.READY)
            self.client.log_outputs(run_id, [LoggedModelOutput(model.model_id, step=0)])
        except (MlflowException, OSError) as exc:
            raise TrackingError(f"cannot log the agent {policy} as an MLflow model: "
                                f"{_reason(exc)}") from exc

    def set_tags(self, tags: Mapping[str, str]) -> None:
        """Set run tags now (e.g. why the run stopped)."""
        run_id = self._require_open()
        try:
            self.client.log_batch(run_id, tags=[RunTag(k, str(v)) for k, v in tags.items()])
        except MlflowException as exc:
            raise TrackingError(f"cannot tag MLflow run {run_id}: {_reason(exc)}") from exc

    def close(self, status: str = "FINISHED") -> None:
        """Flush and terminate the run (FINISHED, FAILED or KILLED); closing twice is a no-op."""
        if self.run_id is None or self._closed:
            return
        try:
            self.flush()
        finally:  # the status is recorded even if the last metrics could not be sent
            self._closed = True
            try:
                self.client.set_terminated(self.run_id, status)
            except MlflowException as exc:
                raise TrackingError(f"cannot close MLflow run {self.run_id}: "
                                    f"{_reason(exc)}") from exc


def ui_hint(tracking_uri: str, experiment_id: str) -> str:
    """The command that serves the store and the URL of the experiment's runs table (MLflow
    3's UI opens on a GenAI overview without `workflowType`)."""
    return (f"mlflow ui --backend-store-uri {tracking_uri}  then open http://127.0.0.1:5000/"
            f"#/experiments/{experiment_id}/runs?workflowType=machine_learning")


class StoredRun:
    """A run already in the store, for the commands that read it or add results to it after
    training (evaluation, videos, analysis): its tags, its artifacts, and logging without
    reopening it (its status stays what training left)."""

    def __init__(self, client: MlflowClient, run: Run, tracking_uri: str | None = None) -> None:
        self.client = client
        self.tracking_uri = resolve_tracking_uri(tracking_uri)
        self.run_id = run.info.run_id
        self.name = run.info.run_name
        self.status = run.info.status
        self.experiment_id = run.info.experiment_id
        self.tags = dict(run.data.tags)
        self.metrics = dict(run.data.metrics)  # each metric's last value

    @classmethod
    def open(cls, run_id: str, tracking_uri: str | None = None) -> StoredRun:
        """Connect to the store (proving it answers) and find the run, or TrackingError."""
        uri = resolve_tracking_uri(tracking_uri)
        client = open_store(uri)
        try:
            return cls(client, client.get_run(run_id), uri)
        except MlflowException as exc:
            raise TrackingError(f"run {run_id} is not in the MLflow store {uri}.") from exc

    def has_artifact(self, artifact_path: str) -> bool:
        folder, _, name = artifact_path.rpartition("/")
        try:
            listed = self.client.list_artifacts(self.run_id, folder or None)
        except (MlflowException, OSError):
            return False
        return any(f.path == artifact_path or f.path.endswith(f"/{name}") for f in listed)

    def download(self, artifact_path: str, dst: Path) -> Path:
        """The artifact (file or folder) copied under `dst`; its local path."""
        os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")  # one per file
        try:
            return Path(self.client.download_artifacts(self.run_id, artifact_path, str(dst)))
        except (MlflowException, OSError) as exc:
            raise TrackingError(f"cannot download {artifact_path} of run {self.run_id}: "
                                f"{_reason(exc)}") from exc

    def ui_hint(self) -> str:
        """Where to look at this run (`ui_hint`)."""
        return ui_hint(self.tracking_uri, self.experiment_id)

    def log_results(self, metrics: Mapping[str, float], tags: Mapping[str, str] = {},
                    artifacts: Mapping[str, str | Path] = {}) -> None:
        """Metrics (one batch), tags and artifacts {local path: artifact folder}."""
        try:
            now = int(time.time() * 1000)
            self.client.log_batch(
                self.run_id,
                metrics=[Metric(metric_key(k), float(v), now, 0) for k, v in metrics.items()],
                tags=[RunTag(k, str(v)) for k, v in tags.items()])
            for path, folder in artifacts.items():
                self.client.log_artifact(self.run_id, str(_existing_path(path)), str(folder))
        except (MlflowException, OSError) as exc:
            raise TrackingError(f"cannot log results to run {self.run_id}: "
                                f"{_reason(exc)}") from exc
