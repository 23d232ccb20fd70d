"""Environment-agent pairs, what the ePOET loop keeps for each environment it has admitted, and
the small records its steps pass around (thresholds, proposed children, fine-tuning jobs)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from epoet.es.optimizer import OpenAIES

if TYPE_CHECKING:
    from epoet.terrain import Terrain


@dataclass
class Environment:
    """An environment of the pool: a CPPN genome (or none for bowl-only) plus provenance.

    The concrete heightmap changes every iteration (the bowl part is redrawn and the maximum
    height grows, paper appendix "Generated Environments"), so the pool stores what is fixed.
    """

    index: int                  # admission order: 0 is the root environment
    genome: Any                 # neat-python genome of the CPPN part
    generation: int
    parent: int | None          # index of the parent environment
    created_at: int             # iteration of admission
    solved: bool = False        # its agent reached the reproduction threshold at some point


@dataclass
class Pair:
    """An environment with the agent that is optimised on it by its own OpenAI-ES."""

    env: Environment
    es: OpenAIES
    scores: list[float] = field(default_factory=list)   # evaluation score per iteration
    best_score: float = -np.inf  # the best evaluation score on this environment so far,
    best_theta: np.ndarray | None = None  # and the policy that scored it (EPOET.policy)

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


class FineTune(NamedTuple):
    """One proposal ES step: `theta` on `terrain` with `es`'s settings and state; `ids` key its
    noise and spawn seeds."""

    es: OpenAIES
    terrain: Terrain
    theta: np.ndarray
    ids: tuple[int, ...]
