"""A run already in the store, read and added to after training by evaluation, videos and
analysis."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from pathlib import Path

from mlflow import MlflowClient
from mlflow.entities import Metric, Run, RunTag
from mlflow.exceptions import MlflowException

from epoet.tracking.errors import TrackingError, reason
from epoet.tracking.inputs import existing_path, metric_key
from epoet.tracking.store import open_store, resolve_tracking_uri, sqlite_path, ui_hint


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
        """Connect to the store (proving it answers) and find the run, or TrackingError. A
        sqlite store that does not exist is not created (MLflow would make an empty one, left
        behind by a command that looked for a run in the wrong store)."""
        uri = resolve_tracking_uri(tracking_uri)
        db = sqlite_path(uri)
        if db is not None and not db.is_file():
            raise TrackingError(
                f"run {run_id} is not in the MLflow store {uri}: there is no "
                f"store at {db} (MLFLOW_TRACKING_URI or the command's "
                f"tracking.uri names the store the run was logged to)."
            )
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
            raise TrackingError(
                f"cannot download {artifact_path} of run {self.run_id}: {reason(exc)}"
            ) from exc

    def ui_hint(self) -> str:
        """Where to look at this run (`ui_hint`)."""
        return ui_hint(self.tracking_uri, self.experiment_id)

    def log_results(
        self,
        metrics: Mapping[str, float],
        tags: Mapping[str, str] = {},
        artifacts: Mapping[str | Path, str] = {},
        step: int = 0,
    ) -> None:
        """Metrics at `step` (one batch), tags and artifacts {local path: artifact folder}.

        Each result is logged once: a metric point the run already holds (same key, step and
        value, e.g. an evaluation killed after logging and run again on resume) is skipped. A
        different value at that step (another evaluation's) is logged, so the metric's last
        value is always the latest evaluation's, the one whose artifacts the run keeps."""
        try:
            now = int(time.time() * 1000)
            keyed = {metric_key(k): float(v) for k, v in metrics.items()}
            held = {
                (key, m.value)
                for key in keyed
                for m in self.client.get_metric_history(self.run_id, key)
                if m.step == step
            }
            self.client.log_batch(
                self.run_id,
                metrics=[Metric(k, v, now, step) for k, v in keyed.items() if (k, v) not in held],
                tags=[RunTag(k, str(v)) for k, v in tags.items()],
            )
            for path, folder in artifacts.items():
                self.client.log_artifact(self.run_id, str(existing_path(path)), str(folder))
        except (MlflowException, OSError) as exc:
            raise TrackingError(f"cannot log results to run {self.run_id}: {reason(exc)}") from exc
