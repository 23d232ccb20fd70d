"""The agent an ePOET run (or a run of a loop that extends it) exports as its own, `policies/agent.npz`, beside the
pool's niche agents: chosen among every niche's best and last parameters by `selection`
(epoet/rollout/selection.py), at every CPU-time snapshot and at the end of the run.

Both readings are recorded in `policies/choice.json`: the held-out choice and the run's own
(the niche with the best score on its own terrain, today's `evaluate run=<run folder>` pick
before held-out terrains), so tables can be made from either.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from epoet.rollout.agent_files import ES_POLICIES, EXPORTED_AGENT, write_es_policy
from epoet.rollout.selection import es_held_out, write_choice

if TYPE_CHECKING:
    from epoet.config import Config
    from epoet.envs.config import AgentConfig
    from epoet.open_ended.loop import Epoet


class Niche(NamedTuple):
    """What a niche offers as candidates: its best and its last parameters with their scores."""

    env: int  # its environment's index
    best: np.ndarray
    best_score: float
    final: np.ndarray
    final_score: float


def niches_of(loop: Epoet) -> list[Niche]:
    """Every pair of the pool (active and archived) as raw-observation parameters."""
    niches = []
    for pair in loop.pool.pairs:
        final = loop.service.policy(pair.theta)
        best = pair.best_theta if pair.best_theta is not None else final
        niches.append(Niche(pair.env.index, best, pair.best_score, final, pair.score))
    return niches


def candidates(niches: Iterable[Niche]) -> tuple[list[str], np.ndarray, list[float]]:
    """Every niche's best and last parameters (a niche whose last is its best counts once),
    their names (`env<N>/best`, `env<N>/final`) and own-terrain scores."""
    names, thetas, scores = [], [], []
    for niche in niches:
        for which, theta, score in (
            ("best", niche.best, niche.best_score),
            ("final", niche.final, niche.final_score),
        ):
            if which == "final" and np.array_equal(theta, niche.best):
                continue
            names.append(f"env{niche.env}/{which}")
            thetas.append(theta)
            scores.append(float(score))
    return names, np.stack(thetas), scores


def choose(
    folder: Path,
    niches: Iterable[Niche],
    cfg: Config,
    agent: AgentConfig,
    layer_sizes: Sequence[int],
    **info: Any,
) -> dict[str, Any]:
    """Choose among the niches' candidates by `cfg.selection` (on the run's held-out terrains,
    `cfg.seed`'s), write the exported agent and the choice record (with `info`) into
    `folder`/policies/; returns the record."""
    started = time.process_time()
    names, thetas, scores = candidates(niches)
    # The run's own rule: the best score on its own terrain, the earlier niche on a tie.
    own = names[max(range(len(names)), key=lambda k: (scores[k], -k))]
    record: dict[str, Any] = {"rule": cfg.selection.rule, "own": own}
    if cfg.selection.terrains:
        held_out = es_held_out(
            thetas,
            names,
            agent,
            cfg.terrain,
            cfg.selection,
            cfg.seed,
            layer_sizes,
            cfg.workers.batch,
            cfg.budget.score_scale,
        )
        record.update(validation=held_out["chosen"], candidates=held_out["candidates"])
    exported = record["validation"] if cfg.selection.rule == "validation" else own
    k = names.index(exported)
    record.update(
        exported=exported,
        **info,
        selection=asdict(cfg.selection),
        cpu_s=time.process_time() - started,
    )
    write_es_policy(
        folder / ES_POLICIES / EXPORTED_AGENT,
        thetas[k],
        scores[k],
        layer_sizes,
        agent,
        choice=exported,
    )
    write_choice(folder / ES_POLICIES, record)
    return record


def export_agent(loop: Epoet, folder: Path, cfg: Config) -> dict[str, Any]:
    """Choose the run's agent among its pool's, at iteration `loop.iteration`."""
    agent = loop.service.evaluator.agent
    return choose(
        folder, niches_of(loop), cfg, agent, loop.service.layer_sizes, iteration=loop.iteration
    )
