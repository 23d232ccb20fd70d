"""The agent an ePOET (or ePOET-SAC) run exports as its own, `policies/agent.npz`, beside the
pool's niche agents: chosen among every niche's best and last parameters by `selection`
(epoet/rollout/selection.py), at every CPU-time snapshot and at the end of the run.

Both readings are recorded in `policies/choice.json`: the held-out choice and the run's own
(the niche with the best score on its own terrain, today's `evaluate run=<run folder>` pick
before held-out terrains), so tables can be made from either.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from epoet.rollout.agent_files import ES_POLICIES, EXPORTED_AGENT, write_es_policy
from epoet.rollout.selection import es_held_out, write_choice

if TYPE_CHECKING:
    from epoet.config import Config
    from epoet.poet.loop import EPOET


def candidates(loop: EPOET) -> tuple[list[str], np.ndarray, list[float]]:
    """Every niche's best and last raw-observation parameters (a pair whose last is its best
    counts once), their names (`env<N>/best`, `env<N>/final`) and own-terrain scores."""
    names, thetas, scores = [], [], []
    for pair in loop.pool.pairs:
        final = loop.service.policy(pair.theta)
        best = pair.best_theta if pair.best_theta is not None else final
        for which, theta, score in (("best", best, pair.best_score), ("final", final, pair.score)):
            if which == "final" and np.array_equal(theta, best):
                continue
            names.append(f"env{pair.env.index}/{which}")
            thetas.append(theta)
            scores.append(float(score))
    return names, np.stack(thetas), scores


def export_agent(loop: EPOET, folder: Path, cfg: Config) -> dict[str, Any]:
    """Choose the run's agent, write it and the choice record into `folder`/policies/; returns
    the record."""
    started = time.process_time()
    names, thetas, scores = candidates(loop)
    # The run's own rule: the best score on its own terrain, the earlier niche on a tie.
    own = names[max(range(len(names)), key=lambda k: (scores[k], -k))]
    record: dict[str, Any] = {"rule": cfg.selection.rule, "own": own}
    if cfg.selection.terrains:
        held_out = es_held_out(
            thetas,
            names,
            loop.service.evaluator.agent,
            loop.service.terrain_cfg,
            cfg.selection,
            loop.service.run_seed,
            loop.layer_sizes,
            cfg.workers.batch,
            cfg.budget.score_scale,
        )
        record.update(validation=held_out["chosen"], candidates=held_out["candidates"])
    exported = record["validation"] if cfg.selection.rule == "validation" else own
    k = names.index(exported)
    record.update(
        exported=exported,
        iteration=loop.iteration,
        selection=asdict(cfg.selection),
        cpu_s=time.process_time() - started,
    )
    write_es_policy(
        folder / ES_POLICIES / EXPORTED_AGENT,
        thetas[k],
        scores[k],
        loop.layer_sizes,
        loop.service.evaluator.agent,
        choice=exported,
    )
    write_choice(folder / ES_POLICIES, record)
    return record
