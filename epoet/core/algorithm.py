"""What an algorithm is to the platform: one record (`Algorithm`), declared beside its settings'
schema, and the interface that schema implements (`AlgoSettings`, the type of `Config.algo`).

The record is the one place an algorithm's name, family (what its budget counts and which
metrics it logs: `Family.metrics`), runner, schema and figure style are written; composition
(epoet/config.py), the run (epoet/run.py), `make paper` and analysis read it through
epoet/registry.py, which imports the records by name. It lives in `core` so that every
algorithm's schema module can declare one without importing anything above it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, ClassVar, Self

# What every algorithm logs, each at every step that has a `score` (the driver logs them from
# its counters, epoet/driver.py): the score (ePOET: its best active pair's evaluation; a
# baseline: its deterministic evaluation return), the best so far and the x-axes. Their readers
# take the names from here: the learning-curve figure (analysis/figures.py) draws SCORE against
# ENV_STEPS and ELAPSED (or CPU_TIME); a run's record keeps them all (pipeline/snapshots.py).
SCORE = "score"
BEST_SCORE = "best_score"
ENV_STEPS = "env_steps"  # environment steps (a baseline's frames)
ELAPSED = "elapsed"  # wall seconds of training, summed over resumes
CPU_TIME = "cpu_time"  # CPU seconds of the run's processes, summed over resumes
AXES = (ENV_STEPS, ELAPSED, CPU_TIME)
SCORE_METRICS = (SCORE, BEST_SCORE, *AXES)


class Family(Enum):
    """What an algorithm trains and so what its budget counts. The value names the folder of
    the values every algorithm of the family runs on a budget,
    conf/algo_budget/<value>/<budget>.yaml. Declaration order is table and legend order."""

    BASELINE = "baselines"  # one agent learning from environment frames
    OPEN_ENDED = "open_ended"  # an open-ended pool of environment-agent pairs, trained by ES

    @property
    def counts(self) -> str:
        """The unit of the family's budget: environment frames or iterations of the ES loop."""
        return "frames" if self is Family.BASELINE else "iterations"

    @property
    def curve(self) -> str:
        """The metric of the family's own curves (analysis/curves.py): a baseline's score (its
        evaluation return, which the driver logs for every algorithm) against frames; a pool's
        mean ES return per pair, `pair<N>/return_mean`, of which every run logs pair 0's."""
        return SCORE if self is Family.BASELINE else "pair0/return_mean"

    @property
    def metrics(self) -> tuple[str, ...]:
        """What every run of the family logs (the metrics contract; tests/test_evaluation.py
        runs every registered algorithm and checks it)."""
        return tuple(dict.fromkeys((*SCORE_METRICS, self.curve)))


@dataclass
class AlgoSettings:
    """What a run asks of its algorithm's settings (`cfg.algo`): every algorithm's schema is a
    dataclass subclassing this one. `name` is filled in from the record when the schema is
    registered (epoet/config.py), so an algorithm's YAML does not repeat it."""

    KEY: ClassVar[str] = "algo"

    name: str  # the algorithm's record name: algo=<name>, its runs' `algo` tag

    @classmethod
    def of(cls, cfg: Any) -> Self:
        """`cfg.algo` (`cfg`: the root Config) as this schema, what a runner reads its own
        settings through; TypeError if the run is another algorithm's (a runner's bug)."""
        algo = cfg.algo
        if not isinstance(algo, cls):
            raise TypeError(f"algo={algo.name} has {type(algo).__name__}, not {cls.__name__}.")
        return algo

    def check_run(self, cfg: Any) -> None:
        """What the algorithm needs of the run's other settings (`cfg`: the root Config; it is
        above this module's layer); ConfigError in one sentence. Nothing, unless overridden."""

    def check_inputs(self, cfg: Any) -> None:
        """What a new run starts from beyond its config (ePOET-SAC's `algo.sac_init`), checked
        by epoet/run.py before the tracker opens; ConfigError in one sentence. It may import
        the algorithm's code (inside the method: composition stays light). Nothing, unless
        overridden."""

    def unused_keys(self) -> Sequence[str]:
        """Dotted keys (and key prefixes) of the run's settings this algorithm never reads, left
        out of its MLflow params. None, unless overridden."""
        return ()


# An algorithm's training: train(cfg, tracker, run_dir, resume) -> its final state (`cfg`: the
# root Config; `resume`: the checkpoint's state, None for a new run).
Runner = Callable[[Any, Any, Path, "dict[str, Any] | None"], Any]


@dataclass(frozen=True)
class Algorithm:
    """One algorithm, declared once, as a module-level value of the module that defines its
    schema (epoet/<package>/config.py), which epoet/registry.py imports."""

    name: str  # conf/algo/<name>.yaml, `algo=<name>`, its runs' `algo` tag
    family: Family
    schema: type[AlgoSettings]  # its settings, checked at composition and by `validate`
    # Returns the runner, importing it (the import sits inside this function, so composing a
    # config imports no torch): the one arrow from a schema module up into its algorithm's code.
    runner: Callable[[], Runner]
    label: str  # its name in figures
    colour: str  # its colour in figures (a matplotlib colour)
    # The algorithm the paper claims this one beats (ePOET-SAC ePOET, ePOET SAC, SAC PPO):
    # the claims analysis.comparisons reads as paired differences; None for no claim.
    beats: str | None = None
