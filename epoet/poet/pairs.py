"""Environment-agent pairs: what the ePOET loop keeps for each environment it has admitted."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from epoet.es.optimizer import OpenAIES


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
    sac_join: int = 0           # ePOET-SAC: k if the k-th join of the SAC actor made this pair
    best_score: float = -np.inf  # the best evaluation score on this environment so far,
    best_theta: np.ndarray | None = None  # and the policy that scored it (EPOET.policy)

    @property
    def theta(self) -> np.ndarray:
        return self.es.theta

    @property
    def score(self) -> float:
        """Latest evaluation score (-inf before the first evaluation)."""
        return self.scores[-1] if self.scores else -np.inf
