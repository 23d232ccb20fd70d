"""Environment-agent pairs, what the ePOET loop keeps for each environment it has admitted, the
pool that holds them, the small records its steps pass around (thresholds, proposed children),
and what an iteration reports of them (ANNECS, the best score of each lineage)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Iterable

import numpy as np

from epoet.es.optimizer import OpenAIES

if TYPE_CHECKING:
    from epoet.terrain import Terrain


@dataclass
class Environment:
    """An environment of the pool: its encoding (the terrain generator's genome: a CPPN's neat
    genome) plus provenance.

    The concrete heightmap changes every iteration (the bowl part is redrawn and the maximum
    height grows, paper appendix "Generated Environments"), so the pool stores what is fixed.
    """

    index: int  # admission order: 0 is the root environment
    genome: Any  # the encoding the generator renders and mutates
    generation: int
    parent: int | None  # index of the parent environment
    created_at: int  # iteration of admission
    solved: bool = False  # its agent reached the reproduction threshold at some point


@dataclass
class Pair:
    """An environment with the agent that is optimised on it by its own OpenAI-ES."""

    env: Environment
    es: OpenAIES
    scores: list[float] = field(default_factory=list)  # evaluation score per iteration
    best_score: float = -np.inf  # the best evaluation score on this environment so far,
    best_theta: np.ndarray | None = None  # and the policy that scored it (Epoet.policy)

    @property
    def theta(self) -> np.ndarray:
        return self.es.theta

    @property
    def score(self) -> float:
        """Latest evaluation score (-inf before the first evaluation)."""
        return self.scores[-1] if self.scores else -np.inf


@dataclass(frozen=True)
class Thresholds:
    """The run's score thresholds: the paper's (set for 2000-step episodes) times the budget's
    score scale."""

    mc_lower: float
    mc_upper: float
    repro: float

    def passes_mc(self, score: float) -> bool:
        """The minimal criterion: neither too hard nor too easy."""
        return self.mc_lower <= score <= self.mc_upper


@dataclass
class Child:
    """A proposed child environment with the terrain the minimal criterion judged it on."""

    env: Environment
    terrain: Terrain
    slot: int


class Pool:
    """The environment-agent pairs of a run: the active ones, optimised every iteration, and the
    archive of those that left it (Enhanced POET's optimizers and archived optimizers)."""

    def __init__(
        self, max_active: int, thresholds: Thresholds, policy: Callable[[np.ndarray], np.ndarray]
    ) -> None:
        self.active: list[Pair] = []
        self.archived: list[Pair] = []
        self.next_index = 0  # the index the next admitted environment gets
        self.max_active = max_active
        self.thresholds = thresholds
        self.policy = policy  # ES parameters -> the policy a pair's best score keeps

    @property
    def pairs(self) -> list[Pair]:
        return self.active + self.archived

    def admit(self, env: Environment, es: OpenAIES) -> Pair:
        """A new active pair; beyond `max_active` the oldest pair leaves for the archive."""
        pair = Pair(env=env, es=es)
        self.active.append(pair)
        self.next_index = max(self.next_index, env.index + 1)
        if len(self.active) > self.max_active:
            self.archived.append(self.active.pop(0))
        return pair

    def record(self, pair: Pair, score: float) -> None:
        """The pair's evaluation this iteration: its best so far, and whether its environment
        has been solved (reached the reproduction threshold)."""
        pair.scores.append(score)
        if score > pair.best_score:
            pair.best_score, pair.best_theta = score, np.array(self.policy(pair.theta))
        pair.env.solved |= score >= self.thresholds.repro

    def replace_agent(self, pair: Pair, theta: np.ndarray, score: float) -> None:
        """A new agent for the pair (a transfer, a crossover child) with a fresh optimiser; its
        score, measured this iteration, stands in place of the old agent's."""
        pair.es.reset(theta)
        pair.scores.pop()
        self.record(pair, score)


def annecs(pairs: Iterable[Pair]) -> int:
    """ANNECS: admitted environments (not the root) whose agent reached the reproduction
    threshold, at admission or later."""
    return sum(p.env.solved for p in pairs if p.env.index > 0)


def best_by_lineage(pairs: Iterable[Pair], lineage: Callable[[Pair], int]) -> dict[str, float]:
    """`gen<g>/score`: the best active score of each lineage g (paper Figure 2's
    <algorithm>_gen<g> curves; ePOET's lineages are the environments' generations)."""
    best: dict[int, float] = {}
    for pair in pairs:
        g = lineage(pair)
        best[g] = max(best.get(g, -np.inf), pair.score)
    return {f"gen{g}/score": score for g, score in sorted(best.items())}
