"""ePOET's transfer step (paper Algorithm 1; Enhanced POET's `transfer`): every agent is tried
on every other active environment, and the best fine-tuned one that beats the incumbent's recent
best replaces it. A plain step over the pool and the service.
"""

from __future__ import annotations

import numpy as np

from epoet.open_ended.config import EpoetConfig
from epoet.open_ended.keys import Key
from epoet.open_ended.pairs import Pool
from epoet.open_ended.service import FineTune, Service


def transfer(pool: Pool, service: Service, cfg: EpoetConfig, t: int) -> dict[int, int]:
    """Try every other agent on each environment; the best fine-tuned one that beats the
    incumbent's recent best replaces it, resetting its optimiser. Returns the replacements,
    {target environment index: source environment index}.

    As the reference: direct transfers are evaluated first; those that beat the target's best
    score over its last `transfer_bar_window` evaluations are refined by one proposal ES step
    (`proposal_step`) at the target's sigma, and only a proposal that also beats that bar can be
    accepted (an untuned direct transfer never replaces an agent).
    """
    active = pool.active
    thetas = np.stack([p.theta for p in active])  # agents before any replacement
    others = [[j for j in range(len(active)) if j != m] for m in range(len(active))]
    bars = [max(p.scores[-cfg.transfer_bar_window :]) for p in active]
    direct = service.scores(
        [
            service.eval_request(
                service.terrain(target.env, t),
                thetas[others[m]],
                Key.TRANSFER,
                target.env.index,
                t,
                0,
            )
            for m, target in enumerate(active)
        ]
    )
    candidates = [
        (m, j)
        for m in range(len(active))
        for j, score in zip(others[m], direct[m])
        if score > bars[m]
    ]
    if not candidates:
        return {}
    proposals = service.fine_tune(
        [
            FineTune(
                active[m].es,
                service.terrain(active[m].env, t),
                thetas[j],
                (active[m].env.index, t, j),
            )
            for m, j in candidates
        ],
        Key.PROPOSAL_NOISE,
        Key.PROPOSAL_SPAWN,
        cfg.proposal_step,
    )
    scores = service.scores(
        [
            service.eval_request(
                service.terrain(active[m].env, t),
                proposal[None],
                Key.TRANSFER,
                active[m].env.index,
                t,
                j + 1,
            )
            for (m, j), proposal in zip(candidates, proposals)
        ]
    )
    best: dict[int, tuple[float, np.ndarray, int]] = {}
    for (m, j), proposal, score in zip(candidates, proposals, scores):
        if score[0] > max(bars[m], best.get(m, (-np.inf,))[0]):
            best[m] = (float(score[0]), proposal, j)
    for m, (best_score, theta, _) in best.items():
        pool.replace_agent(active[m], theta, best_score)
    return {active[m].env.index: active[j].env.index for m, (_, _, j) in best.items()}
