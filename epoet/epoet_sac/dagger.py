"""DAgger (Ross, Gordon & Bagnell 2011): the SAC actor mapped into the ES network by training
the ES network on the states it visits itself.

Behaviour cloning (bridge.py `distill_into_es`) fits the [40, 40] tanh student to the actor's
mean action on replay states; once the student's small errors take it off those states it meets
states nobody labelled, falls and never recovers (covariate shift: the errors compound over the
episode, Ross et al.'s O(T^2) against DAgger's O(T)). DAgger labels the states the student
itself reaches:

    D <- the teacher's own states on the join terrain, labelled tanh(loc(s));  fit student on D
    repeat `rounds` times:
        roll the student out on the join terrain (the real rollout engine, as the pool's agents)
        D <- D + its states labelled by the teacher;  refit the student on D (from where it is)

Round 0 rolls out the teacher alone and later rounds the student alone (Ross et al.'s
beta_1 = 1, beta_i = 0 for i > 1, the mixing schedule they report works best in practice). The
student is refitted from where the previous round left it, not from scratch, so each round
costs `epochs` passes over D. Every random choice (spawn starts, minibatch order) comes from a
seed the caller derives from the run's keys, so a mapping is a function of the run's seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
import torch

from epoet.epoet_sac.bridge import es_module, es_theta, fit
from epoet.epoet_sac.config import DaggerConfig
from epoet.rollout.policy import Standardizer

Teacher = Callable[[np.ndarray], np.ndarray]
"""Raw observations (N, obs) -> the teacher's actions (N, act) in [-1, 1]."""
Rollout = Callable[[np.ndarray, int], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""(ES vector in the pool's space, round) -> the visited raw observations (M, obs), the
episodes' returns and lengths: the student's episodes of that round."""


class Dagger(NamedTuple):
    """A DAgger mapping's result and what it cost."""

    theta: np.ndarray
    error: float  # the final mean squared action error over all the labelled states
    student_returns: list[float]  # the student's mean return in each round's rollouts
    episodes: int  # the student's episodes (the teacher's round 0 is the caller's to count)
    env_steps: int  # the student's environment steps
    states: int  # labelled states at the end
    seconds: float  # wall time of the rollouts and the fitting


def dagger_into_es(
    teacher: Teacher,
    teacher_states: np.ndarray,
    roll_out: Rollout,
    init: np.ndarray,
    layer_sizes: Sequence[int],
    cfg: DaggerConfig,
    *,
    seed: int,
    standardizer: Standardizer | None = None,
) -> Dagger:
    """Map `teacher` into an ES vector from `init` by DAgger; `roll_out(theta, round)` returns
    the student's visited raw observations, its episodes' returns and lengths. With the pool's
    `standardizer` the vector acts on standardised observations, as the pool's do."""
    started = time.perf_counter()
    generator = torch.Generator().manual_seed(seed)
    student = es_module(init, layer_sizes)

    def inputs(states: np.ndarray) -> torch.Tensor:
        if standardizer is not None:
            states = (states - standardizer.mean) / standardizer.std
        return torch.as_tensor(states, dtype=torch.float64)

    def labels(states: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(teacher(states), dtype=torch.float64)

    def refit() -> float:
        return fit(
            student,
            student,
            states,
            targets,
            epochs=cfg.epochs,
            batch=cfg.batch,
            lr=cfg.lr,
            generator=generator,
        )

    states, targets = inputs(teacher_states), labels(teacher_states)
    error = refit()
    returns: list[float] = []
    episodes = env_steps = 0
    for round_ in range(1, cfg.rounds + 1):
        visited, episode_returns, lengths = roll_out(es_theta(student, layer_sizes), round_)
        returns.append(float(np.mean(episode_returns)))
        episodes += len(lengths)
        env_steps += int(np.sum(lengths))
        states = torch.cat([states, inputs(visited)])
        targets = torch.cat([targets, labels(visited)])
        error = refit()
    return Dagger(
        es_theta(student, layer_sizes),
        error,
        returns,
        episodes,
        env_steps,
        len(states),
        time.perf_counter() - started,
    )
