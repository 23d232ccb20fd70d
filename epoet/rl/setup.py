"""What the three baselines' runs share besides the env (env.py) and the networks (nets.py): the
compute plan, evaluation and the collector. PPO's and SAC's loops and updates live in their own
files (ppo.py, sac.py; vmpo.py runs PPO's loop with the V-MPO loss of vmpo_loss.py); a run's
bookkeeping (counters, checkpoints, resume) in run_state.py; the exported policy in
policy_file.py.

Data flow of one run:

    env.make_env --Collector(actor)--> batch of frames_per_batch --> the algorithm's update -->
        metrics --> tracker; every budget.eval_every frames a deterministic evaluation on a
        second env.

Evaluation (the paper's tables do not fix it): `budget.eval_episodes` episodes of the
deterministic policy on a separate env whose terrains come from a fixed seed, at the training
env's current point of the height schedule, at frame 0, every `budget.eval_every` frames and at
the end. It runs under `fork_rng`, so it never changes the training's random streams.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, ExplorationType
from torchrl.envs.utils import set_exploration_type
from torchrl.modules import ProbabilisticActor

from epoet.config import Config
from epoet.es.workers import default_workers
from epoet.rl.env import hexapod


# --- compute plan ---------------------------------------------------------------------------------

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


def batch_plan(cfg: Config) -> BatchPlan:
    frames = min(cfg.algo.frames_per_batch, cfg.budget.frames)
    return BatchPlan(frames, math.ceil(cfg.budget.frames / frames),
                     frames / cfg.algo.frames_per_batch)


def set_threads(cfg: Config) -> int:
    """torch threads = workers.num, else the cores this process may use; returns the count."""
    threads = cfg.workers.num or default_workers()
    torch.set_num_threads(threads)
    return threads


# --- evaluation -----------------------------------------------------------------------------------

def evaluate(env: EnvBase, actor: ProbabilisticActor, episodes: int, seed: int,
             episode_index: int, max_steps: int) -> dict[str, float]:
    """Mean return, length and finish rate of `episodes` deterministic-policy episodes.

    Terrains come from `seed` at height-schedule position `episode_index`, so evaluations at the
    same schedule point see the same terrains.
    """
    returns, lengths, finished = [], [], []
    with torch.random.fork_rng(devices=[]), torch.no_grad(), \
            set_exploration_type(ExplorationType.DETERMINISTIC):
        env.set_seed(seed)
        hexapod(env).episodes = episode_index
        for _ in range(episodes):
            td = env.rollout(max_steps, policy=actor)
            returns.append(float(td["next", "reward"].sum()))
            lengths.append(td.shape[0])
            finished.append(bool(td["next", "finished"].any()))
    return {"return_mean": float(np.mean(returns)), "return_std": float(np.std(returns)),
            "length_mean": float(np.mean(lengths)), "finish_rate": float(np.mean(finished))}


# --- collection -----------------------------------------------------------------------------------

def make_collector(env: EnvBase, actor: ProbabilisticActor, plan: BatchPlan,
                   random_frames: int = 0) -> Collector:
    """Batches of `plan.frames_per_batch` frames from the stochastic actor, forever (the loop
    counts); the first `random_frames` frames use uniform random actions (SAC)."""
    return Collector(env, actor, frames_per_batch=plan.frames_per_batch, total_frames=-1,
                     init_random_frames=random_frames, exploration_type=ExplorationType.RANDOM,
                     auto_register_policy_transforms=False)  # the policy is not recurrent
