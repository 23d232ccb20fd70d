"""The one training driver: every algorithm's run, from its first step to its exported agent.

An algorithm gives the driver a `Trainable` (its step, its counters, its state, its agents) and
the driver does the rest, the same for every algorithm, read top to bottom in `drive`:

    begin       what the algorithm logs before its first step (a baseline: its frame-0 evaluation)
    step        one step of the algorithm (a collector batch and its update, an ES iteration),
                logged with the metrics every algorithm logs, taken from its counters
    snapshot    the agents and the run's choice among them at each `snapshot_cpu_minutes` mark
    checkpoint  every `checkpoint_every` steps and when a signal asks the run to stop (then it
                stops there, with a checkpoint to resume from)
    stop        when the budget's count (frames, iterations) is reached or its hours or CPU
                hours are used
    finish      the algorithm's last step (a baseline: its final evaluation), the last
                checkpoint, the exported agent, why the run stopped, the artifacts

Nothing else in the product takes a snapshot, writes a run's checkpoint or reports its stop
(tests/test_algorithms.py holds every module to that).
"""

from __future__ import annotations

import copy
import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from epoet.core.algorithm import AXES, BEST_SCORE, SCORE
from epoet.core.checkpoint import CHECKPOINT_NAME, CheckpointError, save_checkpoint
from epoet.core.clock import CpuMeter
from epoet.core.files import atomic_write
from epoet.core.lifecycle import Stopped, raise_if_stopped, stop_requested
from epoet.rollout.backends.base import WorkersGone

if TYPE_CHECKING:  # the root config and the tracker protocol (which would pull in mlflow)
    from epoet.config import BudgetConfig, Config
    from epoet.tracking import Tracker


@dataclass(frozen=True)
class Counters:
    """Where a run stands, summed over resumes: what the driver budgets, logs and reports."""

    steps: int  # the driver's steps taken (collector batches, ES iterations): checkpoint cadence
    count: int  # progress in the unit the budget counts (frames, iterations)
    env_steps: int
    wall_time: float  # seconds of training
    cpu_time: float  # CPU seconds of the run's processes
    best_score: float  # the best `score` so far

    def axes(self) -> dict[str, float]:
        """The x-axes every algorithm logs (`core/algorithm.py` AXES), from these counters."""
        return dict(zip(AXES, (float(self.env_steps), self.wall_time, self.cpu_time)))


@dataclass(frozen=True)
class Logged:
    """What one step logs: its own `metrics` at MLflow step `at` (frames, the iteration), and
    its `score` (None: the step scored nothing, e.g. a baseline batch without an evaluation)."""

    at: int
    metrics: dict[str, float]
    score: float | None = None


class Trainable(Protocol):
    """What an algorithm gives the driver. Its counters live in its own state (so its
    checkpoints keep their layout); its CPU meter is lapped at the end of each step."""

    name: str  # the algorithm's name: its lines' prefix
    unit: str  # what its budget counts (`Family.counts`): frames or iterations
    total: int  # the budget's count, in `unit`
    cpu_meter: CpuMeter

    def counters(self) -> Counters: ...

    def begin(self) -> Logged | None:
        """What the run logs before its first step (a resumed run: nothing)."""
        ...

    def step(self) -> Logged: ...

    def end(self) -> Logged | None:
        """What the run logs after its last step, before its last checkpoint."""
        ...

    def add_cpu_time(self, seconds: float) -> None:
        """Count CPU the driver spent for the run (a snapshot's choice) in its CPU time."""
        ...

    def snapshot_info(self) -> dict[str, float]:
        """What a snapshot.json records besides the axes (the step, the terrains' height)."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """The checkpoint's entries besides the run id, the algorithm's name and the config."""
        ...

    def save_agents(self, folder: Path) -> None:
        """The agents a checkpoint leaves beside it, so the run evaluates mid-training."""
        ...

    def export(self, folder: Path) -> dict[str, Any]:
        """The agents and the one the run exports into `folder` (`selection`); the choice record."""
        ...

    def after_checkpoint(self) -> None:
        """What follows each checkpoint within the run (a baseline ends its running episode)."""
        ...

    def artifacts(self, run_dir: Path) -> list[tuple[Path, str | None]]:
        """The files logged to the run's store at its end: (path, artifact folder)."""
        ...

    def say(self, line: str) -> None:
        """A line of the run's progress output, prefixed with the algorithm's name."""
        ...


def drive(algo: Trainable, cfg: Config, tracker: Tracker, run_dir: Path, resumed: bool) -> Counters:
    """Run `algo` to the end of the budget (a `resumed` run from where its checkpoint left it);
    returns its counters at the end."""
    budget = cfg.budget
    if resumed:
        algo.say(f"resumed at {algo.counters().count} {algo.unit}")

    def out_of_time() -> str | None:
        counters = algo.counters()
        return budget.time_is_up(counters.wall_time, counters.cpu_time)

    def spent() -> bool:
        return algo.counters().count >= algo.total or out_of_time() is not None

    log(tracker, algo, algo.begin())
    # Workers lost for good mid-step leave the state half-changed: where they can be lost, the
    # state at each step's start is kept to checkpoint from.
    boundary: tuple[int, dict[str, Any]] | None = None
    while not spent():
        if cfg.workers.may_be_lost:
            boundary = algo.counters().count, copy.deepcopy(algo.state_dict())
        try:
            log(tracker, algo, algo.step())  # step
            snapshot(algo, run_dir, cfg.snapshot_cpu_minutes)  # snapshot
        except WorkersGone as gone:
            if boundary is None:
                raise
            count, state = boundary
            save_run_state(run_dir, tracker, cfg, state)  # as the failed step found it
            reason = f"stopped after {count} {algo.unit}, its workers lost: {gone}"
            raise Stopped(reason, Stopped.WORKERS_GONE) from gone
        steps = algo.counters().steps
        if (steps % cfg.checkpoint_every == 0 or stop_requested()) and not spent():
            checkpoint(algo, cfg, tracker, run_dir)  # checkpoint
            raise_if_stopped(f"after {algo.counters().count} {algo.unit}")
            algo.after_checkpoint()
    log(tracker, algo, algo.end())  # finish
    checkpoint(algo, cfg, tracker, run_dir)
    record = algo.export(run_dir)
    algo.say(exported(record))
    counters = algo.counters()
    report_stop(
        tracker,
        algo.name,
        budget,
        out_of_time() if counters.count < algo.total else None,
        counters.count,
        algo.unit,
        counters.wall_time,
        counters.cpu_time,
    )
    for path, folder in algo.artifacts(run_dir):
        tracker.log_artifact(path, folder)
    tracker.flush()
    return counters


def log(tracker: Tracker, algo: Trainable, logged: Logged | None) -> None:
    """A step's metrics with the axes every algorithm logs (`core/algorithm.py` AXES), and the
    score and the best so far where it scored, all from the algorithm's counters, so MLflow
    and the figures chart every algorithm against the same axes."""
    if logged is None:
        return
    counters = algo.counters()
    scored = {} if logged.score is None else {SCORE: logged.score, BEST_SCORE: counters.best_score}
    tracker.log_metrics(logged.at, {**logged.metrics, **counters.axes(), **scored})


def checkpoint(algo: Trainable, cfg: Config, tracker: Tracker, run_dir: Path) -> None:
    """The algorithm's agents, then its state with the config and the MLflow run it continues.

    Agents first: a process killed between the two writes leaves agents newer than the
    checkpoint, which resuming overwrites, never a checkpoint whose agents are missing (the
    first) or older than it (`evaluate run=<folder>` of a killed run reads them)."""
    try:
        algo.save_agents(run_dir)
    except OSError as exc:  # a full disk: name what was being saved, as save_checkpoint does
        raise CheckpointError(
            f"cannot save checkpoint {Path(run_dir) / CHECKPOINT_NAME}: its agents: "
            f"{type(exc).__name__}: {exc}."
        ) from exc
    save_run_state(run_dir, tracker, cfg, algo.state_dict())


def snapshot(algo: Trainable, run_dir: Path, marks: Sequence[float]) -> None:
    """The run's agents and its choice at each CPU-time mark it has passed (`take_snapshots`);
    the choice's CPU is counted before the checkpoint that may end the run."""
    counters = algo.counters()
    info = {
        **counters.axes(),
        **algo.snapshot_info(),
    }

    def save(folder: Path) -> None:
        algo.say(exported(algo.export(folder)))

    saved, spent = take_snapshots(run_dir, marks, counters.cpu_time, save, info, algo.cpu_meter)
    algo.add_cpu_time(spent)
    for minutes in saved:
        algo.say(f"snapshot at {minutes:g} CPU minutes")


def exported(record: dict[str, Any]) -> str:
    """What a run says of the agent it exported (a `selection` choice record)."""
    own = f", own-terrain choice: {record['own']}" if "own" in record else ""
    return (
        f"exports {record['exported']} (held-out choice: {record.get('validation', 'none')}"
        f"{own}; {record['cpu_s']:.0f} CPU s)"
    )


# --- a run's checkpoint, snapshots and stop ---------------------------------------------------


def save_run_state(run_dir: Path, tracker: Tracker, cfg: Config, state: dict[str, Any]) -> Path:
    """Checkpoint a run's state with its config and the MLflow run id it continues."""
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
    clock: str | None,
    count: int,
    unit: str,
    seconds: float,
    cpu_seconds: float,
) -> None:
    """Tag why the run ended (`stop_reason`: the budget's `unit`, iterations or frames, or the
    clock that ended it first, `hours` or `cpu_hours`) and say so when a clock ended it: a resume
    with a larger budget on that clock continues."""
    tracker.set_tags({"stop_reason": clock or unit})
    if clock is not None:
        kind, limit = (
            ("wall-clock", budget.hours) if clock == "hours" else ("CPU-time", budget.cpu_hours)
        )
        print(
            f"[{name}] stopped at the {kind} budget (budget.{clock}={limit:g}) after {count} {unit}, "
            f"{seconds / 3600:.3g} h of training and {cpu_seconds / 3600:.3g} CPU hours; resume "
            f"with a larger budget.{clock} to continue",
            flush=True,
        )


SNAPSHOTS = "snapshots"  # <run folder>/snapshots/cpu<minutes>/: the agents at a CPU-time mark
SNAPSHOT_INFO = "snapshot.json"


def snapshot_folder(run_dir: Path, minutes: float) -> Path:
    return Path(run_dir) / SNAPSHOTS / f"cpu{minutes:g}"


def take_snapshots(
    run_dir: Path,
    marks: Sequence[float],
    cpu_seconds: float,
    save: Callable[[Path], object],
    info: dict[str, float],
    meter: CpuMeter,
) -> tuple[list[float], float]:
    """Save the run's agents (`save(folder)`: the agents and the run's choice among them) once
    for every mark of `marks` (CPU minutes) that the run's CPU time has passed and that has no
    snapshot yet, so success can be measured against compute from one run. Returns the marks
    saved and the CPU seconds the saving took (`meter`, lapped: the caller adds them to the
    run's CPU time), so a snapshot's choice is counted even at the run's last mark, after
    which no step laps the meter again; snapshot.json's `cpu_time` includes them. A snapshot
    is complete when its `snapshot.json` exists (written last, atomically): a run killed while
    saving writes it again on resume."""
    saved, spent = [], 0.0
    for minutes in marks:
        folder = snapshot_folder(run_dir, minutes)
        if cpu_seconds < minutes * 60 or (folder / SNAPSHOT_INFO).is_file():
            continue
        save(folder)
        spent += meter.lap()  # since the caller's last lap: the saving and what just preceded it
        counted = {**info, "cpu_time": info["cpu_time"] + spent, "choice_cpu_s": spent}
        with atomic_write(folder / SNAPSHOT_INFO) as file:
            file.write(json.dumps({"cpu_minutes": minutes, **counted}, indent=1).encode())
        saved.append(minutes)
    return saved, spent
