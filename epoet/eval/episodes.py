"""One terrain's evaluation episodes, as a worker process runs them (`run_task`), and the pool of
worker processes that runs them (`evaluation_pool`): the part of an evaluation
(epoet.eval.evaluate) that happens away from the process that asked for it, and all a worker
imports.

An episode starts from a seed keyed by (evaluation seed, terrain, episode) (`episode_seeds`), so
two agents meet the same starts; each gives one row of `COLUMNS`.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from epoet.core.lifecycle import end_with
from epoet.envs.config import AgentConfig
from epoet.envs.terrain_env import TerrainEnv
from epoet.eval.agents import AgentSource
from epoet.eval.suite import SuiteTerrain
from epoet.terrain.config import TerrainConfig

COLUMNS = [
    "terrain",
    "level",
    "roughness",
    "episode",
    "start_seed",
    "return",
    "finished",
    "solved",
    "forward_distance",
    "length",
    "path_roughness",
]


@dataclass(frozen=True)
class Task:
    """One terrain's episodes: everything a worker process needs, picklable."""

    index: int
    terrain: SuiteTerrain
    agent: AgentSource
    agent_cfg: AgentConfig
    terrain_cfg: TerrainConfig
    seeds: tuple[int, ...]
    solve_return: float
    action_samples: int


_cache: dict[str, Any] = {}  # per worker process: the env and policy, built once


def _env_and_policy(task: Task) -> tuple[TerrainEnv, Any]:
    key = repr((task.agent, task.agent_cfg, task.terrain_cfg))
    if _cache.get("key") != key:
        if "env" in _cache:
            _cache["env"].close()
        if task.agent.kind == "torch":
            # One thread per process: the pool already has a process per core, and a 256-wide
            # actor's one-observation forward passes slowed ~100x when each process's threads
            # fought over the cores.
            import torch

            torch.set_num_threads(1)
        _cache.update(
            key=key, env=TerrainEnv(task.agent_cfg, task.terrain_cfg), policy=task.agent.load()
        )
    return _cache["env"], _cache["policy"]


def run_task(task: Task) -> tuple[int, list[list[Any]], list[np.ndarray], list[str]]:
    """The terrain's episodes: CSV rows, each episode's sampled actions, and a note for each
    episode cut short by non-finite (NaN or inf) actions.

    Such an episode ends before that action is applied, as a failed one (not finished, the
    return accumulated so far): an agent acting NaN on some terrain fails there, it does not end
    the evaluation (MuJoCo would otherwise step NaN controls).
    """
    env, policy = _env_and_policy(task)
    env.set_terrain(task.terrain)
    n_actions = env.action_space.shape[0]
    rows, samples, broken = [], [], []
    for episode, seed in enumerate(task.seeds):
        obs, info = env.reset(seed=seed)
        x0, total, path = info["x"], 0.0, [info["roughness"]]
        actions: list[np.ndarray] = []
        done = cut = False
        while not done:
            action = np.asarray(policy(obs), dtype=np.float64)
            cut = not np.isfinite(action).all()
            if cut:
                broken.append(f"{task.terrain.name} episode {episode} step {len(actions)}")
                break
            actions.append(action)
            obs, reward, terminated, truncated, info = env.step(action)
            total += reward
            path.append(info["roughness"])
            done = terminated or truncated
        taken = np.asarray(actions).reshape(len(actions), n_actions)
        keep = np.linspace(0, len(actions) - 1, min(task.action_samples, len(actions)))
        samples.append(taken[np.unique(np.rint(keep).astype(int))])
        finished = bool(info["finished"]) and not cut
        rows.append(
            [
                task.terrain.name,
                task.terrain.level,
                task.terrain.roughness,
                episode,
                seed,
                total,
                finished,
                finished and total >= task.solve_return,
                info["x"] - x0,
                info["steps"],
                float(np.mean(path)),
            ]
        )
    return task.index, rows, samples, broken


def episode_seeds(seed: int, terrain: int, episodes: int) -> tuple[int, ...]:
    return tuple(
        int(np.random.SeedSequence([seed, terrain, e]).generate_state(1)[0])
        for e in range(episodes)
    )


@contextmanager
def evaluation_pool(workers: int) -> Iterator[Executor | None]:
    """Worker processes for evaluations; None for one worker (episodes run in this process).
    One pool serves any number of evaluations (`make paper` runs every missing one through the
    same pool), so its start-up (imports, torch) is paid once."""
    if workers == 1:
        yield None
        return
    ctx = mp.get_context("forkserver")
    # The fork server imports this module (MuJoCo, the env, the agent loaders) once; each worker
    # is then a cheap fork instead of seconds of imports per process.
    ctx.set_forkserver_preload([__name__])
    # Workers end with this process, however it ends (epoet.core.lifecycle).
    with ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=end_with, initargs=(os.getpid(),)
    ) as pool:
        yield pool
