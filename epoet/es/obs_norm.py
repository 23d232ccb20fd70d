"""Observation normalisation for ES, as Salimans et al. (2017) use it: running statistics of the
observations the perturbed policies see, and a policy that acts on standardised observations.

The policy stays a plain MLP: standardising the input, (obs - mean) / std, is an affine map, so
it folds into the first layer (W1 / std per input row, b1 - (mean / std) @ W1). ES searches the
standardised space (`theta`); what runs, is evaluated and is exported is `fold(theta)`, a policy
on raw observations that evaluation, rendering and the agent files use unchanged.

Deviation from Salimans et al.: no clipping of the standardised observation to [-5, 5] (a clip
does not fold into a linear layer). As theirs, the variance has a floor of 1e-2, and the
statistics grow from a small share of the ES episodes (their 1 %).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from epoet.rollout.policy import Standardizer

VAR_FLOOR = 1e-2


class ObsNormalizer:
    """Running count, sum and sum of squares of observations; mean 0 and std 1 until the first
    update, so a run starts from the same policy as one without normalisation."""

    def __init__(self, dim: int) -> None:
        self.count = 0
        self.sum = np.zeros(dim)
        self.sumsq = np.zeros(dim)

    def update(self, obs: np.ndarray) -> None:
        obs = np.asarray(obs, dtype=np.float64)
        self.count += len(obs)
        self.sum += obs.sum(axis=0)
        self.sumsq += np.square(obs).sum(axis=0)

    @property
    def mean(self) -> np.ndarray:
        return self.sum / self.count if self.count else np.zeros_like(self.sum)

    @property
    def std(self) -> np.ndarray:
        if not self.count:
            return np.ones_like(self.sum)
        return np.sqrt(np.maximum(self.sumsq / self.count - np.square(self.mean), VAR_FLOOR))

    def standardizer(self, layer_sizes: Sequence[int]) -> Standardizer:
        return Standardizer(self.mean, self.std, tuple(layer_sizes))

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "sum": self.sum.copy(), "sumsq": self.sumsq.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count = int(state["count"])
        self.sum = np.array(state["sum"], dtype=np.float64)
        self.sumsq = np.array(state["sumsq"], dtype=np.float64)
