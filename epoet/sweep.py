"""Hydra callback giving a multirun one MLflow parent run, with every job as its child.

The parent run id travels to the jobs in env EPOET_PARENT_RUN_ID (read by
`epoet.tracking.parent_run_id`): environment variables reach in-process jobs (basic launcher) and
are inherited by launcher worker processes created after `on_multirun_start`.
"""

from __future__ import annotations

import atexit
import os
from typing import TYPE_CHECKING, Any

import numpy as np
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from epoet.core.algorithm import BEST_SCORE, SCORE
from epoet.eval.keys import SHIPPED_NAME, suite_metric

# Hydra instantiates this callback for single runs too, before the job: epoet.tracking (mlflow, a
# slow import) is imported when a multirun starts, so a bad override fails without it.
if TYPE_CHECKING:
    from epoet.tracking import MlflowTracker, Run


class MlflowSweepCallback(Callback):
    """Opens the parent run at multirun start (the sweep's overrides as params; `algos`,
    `budget` and `seeds` tags) and at the end prints a line per job and logs a summary per
    algorithm.

    Hydra skips `on_multirun_end` when a job raises, so an exit hook closes the parent as FAILED
    in that case; a sweep that ends normally is FAILED too if any child run failed.
    """

    def __init__(self, experiment: str, tracking_uri: str | None = None) -> None:
        self.experiment = experiment
        self.tracking_uri = tracking_uri
        self._tracker: MlflowTracker | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        overrides = list(config.hydra.overrides.task)
        params = sweep_params(overrides)
        from epoet.tracking import PARENT_RUN_ENV, MlflowTracker

        tracker = MlflowTracker(self.tracking_uri, self.experiment)
        text = " ".join(overrides)
        name = f"sweep {text}" if text else f"sweep {config.hydra.job.name}"
        run_id = tracker.start(
            run_name=name[:250],  # MLflow's SQL schema holds 250 characters; the tag has it all
            params=params,
            tags={
                "sweep_dir": os.path.abspath(str(config.hydra.sweep.dir)),
                "sweep_overrides": text,
                # what the sweep spans ("algos", not the jobs' "algo": analysis selects
                # runs by their algo tag, and the parent is no run of one algorithm)
                "algos": params.get("algo", str(OmegaConf.select(config, "algo.name"))),
                "budget": params.get("budget", str(OmegaConf.select(config, "budget.name"))),
                "seeds": params.get("seed", str(OmegaConf.select(config, "seed"))),
            },
        )
        self._tracker = tracker
        os.environ[PARENT_RUN_ENV] = run_id
        atexit.register(self._close, "FAILED")

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if self._tracker is None:
            return
        children = self._tracker.children()
        for line in job_lines(children):
            print(line, flush=True)
        if summary := sweep_summary(children):
            self._tracker.log_metrics(0, summary)
        failed = any(run.info.status == "FAILED" for run in children)
        self._close("FAILED" if failed else "FINISHED")

    def _close(self, status: str) -> None:
        """Close the parent once; called by `on_multirun_end` or, failing that, at exit."""
        from epoet.tracking import PARENT_RUN_ENV

        atexit.unregister(self._close)
        os.environ.pop(PARENT_RUN_ENV, None)
        tracker, self._tracker = self._tracker, None
        if tracker is not None:
            tracker.close(status)


def sweep_params(overrides: list[str]) -> dict[str, str]:
    """The sweep's overrides as params (`algo=epoet,sac` -> algo: "epoet,sac")."""
    params = {}
    for override in overrides:
        key, sep, value = override.partition("=")
        if sep:
            params[key.lstrip("+~")] = value
    return params


def job_lines(children: list[Run]) -> list[str]:
    """One line per job: what it was, how it ended, its headline numbers, its run id."""
    lines = []
    for run in children:
        tags = run.data.tags
        numbers = "".join(
            f" {label}={value:.1f}"
            for label, key in (("score", SCORE), ("best", BEST_SCORE))
            if (value := run.data.metrics.get(key)) is not None
        )
        if (success := suite_metric(run.data.metrics, SHIPPED_NAME, "success_rate")) is not None:
            numbers += f" solved={success:.0%}"
        lines.append(
            f"[sweep] {tags.get('algo', '?')} seed={tags.get('seed', '?')} "
            f"{run.info.status}{numbers} run_id={run.info.run_id}"
        )
    return lines


def sweep_summary(children: list[Run]) -> dict[str, float]:
    """Per algorithm over its finished jobs: the mean (and std) final `score` and suite success
    rate (the shipped suite's, `epoet.eval.keys`), and how many finished, so the parent row
    reads as the sweep's result."""
    groups: dict[str, list[Run]] = {}
    for run in children:
        if run.info.status == "FINISHED":
            groups.setdefault(run.data.tags.get("algo", "unknown"), []).append(run)
    summary: dict[str, float] = {}
    for algo, runs in groups.items():
        summary[f"sweep/{algo}/finished"] = float(len(runs))
        for name, found in (
            ("score", [r.data.metrics.get("score") for r in runs]),
            (
                "success_rate",
                [suite_metric(r.data.metrics, SHIPPED_NAME, "success_rate") for r in runs],
            ),
        ):
            values = [v for v in found if v is not None]
            if values:
                summary[f"sweep/{algo}/{name}_mean"] = float(np.mean(values))
                if len(values) > 1:
                    summary[f"sweep/{algo}/{name}_std"] = float(np.std(values, ddof=1))
    return summary
