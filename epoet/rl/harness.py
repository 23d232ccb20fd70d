"""The pieces of a baseline run (epoet/rl/baseline_run.py) that are not its steps: how the budget
maps onto collector batches, the collector, torch's threads, the loop's counters and what a run
returns. ePOET-SAC and the benchmarks take `set_threads` from here too.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import torch
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, ExplorationType
from torchrl.modules import ProbabilisticActor

from epoet.config import BaselineBudgetConfig, Config
from epoet.core.cores import default_workers
from epoet.rl.config import BaselineConfig, BaselineSettings

# --- the compute plan and the collector -----------------------------------------------------------


@dataclass(frozen=True)
class BatchPlan:
    """How a budget maps onto collector batches.

    budget.frames is the total; a batch is `algo.frames_per_batch` frames unless the budget is
    smaller, then the batch is the whole budget. `scale` (batch / algo.frames_per_batch) shrinks
    what is counted per batch in the config (SAC's updates and random frames), so the ratios of
    the paper -- e.g. 1000 SAC updates per 2000 frames -- hold at every budget. The run ends after
    `batches` batches, the first multiple of the batch at or above budget.frames.
    """

    frames_per_batch: int
    batches: int
    scale: float

    @property
    def total_frames(self) -> int:
        return self.frames_per_batch * self.batches

    def scaled(self, count: int, minimum: int = 0) -> int:
        """A per-batch count from the config, scaled to this batch size."""
        return max(minimum, round(count * self.scale))


def baseline(cfg: Config) -> BaselineSettings:
    """The run's baseline settings, as the baseline run reads them."""
    algo = cfg.algo
    if not isinstance(algo, BaselineConfig):
        raise TypeError(f"algo={algo.name} is not a baseline.")  # a runner's bug
    return cast(BaselineSettings, algo)


def batch_plan(cfg: Config) -> BatchPlan:
    budget = cast(BaselineBudgetConfig, cfg.budget)  # a baseline's record: the baselines family
    per_batch = baseline(cfg).frames_per_batch
    frames = min(per_batch, budget.frames)
    return BatchPlan(frames, math.ceil(budget.frames / frames), frames / per_batch)


def set_threads(cfg: Config) -> int:
    """torch threads = workers.num, else the cores this process may use; returns the count."""
    threads = cfg.workers.num or default_workers()
    torch.set_num_threads(threads)
    return threads


def make_collector(
    env: EnvBase, actor: ProbabilisticActor, plan: BatchPlan, random_frames: int = 0
) -> Collector:
    """Batches of `plan.frames_per_batch` frames from the stochastic actor, forever (the loop
    counts); the first `random_frames` frames use uniform random actions (SAC)."""
    return Collector(
        env,
        actor,
        frames_per_batch=plan.frames_per_batch,
        total_frames=-1,
        init_random_frames=random_frames,
        exploration_type=ExplorationType.RANDOM,
        auto_register_policy_transforms=False,
    )  # the policy is not recurrent


# --- the loop's counters and result ---------------------------------------------------------------


@dataclass
class LoopState:
    """The loop's counters (checkpointed with the learner)."""

    frames: int = 0
    batches: int = 0
    episodes: int = 0  # finished training episodes
    next_eval: int = 0  # frame count of the next evaluation
    last_eval_frames: int = -1
    last_eval: dict[str, float] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0  # seconds of training, summed over resumes
    cpu_time: float = 0.0  # CPU seconds of the run's processes (evaluations too), over resumes
    best_score: float = -math.inf  # the best evaluation return so far


@dataclass
class TrainResult:
    """What a baseline runner returns."""

    frames: int
    batches: int
    final_eval: dict[str, float]
    policy_path: Path
    learner: Any
