"""Choosing a run's agent on held-out terrains (`selection`, docs/evaluation.md "Which agent a
run exports").

A pool's best score on its own terrain does not predict how an agent walks on terrains it never
trained on (docs/RESULTS.md), so a run picks the agent it exports the way procedurally generated
benchmarks keep validation levels apart from training and test levels: every candidate (each
niche's best and last parameters, a baseline's policy at each evaluation point) walks a small set
of CPPN terrains that the run generates from its own seed, never the evaluation suites, with the
evaluation's episode rules (long enough to reach the finish line), and the candidate that solves
most of them is exported. Ties go to the higher mean return, then to the earlier candidate.

The terrains are roots of new CPPN lineages mutated `generations` times, as the paper suite's
are children of a separate ePOET run, rendered at the relief and with the rendering of
`selection` (default: the paper suite's S = 1 m and the reference's rendering).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from epoet.core.files import atomic_write
from epoet.envs.config import AgentConfig
from epoet.rollout.backends.serial import SerialEvaluator
from epoet.rollout.config import SelectionConfig
from epoet.rollout.populations import Agents, Request
from epoet.terrain import Terrain, generator_for
from epoet.terrain.config import MutationError, TerrainConfig

# The seeds of held-out terrains and their episodes: their own stream of the run seed, apart
# from every keyed stream of a run's training (epoet.open_ended.keys numbers those from 0).
HELD_OUT_STREAM = 1000
LAST = "last"  # a baseline's own rule: its last policy (epoet/rl/candidates.py)
CHOICE_FILE = "choice.json"  # beside an exported agent: both choices and every candidate's record
SOLVED = 2000.0  # the paper's success: the finish line and a return of at least this x the
# budget's score scale (the suites' `solve_score`)


def stream(run_seed: int, *ids: int) -> np.random.SeedSequence:
    return np.random.SeedSequence([run_seed, HELD_OUT_STREAM, *ids])


def held_out_terrains(cfg: TerrainConfig, sel: SelectionConfig, run_seed: int) -> list[Terrain]:
    """The run's `sel.terrains` held-out CPPN terrains, a function of its seed and settings."""
    field = replace(cfg, kind="cppn", rendering=sel.rendering)
    generator = generator_for("cppn")
    terrains = []
    for i in range(sel.terrains):
        seeds = [int(s) for s in stream(run_seed, i).generate_state(sel.generations + 2)]
        genome = generator.encode(field, seeds[0])
        generation = 0
        for seed in seeds[1:-1]:
            try:
                genome, generation = generator.mutate(field, genome, seed), generation + 1
            except MutationError:  # no valid child from this seed: the lineage stops here
                break
        heights = generator.render(field, genome, seeds[-1], sel.max_height)
        terrains.append(
            Terrain(
                heights, sel.max_height, field.size, "cppn", seeds[-1], generation, None, genome
            )
        )
    return terrains


@dataclass(frozen=True)
class Candidate:
    """An agent a run may export: its name (e.g. `env3/final`) and what it runs."""

    name: str
    params: Any  # ES policy parameters (P,), or a torch policy's file


def rank(names: Sequence[str], solved: np.ndarray, returns: np.ndarray) -> dict[str, Any]:
    """The held-out record of candidates whose episodes gave `solved` and `returns`, (K, ...)
    each: per candidate its solved share and mean return, and the chosen one's name."""
    share = solved.reshape(len(names), -1).mean(axis=1)
    mean = returns.reshape(len(names), -1).mean(axis=1)
    candidates = {
        name: {"solved": float(s), "mean_return": float(m)}
        for name, s, m in zip(names, share, mean)
    }
    return {"chosen": best_of(candidates), "candidates": candidates}


def best_of(candidates: dict[str, dict[str, float]]) -> str:
    """The candidate that solves most held-out episodes; ties go to the higher mean return, then
    to the earlier candidate (insertion order)."""
    names = list(candidates)
    k = max(
        range(len(names)),
        key=lambda k: (candidates[names[k]]["solved"], candidates[names[k]]["mean_return"], -k),
    )
    return names[k]


def es_held_out(
    thetas: np.ndarray,
    names: Sequence[str],
    agent: AgentConfig,
    terrain_cfg: TerrainConfig,
    sel: SelectionConfig,
    run_seed: int,
    layer_sizes: Sequence[int],
    batch: int,
    score_scale: float,
) -> dict[str, Any]:
    """ES candidates (K, P raw-observation parameters) on the held-out terrains, in this process
    (its CPU counts against the run's budget), with the evaluation's episode length."""
    rules = replace(agent, max_episode_steps=round(sel.episode_ratio * agent.max_episode_steps))
    terrain_cfg = terrain_cfg.reaching(sel.max_height)  # held-out S may exceed the run's cap
    terrains = held_out_terrains(terrain_cfg, sel, run_seed)
    requests = [
        Request(
            terrain,
            Agents.of(thetas, stream(run_seed, i, 1).generate_state(sel.episodes).astype(np.int64)),
        )
        for i, terrain in enumerate(terrains)
    ]
    with SerialEvaluator(rules, terrain_cfg, batch, layer_sizes) as evaluator:
        episodes = evaluator.run(requests)
    solved = np.stack([e.finished & (e.returns >= SOLVED * score_scale) for e in episodes], axis=1)
    returns = np.stack([e.returns for e in episodes], axis=1)
    return rank(names, solved, returns)


def policy_held_out(
    policies: Sequence[Callable[[np.ndarray], np.ndarray]],
    names: Sequence[str],
    agent: AgentConfig,
    terrain_cfg: TerrainConfig,
    sel: SelectionConfig,
    run_seed: int,
    score_scale: float,
) -> dict[str, Any]:
    """Policies (`act(obs) -> action`: a baseline's exported ones) on the held-out terrains, one
    step at a time in this process, with the evaluation's episode length."""
    from epoet.envs.terrain_env import TerrainEnv  # MuJoCo's gym env, for policies only

    rules = replace(agent, max_episode_steps=round(sel.episode_ratio * agent.max_episode_steps))
    terrain_cfg = terrain_cfg.reaching(sel.max_height)  # held-out S may exceed the run's cap
    terrains = held_out_terrains(terrain_cfg, sel, run_seed)
    shape = (len(policies), len(terrains), sel.episodes)
    solved, returns = np.zeros(shape, dtype=bool), np.zeros(shape)
    env = TerrainEnv(rules, terrain_cfg)
    try:
        for i, terrain in enumerate(terrains):
            env.set_terrain(terrain)
            starts = stream(run_seed, i, 1).generate_state(sel.episodes)
            for k, act in enumerate(policies):
                for e, start in enumerate(starts):
                    obs, info = env.reset(seed=int(start))
                    done, total = False, 0.0
                    while not done:
                        action = np.asarray(act(obs), dtype=np.float64)
                        if not np.isfinite(action).all():  # a diverged policy fails here
                            break
                        obs, reward, terminated, truncated, info = env.step(action)
                        total += reward
                        done = terminated or truncated
                    returns[k, i, e] = total
                    solved[k, i, e] = bool(info.get("finished")) and total >= SOLVED * score_scale
    finally:
        env.close()
    return rank(names, solved, returns)


def write_choice(folder: Path, record: dict[str, Any]) -> Path:
    """The choice record beside the exported agent, atomically."""
    path = Path(folder) / CHOICE_FILE
    with atomic_write(path) as file:
        file.write(json.dumps(record, indent=1).encode())
    return path
