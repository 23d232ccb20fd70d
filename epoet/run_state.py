"""A run folder's marks: DONE when a run finished there (with the budget it finished on), RUNNING
while a process trains there, and what the next command does with a mark a killed process left.

Run-level code, so it sits above `core` (which imports nothing else of the package); the driver
(epoet/driver.py) writes the run's checkpoints and snapshots, `epoet/run.py` the marks.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Any

from epoet.core.checkpoint import CheckpointError
from epoet.core.files import atomic_write

if TYPE_CHECKING:  # the tracker protocol; importing it at run time would pull in mlflow
    from epoet.config import BudgetConfig


# The budget's limits a resume may raise (epoet/migration.py RESUMABLE), where the family has them.
BUDGET_LIMITS = ("iterations", "hours", "cpu_hours")
# Written into the run folder when a run finished: its MLflow run id, then (JSON) the budget
# limits it finished on, so `resume=auto` decides without loading a checkpoint (a SAC replay
# buffer makes one hundreds of MB).
DONE = "DONE"
# Written into the run folder while a process trains there (its MLflow run id and store, host
# and pid) and removed when the run ends, however it ends but SIGKILL or a power cut: one left
# behind names an MLflow run that stays RUNNING for good, which the next run in the folder
# closes as KILLED (epoet/run.py).
LIVE = "RUNNING"
HOST_TAG, PID_TAG = "epoet.host", "epoet.pid"  # the same, on the MLflow run (analysis reads it)


def process_alive(host: str, pid: int) -> bool | None:
    """Whether epoet's process `pid` on `host` still runs; None: on another host, unknown. A pid
    taken since by another program does not count (its command line names no epoet)."""
    if host != socket.gethostname():
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        pass
    cmdline = Path(f"/proc/{pid}/cmdline")
    return not cmdline.is_file() or b"epoet" in cmdline.read_bytes()


def mark_live(run_dir: Path, run_id: str, tracking_uri: str) -> None:
    mark = {"run_id": run_id, "uri": tracking_uri, "host": socket.gethostname(), "pid": os.getpid()}
    with atomic_write(Path(run_dir) / LIVE) as f:
        f.write((json.dumps(mark) + "\n").encode())


def process_tags() -> dict[str, str]:
    """The MLflow tags that tell a killed run from a live one (`process_alive`)."""
    return {HOST_TAG: socket.gethostname(), PID_TAG: str(os.getpid())}


def close_killed_run(run_dir: Path, resuming: str | None) -> None:
    """Close as KILLED the MLflow run a killed process left open in `run_dir` (a resume of that
    very run, `resuming`, reopens it instead)."""
    killed = orphaned_run(run_dir)
    if killed is not None and killed["run_id"] != resuming:
        from epoet.tracking import close_killed  # mlflow: only when there is one to close

        close_killed(killed["uri"], killed["run_id"])


def close_if_killed(run_dir: Path) -> None:
    """What a command that reads a run folder without training in it does (evaluate): close as
    KILLED the MLflow run a killed process left open there; a run still training is left
    alone."""
    try:
        close_killed_run(run_dir, None)
    except CheckpointError:  # its process is alive: a run still training, evaluated mid-way
        pass


def orphaned_run(run_dir: Path) -> dict[str, Any] | None:
    """The mark a killed process left in `run_dir` (None: none); CheckpointError (one line) when
    the process that wrote it still trains there."""
    path = Path(run_dir) / LIVE
    if not path.is_file():
        return None
    try:
        mark = json.loads(path.read_text())
        alive = process_alive(str(mark["host"]), int(mark["pid"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None  # not a mark this code wrote: nothing to close
    if alive:
        raise CheckpointError(
            f"{run_dir} is in use: process {mark['pid']} is training there (its {LIVE}); "
            "wait for it or stop it first."
        )
    return mark


def mark_done(run_dir: Path, run_id: str, budget: BudgetConfig) -> None:
    """Write the run folder's DONE: the run id, then the limits of the budget it finished on."""
    limits = {key: getattr(budget, key) for key in BUDGET_LIMITS if hasattr(budget, key)}
    with atomic_write(Path(run_dir) / DONE) as f:
        f.write(f"{run_id}\n{json.dumps(limits)}\n".encode())


def finished_limits(run_dir: Path) -> dict[str, Any] | None:
    """The budget limits the run in `run_dir` finished on (its DONE file); None: not finished.
    A DONE from before it held them reads as no limits, so that run stays finished;
    CheckpointError (one line, what to do) for a DONE that is no run's mark."""
    done = Path(run_dir) / DONE
    if not done.is_file():
        return None
    try:
        run_id, _, limits = done.read_text().partition("\n")
        found = json.loads(limits) if limits.strip() else {}
        if not (run_id.strip().isalnum() and isinstance(found, dict)):
            raise ValueError("no run id and budget limits")
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise CheckpointError(
            f"{done} is no finished run's mark ({str(err).splitlines()[0]}): remove it to "
            f"train in {run_dir} again."
        ) from None
    return found


def extends_budget(limits: dict[str, Any], budget: BudgetConfig) -> bool:
    """Whether `budget` gives a finished run more than the `limits` it ended on: a larger limit,
    or none, where it had one. Asked for more, a finished run continues, as its stop message
    says it can; asked for the same or less, it stays finished."""
    for key, old in limits.items():
        new = getattr(budget, key, old)
        if old is not None and (new is None or new > old):
            return True
    return False
