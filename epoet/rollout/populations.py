"""Populations: numbered sets of episodes whose parameters are rebuilt on demand from a compact
form, so that what crosses to a worker is small (theta, sigma and integer noise seeds for an ES
step; the K agents' parameter vectors for an evaluation), and `Request`, a population on one
terrain.

The perturbation eps of an ES episode is regenerated from an integer seed,
eps = default_rng(seed).standard_normal(P): the workers rebuild theta +- sigma * eps to run it,
and the optimiser (epoet.es.optimizer) the same eps for the gradient.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from epoet.rollout.engine import TerrainLike, check_seeds
from epoet.rollout.policy import Standardizer


def check_theta(theta: np.ndarray) -> np.ndarray:
    theta = np.asarray(theta, dtype=np.float64)
    if theta.ndim != 1 or theta.size == 0:
        raise ValueError(f"theta must be a non-empty 1-D vector, got shape {theta.shape}.")
    return theta


def noise(seed: int, num_params: int) -> np.ndarray:
    """The perturbation direction eps (num_params,) belonging to one integer seed."""
    return np.random.default_rng(int(seed)).standard_normal(num_params)


def mirrored_population(
    theta: np.ndarray, seeds: Sequence[int] | np.ndarray, sigma: float
) -> np.ndarray:
    """(2n, P) points to evaluate: row i is theta + sigma*eps_i, row n + i theta - sigma*eps_i."""
    theta = check_theta(theta)
    n = len(seeds)
    population = np.empty((2 * n, theta.size))
    for i, seed in enumerate(seeds):
        eps = noise(seed, theta.size)
        np.multiply(eps, sigma, out=eps)
        np.add(theta, eps, out=population[i])
        np.subtract(theta, eps, out=population[n + i])
    return population


class Population(Protocol):
    """A numbered set of episodes whose parameters are rebuilt on demand from a compact form."""

    @property
    def num_params(self) -> int: ...

    @property
    def shape(self) -> tuple[int, ...]:
        """How the episodes' results are arranged for the caller."""
        ...

    def __len__(self) -> int: ...

    def job(self, e: int) -> tuple[np.ndarray, int]:
        """(policy parameters, spawn seed) of episode e."""
        ...


@dataclass(frozen=True)
class Mirrored:
    """2n ES episodes in `mirrored_population` order: e < n is theta + sigma*eps_e, e >= n is
    theta - sigma*eps_(e-n); pair i's two episodes share spawn_seeds[i] (common random numbers)."""

    theta: np.ndarray
    sigma: float
    noise_seeds: np.ndarray
    spawn_seeds: np.ndarray
    standardizer: Standardizer | None = None  # theta acts on standardised observations

    @classmethod
    def of(
        cls,
        theta: np.ndarray,
        noise_seeds: np.ndarray,
        sigma: float,
        spawn_seeds: np.ndarray,
        standardizer: Standardizer | None = None,
    ) -> "Mirrored":
        """The checked population of one ES step around `theta`."""
        theta = np.asarray(theta, dtype=np.float64)
        noise = check_seeds(noise_seeds, "noise_seeds")
        spawn = check_seeds(spawn_seeds, "spawn_seeds")
        if theta.ndim != 1 or not theta.size:
            raise ValueError(f"theta must be a non-empty 1-D vector, got shape {theta.shape}.")
        if noise.ndim != 1 or not len(noise):
            raise ValueError(f"noise_seeds must be a non-empty 1-D array, got {noise.shape}.")
        if spawn.shape != noise.shape:
            raise ValueError(
                f"spawn_seeds must have one seed per noise seed {noise.shape}, got {spawn.shape}."
            )
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}.")
        return cls(theta, float(sigma), noise, spawn, standardizer)

    @property
    def num_params(self) -> int:
        return self.theta.size

    @property
    def shape(self) -> tuple[int, ...]:
        return (len(self),)

    def __len__(self) -> int:
        return 2 * len(self.noise_seeds)

    def job(self, e: int) -> tuple[np.ndarray, int]:
        n = len(self.noise_seeds)
        # The pair through `mirrored_population` itself: bit-identical to its rows e and n + e.
        pair = mirrored_population(self.theta, self.noise_seeds[e % n : e % n + 1], self.sigma)
        params = pair[e // n]
        if self.standardizer is not None:
            params = self.standardizer.fold(params)
        return params, int(self.spawn_seeds[e % n])


@dataclass(frozen=True)
class Agents:
    """K agents times n episodes each; episode e = k * n + j is agent k with spawn_seeds[k, j]."""

    thetas: np.ndarray  # (K, P)
    spawn_seeds: np.ndarray  # (K, n)

    @classmethod
    def of(cls, thetas: np.ndarray, spawn_seeds: np.ndarray) -> "Agents":
        """K agents' episodes: `spawn_seeds` (n,) gives all the same starts, (K, n) each its own."""
        thetas = np.asarray(thetas, dtype=np.float64)
        seeds = check_seeds(spawn_seeds, "spawn_seeds")
        if thetas.ndim != 2 or not thetas.size:
            raise ValueError(f"thetas must have shape (K, P) with K, P >= 1, got {thetas.shape}.")
        k = len(thetas)
        if seeds.ndim == 1:
            seeds = np.broadcast_to(seeds, (k, len(seeds)))
        if seeds.ndim != 2 or seeds.shape[0] != k or not seeds.shape[1]:
            raise ValueError(
                f"spawn_seeds must have shape (n,) or ({k}, n) with n >= 1, got "
                f"{np.shape(spawn_seeds)}."
            )
        return cls(thetas, np.ascontiguousarray(seeds))

    @property
    def num_params(self) -> int:
        return self.thetas.shape[1]

    @property
    def shape(self) -> tuple[int, ...]:
        return self.spawn_seeds.shape

    def __len__(self) -> int:
        return self.spawn_seeds.size

    def job(self, e: int) -> tuple[np.ndarray, int]:
        return self.thetas[e // self.spawn_seeds.shape[1]], int(self.spawn_seeds.flat[e])


class Request(NamedTuple):
    """A population of episodes on one terrain: the unit of work a call is made of.

    The transitions of its first `record` episodes (population order) are recorded, so a
    learner can take a bounded share of an ES step's experience (ePOET-SAC's shared replay).
    """

    terrain: TerrainLike
    population: Population
    record: int = 0
