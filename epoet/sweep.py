"""Hydra callback giving a multirun one MLflow parent run, with every job as its child.

The parent run id travels to the jobs in env EPOET_PARENT_RUN_ID (read by
`epoet.tracking.parent_run_id`): environment variables reach in-process jobs (basic launcher) and
are inherited by launcher worker processes created after `on_multirun_start`.
"""
from __future__ import annotations

import atexit
import os
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from epoet.tracking import PARENT_RUN_ENV, MlflowTracker


class MlflowSweepCallback(Callback):
    """Opens the parent run at multirun start and closes it at the end.

    Hydra skips `on_multirun_end` when a job raises, so an exit hook closes the parent as FAILED
    in that case; a sweep that ends normally is FAILED too if any child run failed.
    """

    def __init__(self, experiment: str = "epoet", tracking_uri: str | None = None) -> None:
        self.experiment = experiment
        self.tracking_uri = tracking_uri
        self._tracker: MlflowTracker | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        overrides = " ".join(config.hydra.overrides.task)
        tracker = MlflowTracker(self.tracking_uri, self.experiment)
        name = f"sweep {overrides}" if overrides else f"sweep {config.hydra.job.name}"
        run_id = tracker.start(
            run_name=name[:250],  # MLflow's SQL schema holds 250 characters; the tag has it all
            tags={"sweep_dir": os.path.abspath(str(config.hydra.sweep.dir)),
                  "sweep_overrides": overrides},
        )
        self._tracker = tracker
        os.environ[PARENT_RUN_ENV] = run_id
        atexit.register(self._close, "FAILED")

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if self._tracker is None:
            return
        failed = "FAILED" in self._tracker.child_runs().values()
        self._close("FAILED" if failed else "FINISHED")

    def _close(self, status: str) -> None:
        """Close the parent once; called by `on_multirun_end` or, failing that, at exit."""
        atexit.unregister(self._close)
        os.environ.pop(PARENT_RUN_ENV, None)
        tracker, self._tracker = self._tracker, None
        if tracker is not None:
            tracker.close(status)
