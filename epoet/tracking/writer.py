"""What algorithms report to (`Tracker`) and the MLflow run that records it (`MlflowTracker`).

Metrics are buffered and sent with `log_batch` because per-point `log_metric` on sqlite (one
transaction per point) would dominate a run.
"""

from __future__ import annotations

import logging
import math
import os
import re
import tempfile
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, runtime_checkable

import numpy as np
from mlflow.entities import Metric, Param, Run, RunTag
from mlflow.exceptions import MlflowException
from mlflow.utils.mlflow_tags import MLFLOW_GIT_COMMIT, MLFLOW_PARENT_RUN_ID
from mlflow.utils.validation import MAX_METRICS_PER_BATCH, MAX_PARAM_VAL_LENGTH, MAX_TAG_VAL_LENGTH

from epoet.core.lifecycle import Stopped
from epoet.tracking.errors import TrackingError, reason
from epoet.tracking.inputs import existing_path, metric_key, metric_points
from epoet.tracking.provenance import git_commit
from epoet.tracking.store import open_store, resolve_tracking_uri, sqlite_path

# MLflow 3's UI opens an experiment by its kind: without it, a new store's experiments may land
# on the GenAI overview (traces, tokens) instead of the training runs' table.
EXPERIMENT_TAGS = {"mlflow.experimentKind": "custom_model_development"}
LOAD_METRIC = "system/load1"  # os.getloadavg()[0], logged with a step at most every LOAD_EVERY s
LOAD_EVERY = 30.0

log = logging.getLogger(__name__)


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


class MlflowTracker:
    """One MLflow run: buffered metrics, params from the flattened config, tags, artifacts.

    Use as a context manager so an exception closes the run as FAILED (KILLED on Ctrl-C):
        with MlflowTracker(cfg.tracking.uri, cfg.tracking.experiment) as tracker:
            tracker.start("ppo-seed1", params=flatten(cfg_dict), parent_run_id=parent_run_id())
    """

    def __init__(
        self,
        tracking_uri: str | None,
        experiment: str,
        flush_every: int = MAX_METRICS_PER_BATCH,
        flush_seconds: float = 10.0,
    ) -> None:
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
        self._last_load = -math.inf

    def __enter__(self) -> MlflowTracker:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
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
                return self.client.create_experiment(
                    self.experiment, artifact_location=location, tags=EXPERIMENT_TAGS
                )
            except MlflowException:
                exp = self.client.get_experiment_by_name(self.experiment)  # a parallel job won
                if exp is None:
                    raise
        if exp.lifecycle_stage != "active":
            raise TrackingError(
                f"MLflow experiment {self.experiment!r} is deleted; restore it "
                "or choose another experiment name."
            )
        for key, value in EXPERIMENT_TAGS.items():  # an experiment made before the tag
            if key not in exp.tags:
                self.client.set_experiment_tag(exp.experiment_id, key, value)
        return exp.experiment_id

    def start(
        self,
        run_name: str | None = None,
        params: Mapping[str, str] | None = None,
        tags: Mapping[str, str] | None = None,
        parent_run_id: str | None = None,
        resume_run_id: str | None = None,
    ) -> str:
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
                run = self.client.create_run(
                    self._experiment_id(), run_name=run_name, tags=all_tags
                )
                self.run_id, self.experiment_id = run.info.run_id, run.info.experiment_id
                all_tags = {}  # already written by create_run
            self._log_params_and_tags(params, all_tags)
        except MlflowException as exc:
            raise TrackingError(
                f"cannot start MLflow run in {self.tracking_uri}: {reason(exc)}"
            ) from exc
        assert self.run_id is not None  # set by create_run or _resume
        return self.run_id

    def _resume(self, run_id: str, run_name: str | None, params: dict[str, str]) -> dict[str, str]:
        """Reopen `run_id`; return the params it does not have yet."""
        try:
            run = self.client.get_run(run_id)
        except MlflowException as exc:
            raise TrackingError(
                f"cannot resume MLflow run {run_id}: it is not in {self.tracking_uri}."
            ) from exc
        self.run_id, self.experiment_id = run_id, run.info.experiment_id
        self.client.update_run(run_id, status="RUNNING", name=run_name)
        self._logged = {
            key: max(m.step for m in self.client.get_metric_history(run_id, key))
            for key in run.data.metrics
        }
        old = run.data.params
        changed = sorted(k for k, v in params.items() if k in old and old[k] != v)
        if changed:
            log.warning(
                "resumed run %s keeps its original values of changed params %s", run_id, changed
            )
        return {k: v for k, v in params.items() if k not in old}

    def _log_params_and_tags(self, params: dict[str, str], tags: dict[str, str]) -> None:
        """One `log_batch`, which MLflow splits into calls of its limit (100 params or tags)."""
        assert self.run_id is not None  # start() set it
        self.client.log_batch(
            self.run_id,
            params=[Param(k, v) for k, v in params.items()],
            tags=[RunTag(k, v) for k, v in tags.items()],
        )

    def children(self) -> list[Run]:
        """This run's children (a sweep's jobs), oldest first."""
        if self.run_id is None:
            raise TrackingError("the MLflow run has not been started.")
        assert self.experiment_id is not None  # set with run_id
        children: list[Run] = []
        token = None
        while True:
            page = self.client.search_runs(
                [self.experiment_id],
                f"tags.`{MLFLOW_PARENT_RUN_ID}` = '{self.run_id}'",
                max_results=1000,
                page_token=token,
                order_by=["attributes.start_time ASC"],
            )
            children.extend(page)
            token = page.token
            if not token:
                return children

    def child_runs(self) -> dict[str, str]:
        """Run id -> status of this run's children (a sweep's jobs)."""
        return {run.info.run_id: run.info.status for run in self.children()}

    def _require_open(self) -> str:
        if self.run_id is None or self._closed:
            raise TrackingError(
                "the MLflow run is not open: call start() first and not after close()."
            )
        return self.run_id

    def log_metrics(self, step: int, metrics: Mapping[str, float]) -> None:
        """Buffer one step's metrics; sent every `flush_every` points or `flush_seconds`.

        The time check runs here (no background thread), so at most one call's worth of points
        waits beyond `flush_seconds`.
        """
        self._require_open()
        now_ms = int(time.time() * 1000)
        step, points = metric_points(step, metrics)
        self._buffer.extend(
            Metric(key, value, now_ms, step)
            for key, value in points
            if step > self._logged.get(key, -1)
        )
        if (
            len(self._buffer) >= self.flush_every
            or time.monotonic() - self._last_flush >= self.flush_seconds
        ):
            self.flush()

    def flush(self) -> None:
        """Send the buffered metrics now; MLflow's `log_batch` splits them into calls of 1000.

        If that fails the points stay buffered for the next flush: those of MLflow's calls that
        succeeded are sent again, and a SQL store keeps an identical point (key, step, value,
        timestamp) once.
        """
        # Our buffer and a synchronous call, not `log_batch(..., synchronous=False)`: MLflow's
        # async queue writes each call as its own transaction (on sqlite, many times slower than
        # one batch of the same points) unless the process-wide
        # MLFLOW_ASYNC_LOGGING_BUFFERING_SECONDS is set; its worker threads bypass
        # `RetryingClient`; and a failure only logs an error and drops the points, raising
        # nothing until someone waits on the call's future. A checkpoint needs its metrics in the
        # store before it exists (`epoet.driver.save_run_state`), and a failure must be one
        # TrackingError here.
        run_id = self._require_open()
        self._last_flush = time.monotonic()
        if self._buffer and self._last_flush - self._last_load >= LOAD_EVERY:
            # The machine's 1-minute load average beside the run's own numbers, at the latest
            # buffered step: a run's speed (and what a wall-clock budget buys) depends on what
            # else shared its cores.
            self._last_load = self._last_flush
            self._buffer.append(
                Metric(
                    LOAD_METRIC,
                    os.getloadavg()[0],
                    self._buffer[-1].timestamp,
                    max(m.step for m in self._buffer),
                )
            )
        try:
            self.client.log_batch(run_id, metrics=self._buffer)
        except MlflowException as exc:
            raise TrackingError(
                f"cannot send metrics to {self.tracking_uri}: {reason(exc)}"
            ) from exc
        self._buffer.clear()

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """Upload a file, or a directory's contents, under `artifact_path`."""
        run_id = self._require_open()
        path = existing_path(path)
        try:
            if path.is_dir():
                self.client.log_artifacts(run_id, str(path), artifact_path)
            else:
                self.client.log_artifact(run_id, str(path), artifact_path)
        except (MlflowException, OSError) as exc:
            raise TrackingError(f"cannot upload artifact {path}: {reason(exc)}") from exc

    def log_dict(self, obj: Any, artifact_file: str) -> None:
        """Upload `obj` as JSON or YAML (by the file's extension), e.g. the resolved config."""
        run_id = self._require_open()
        try:
            self.client.log_dict(run_id, obj, artifact_file)
        except (MlflowException, OSError, TypeError) as exc:
            raise TrackingError(f"cannot upload {artifact_file}: {reason(exc)}") from exc

    def log_agent(self, policy: Path, loader_module: str, obs_dim: int, act_dim: int) -> None:
        """Log the trained agent as this run's MLflow model `agent` (a pyfunc whose data is the
        policy file and whose loader is `loader_module`), with one signature for every
        algorithm: observations (n, obs_dim), float32 or float64, -> actions (n, act_dim)
        float64. The UI's Models column links it and
        `mlflow.pyfunc.load_model("runs:/<run id>/agent")` loads it.

        Through the client (create, upload, finalize, link as the run's output), not
        `mlflow.pyfunc.log_model`, which writes to the fluent API's global store and experiment.
        """
        import mlflow.pyfunc  # the model API is only needed here, once per run
        from mlflow.entities import LoggedModelOutput, LoggedModelStatus
        from mlflow.models import ModelSignature
        from mlflow.types import ColSpec, Schema, TensorSpec

        run_id = self._require_open()
        assert self.experiment_id is not None  # set with run_id
        # One unnamed double column per observation entry: MLflow widens float32 columns to
        # double, where a float64 tensor spec refuses float32 arrays (and a float32 one float64).
        signature = ModelSignature(
            inputs=Schema([ColSpec("double") for _ in range(obs_dim)]),
            outputs=Schema([TensorSpec(np.dtype(np.float64), (-1, act_dim))]),
        )
        try:
            model = self.client.create_logged_model(
                self.experiment_id, name="agent", source_run_id=run_id
            )
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                # the signature says what an input example would; MLflow asks for one anyway
                warnings.filterwarnings("ignore", message=".*An input example was not provided")
                mlflow.pyfunc.save_model(
                    f"{tmp}/agent",
                    loader_module=loader_module,
                    data_path=str(existing_path(policy)),
                    signature=signature,
                    # stated, not inferred: inference loads the model in a subprocess
                    pip_requirements=[f"mlflow=={mlflow.__version__}", f"numpy=={np.__version__}"],
                )
                self.client.log_model_artifacts(model.model_id, f"{tmp}/agent")
            self.client.finalize_logged_model(model.model_id, LoggedModelStatus.READY)
            self.client.log_outputs(run_id, [LoggedModelOutput(model.model_id, step=0)])
        except (MlflowException, OSError) as exc:
            raise TrackingError(
                f"cannot log the agent {policy} as an MLflow model: {reason(exc)}"
            ) from exc

    def set_tags(self, tags: Mapping[str, str]) -> None:
        """Set run tags now (e.g. why the run stopped)."""
        run_id = self._require_open()
        try:
            self.client.log_batch(run_id, tags=[RunTag(k, str(v)) for k, v in tags.items()])
        except MlflowException as exc:
            raise TrackingError(f"cannot tag MLflow run {run_id}: {reason(exc)}") from exc

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
                raise TrackingError(
                    f"cannot close MLflow run {self.run_id}: {reason(exc)}"
                ) from exc


def close_killed(tracking_uri: str, run_id: str) -> bool:
    """Mark the MLflow run of a process that was killed (it stayed RUNNING) as KILLED; False if
    it is no longer RUNNING or not in that store (nothing to close)."""
    try:
        client = open_store(tracking_uri)
        if client.get_run(run_id).info.status != "RUNNING":
            return False
        client.set_terminated(run_id, "KILLED")
    except (MlflowException, TrackingError):
        return False
    log.warning("closed MLflow run %s as KILLED: its process was killed", run_id)
    return True
