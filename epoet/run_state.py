"""What every runner does at a run's boundaries: checkpoint the run's state together with its
config and the MLflow run it continues, and say why the run stopped.

Run-level code, so it sits above `core` (which imports nothing else of the package) and below the
algorithms that call it; `epoet/run.py` makes the run these belong to.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from epoet.core.checkpoint import CHECKPOINT_NAME, save_checkpoint

if TYPE_CHECKING:  # the tracker protocol; importing it at run time would pull in mlflow
    from epoet.config import BudgetConfig, Config
    from epoet.tracking import Tracker


def save_run_state(run_dir: Path, tracker: Tracker, cfg: Config, state: dict[str, Any]) -> Path:
    """Checkpoint a runner's state with its config and the MLflow run id it continues."""
    path = Path(run_dir) / CHECKPOINT_NAME
    tracker.flush()  # metrics up to the checkpoint are in the store before it exists
    save_checkpoint(
        path,
        {
            "run_id": tracker.run_id,
            "algo": cfg.algo.name,
            "config": dataclasses.asdict(cfg),
            **state,
        },
    )
    return path


def report_stop(
    tracker: Tracker,
    name: str,
    budget: BudgetConfig,
    out_of_time: bool,
    count: int,
    unit: str,
    seconds: float,
) -> None:
    """Tag why the run ended (`stop_reason`: hours, or the budget's `unit`, iterations or
    frames) and say so when the wall clock ended it: a resume with a larger `budget.hours`
    continues."""
    tracker.set_tags({"stop_reason": "hours" if out_of_time else unit})
    if out_of_time:
        print(
            f"[{name}] stopped at the wall-clock budget (budget.hours={budget.hours:g}) after "
            f"{count} {unit} and {seconds / 3600:.3g} h of training; resume with a larger "
            f"budget.hours to continue",
            flush=True,
        )
