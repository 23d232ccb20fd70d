"""PATA-EC environment characterisation and novelty (docs/reference.md, Enhanced POET).

An environment is characterised by how the current agents rank on it: evaluate every active and
archived agent, clip the scores to the minimal-criterion band [mc_lower, mc_upper], and turn them
into centered ranks in [-0.5, 0.5]. A candidate is novel when its rank vector is far from those of
the existing environments. All vectors compared must come from the same agents in the same order.

Two decisions differ from the reference code:
- Ties get their average rank. Clipping exists to make "too hard" (or "too easy") agents
  indistinguishable; the reference's argsort ranks order such ties by agent index, which turns
  an environment where every agent fails into the same vector as one with a real index-ordered
  ranking. With average ranks an all-tied environment is the zero vector.
- A single agent (reference defect 6: 0/0) gets rank 0.0, the middle of the range.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata


def pata_ec(scores: np.ndarray, mc_lower: float, mc_upper: float) -> np.ndarray:
    """Centered, tie-averaged ranks of clipped scores along the last axis (same shape).

    `scores` is (n_agents,) for one environment or (n_envs, n_agents) for several.
    """
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim not in (1, 2) or scores.shape[-1] == 0:
        raise ValueError(
            f"scores must have shape (n_agents,) or (n_envs, n_agents) with "
            f"n_agents >= 1, got {scores.shape}."
        )
    if np.isnan(scores).any():
        raise ValueError("PATA-EC scores contain NaN.")
    n_agents = scores.shape[-1]
    if n_agents == 1:
        return np.zeros_like(scores)
    ranks = rankdata(np.clip(scores, mc_lower, mc_upper), method="average", axis=-1) - 1.0
    return ranks / (n_agents - 1) - 0.5


def _check_archive(archive: np.ndarray, n_agents: int) -> np.ndarray:
    archive = np.asarray(archive, dtype=np.float64)
    if archive.ndim == 1 and archive.size == 0:
        archive = archive.reshape(0, n_agents)  # "no environments yet" written as []
    if archive.ndim != 2 or archive.shape[1] != n_agents:
        raise ValueError(
            f"archive must have shape (m, {n_agents}) to match the candidate's "
            f"{n_agents} agents, got {archive.shape}."
        )
    return archive


def novelty(candidate: np.ndarray, archive: np.ndarray, k: int) -> float:
    """Mean Euclidean distance from `candidate` (n_agents,) to its k nearest rows of `archive`.

    `archive` (m, n_agents) holds the PATA-EC vectors of all active and archived environments;
    with m < k all m are used. With no environments at all (m = 0) every candidate is infinitely
    novel: +inf, so ranking falls back to candidate order and nothing produces NaN.
    """
    candidate = np.asarray(candidate, dtype=np.float64)
    if candidate.ndim != 1 or candidate.size == 0:
        raise ValueError(
            f"candidate must be a non-empty (n_agents,) vector, got {candidate.shape}."
        )
    return float(novelties(candidate[None, :], archive, k)[0])


def novelties(candidates: np.ndarray, archive: np.ndarray, k: int) -> np.ndarray:
    """`novelty` of each row of `candidates` (c, n_agents) against the same `archive`."""
    candidates = np.asarray(candidates, dtype=np.float64)
    if candidates.ndim != 2 or candidates.shape[1] == 0:
        raise ValueError(
            f"candidates must have shape (c, n_agents) with n_agents >= 1, got {candidates.shape}."
        )
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}.")
    archive = _check_archive(archive, candidates.shape[1])
    if archive.shape[0] == 0:
        return np.full(candidates.shape[0], np.inf)
    distances = np.linalg.norm(candidates[:, None, :] - archive[None, :, :], axis=-1)
    nearest = np.sort(distances, axis=1)[:, : min(k, archive.shape[0])]
    return nearest.mean(axis=1)


def rank_by_novelty(
    candidates: np.ndarray, archive: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """(order, novelties): candidate indices most novel first (ties by index) and their novelty."""
    scores = novelties(candidates, archive, k)
    # Stable sort on -novelty: equal novelties (e.g. all +inf) keep the proposal order.
    return np.argsort(-scores, kind="stable"), scores
