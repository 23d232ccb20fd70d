"""ePOET's reproduce step (paper Algorithm 1; Enhanced POET's `adjust_envs_niches`): eligible
parents propose mutated children, the minimal criterion keeps those neither too hard nor too
easy for their parent's agent, and the most novel (PATA-EC) are admitted with the best agent
that passes the minimal criterion on them. Plain steps over the pool and the service.
"""

from __future__ import annotations

import numpy as np

from epoet.open_ended.config import EpoetConfig
from epoet.open_ended.keys import Key
from epoet.open_ended.novelty import pata_ec, rank_by_novelty
from epoet.open_ended.pairs import Child, Environment, Pair, Pool
from epoet.open_ended.service import FineTune, Service
from epoet.terrain import MutationError


def reproduce(pool: Pool, service: Service, cfg: EpoetConfig, t: int) -> int:
    """Propose children of eligible environments and admit the most novel that pass; returns
    how many were admitted."""
    parents = [p for p in pool.active if p.score >= pool.thresholds.repro]
    if not parents:
        return 0
    passing = minimal_criterion(pool, service, propose_children(service, cfg, parents, t), t)
    if not passing:
        return 0
    return admit_most_novel(pool, service, cfg, passing, t)


def propose_children(
    service: Service, cfg: EpoetConfig, parents: list[Pair], t: int
) -> list[tuple[Child, Pair]]:
    """Up to `num_children` valid mutations (the terrain generator's) of randomly chosen
    eligible parents."""
    rng = np.random.default_rng(service.seed(Key.PARENTS, t))
    children = []
    for slot in range(cfg.num_children):
        parent = parents[int(rng.integers(len(parents)))]
        try:
            genome = service.child_genome(
                parent.env, service.seed(Key.CHILD_GENOME, parent.env.index, t, slot)
            )
        except MutationError:
            continue  # this parent yielded no valid child in its tries; propose the next
        env = Environment(
            index=-1,
            genome=genome,
            generation=parent.env.generation + 1,
            parent=parent.env.index,
            created_at=t,
        )
        terrain = service.make_terrain(env, service.seed(Key.CHILD_BOWL, t, slot), t)
        children.append((Child(env, terrain, slot), parent))
    return children


def minimal_criterion(
    pool: Pool, service: Service, children: list[tuple[Child, Pair]], t: int
) -> list[Child]:
    """Children on which their parent's agent neither fails nor already excels."""
    if not children:
        return []
    scores = service.scores(
        [
            service.eval_request(child.terrain, parent.theta[None], Key.MC, t, child.slot)
            for child, parent in children
        ]
    )
    return [
        child
        for (child, _), score in zip(children, scores)
        if pool.thresholds.passes_mc(float(score[0]))
    ]


def admit_most_novel(
    pool: Pool, service: Service, cfg: EpoetConfig, passing: list[Child], t: int
) -> int:
    """In order of PATA-EC novelty, admit children whose best transferred agent also passes
    the minimal criterion (the reference's rule), at most `max_admitted` of them."""
    th = pool.thresholds
    pairs = pool.pairs
    agents = np.stack([p.theta for p in pairs])
    requests = [
        service.eval_request(service.terrain(p.env, t), agents, Key.PATA, p.env.index, t)
        for p in pairs
    ] + [service.eval_request(c.terrain, agents, Key.CHILD_PATA, t, c.slot) for c in passing]
    ranks = [pata_ec(s, th.mc_lower, th.mc_upper) for s in service.scores(requests)]
    order, _ = rank_by_novelty(
        np.stack(ranks[len(pairs) :]), np.stack(ranks[: len(pairs)]), k=cfg.novelty_k
    )
    admitted = 0
    for i in order:
        child = passing[i]
        score, theta = best_agent_for(pool, service, cfg, child, t)
        if not th.passes_mc(score):
            continue
        child.env.index = pool.next_index
        pool.admit(child.env, service.optimizer_for(child.env, theta))
        service.keep_terrain(child.env, t, child.terrain)
        admitted += 1
        if admitted == cfg.max_admitted:
            break
    return admitted


def best_agent_for(
    pool: Pool, service: Service, cfg: EpoetConfig, child: Child, t: int
) -> tuple[float, np.ndarray]:
    """(score, theta) of the best active agent on a child, directly or after one fine-tuning ES
    step (`proposal_step`) with a fresh optimiser, as the reference's candidate pair takes it."""
    slot = child.slot
    thetas = np.stack([p.theta for p in pool.active])
    direct = service.scores([service.eval_request(child.terrain, thetas, Key.ADMIT, t, slot, 0)])[0]
    # A fresh optimiser per candidate: initial lr and sigma, no Adam state (its own noise
    # stream is unused: the step's noise comes from keyed seeds).
    tuned = service.fine_tune(
        [
            FineTune(service.new_es(theta, 0), child.terrain, theta, (t, slot, j))
            for j, theta in enumerate(thetas)
        ],
        Key.ADMIT_NOISE,
        Key.ADMIT_SPAWN,
        cfg.proposal_step,
    )
    scores = service.scores(
        [
            service.eval_request(child.terrain, theta[None], Key.ADMIT, t, slot, j + 1)
            for j, theta in enumerate(tuned)
        ]
    )
    best = int(np.argmax(direct))
    best_score, best_theta = float(direct[best]), thetas[best]
    for theta, score in zip(tuned, scores):
        if score[0] > best_score:
            best_score, best_theta = float(score[0]), theta
    return best_score, best_theta.copy()
