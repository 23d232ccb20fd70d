"""OpenAI-ES with mirrored sampling, centered ranks, L2 and Adam (docs/reference.md).

Perturbations are not read from a shared noise table (the reference's 1 GB per worker): each
eps_i is regenerated from an integer seed, eps_i = default_rng(seed_i).standard_normal(P). Workers
receive (theta, sigma, seeds) and send back returns; the same seeds rebuild eps_i here for the
gradient. The distribution is the same as the table's, and every step is a function of the
optimiser's own seed.

One step, for seeds s_1..s_n (n = n_pairs):
    evaluate R+_i = F(theta + sigma*eps_i) and R-_i = F(theta - sigma*eps_i)
    rank-shape all 2n returns jointly: r = rank/(2n - 1) - 0.5
    g = sum_i (r+_i - r-_i) * eps_i / (n * sigma)
    theta <- theta + Adam step that minimises (-g + l2 * theta)
    lr <- max(lr * lr_decay, lr_floor); sigma <- max(sigma * sigma_decay, sigma_floor)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from epoet.es.config import EsConfig
from epoet.rollout.populations import check_theta, noise

# Seeds are drawn as rng.integers(0, SEED_HIGH, dtype=int64): a 63-bit range makes a repeated
# seed within a run (hence a duplicated perturbation) practically impossible.
SEED_HIGH = 2**63 - 1
# Adam's usual constants (the reference's; not among the paper's settings)
ADAM_BETA1, ADAM_BETA2, ADAM_EPS = 0.9, 0.999, 1e-8


def centered_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks of x scaled to [-0.5, 0.5], same shape as x; ties keep argsort order (as OpenAI-ES).

    A single value gets 0.0 (the middle) instead of the reference's 0/0.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        raise ValueError("centered_ranks needs at least one value.")
    if np.isnan(x).any():
        raise ValueError("centered_ranks got NaN values.")
    if x.size == 1:
        return np.zeros_like(x)
    ranks = np.empty(x.size)
    # A stable sort makes tie-breaking (by position) independent of numpy's sort implementation.
    ranks[np.argsort(x.ravel(), kind="stable")] = np.arange(x.size)
    return (ranks / (x.size - 1) - 0.5).reshape(x.shape)


def _check_returns(
    seeds: Sequence[int] | np.ndarray, returns_pos: np.ndarray, returns_neg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    pos = np.asarray(returns_pos, dtype=np.float64)
    neg = np.asarray(returns_neg, dtype=np.float64)
    if len(seeds) < 1:
        raise ValueError("an ES step needs at least one seed.")
    if pos.shape != (len(seeds),) or neg.shape != (len(seeds),):
        raise ValueError(
            f"returns_pos and returns_neg must each have one value per seed "
            f"({len(seeds)}), got shapes {pos.shape} and {neg.shape}."
        )
    if not (np.isfinite(pos).all() and np.isfinite(neg).all()):
        raise ValueError("ES returns must be finite (got NaN or inf).")
    return pos, neg


def es_gradient(
    seeds: Sequence[int] | np.ndarray,
    returns_pos: np.ndarray,
    returns_neg: np.ndarray,
    sigma: float,
    num_params: int,
) -> np.ndarray:
    """Ascent direction g = sum_i (r+_i - r-_i) eps_i / (n sigma), r = centered ranks of all 2n."""
    pos, neg = _check_returns(seeds, returns_pos, returns_neg)
    if sigma <= 0:
        raise ValueError(f"sigma must be > 0, got {sigma}.")
    ranked = centered_ranks(np.concatenate([pos, neg]))
    n = len(seeds)
    weights = ranked[:n] - ranked[n:]
    g = np.zeros(num_params)
    for w, seed in zip(weights, seeds):
        g += w * noise(seed, num_params)  # one eps at a time: memory stays O(P)
    return g / (n * sigma)


def adam_step(
    theta: np.ndarray,
    grad: np.ndarray,
    m: np.ndarray,
    v: np.ndarray,
    t: int,
    lr: float,
    beta1: float,
    beta2: float,
    eps: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One Adam descent step on `grad`, returning new (theta, m, v, t); inputs are not modified.

    OpenAI-ES form: the bias correction is folded into the step size and eps is added to
    sqrt(v) without correction; this is what the reference optimiser computes.
    """
    t = t + 1
    m = beta1 * m + (1.0 - beta1) * grad
    v = beta2 * v + (1.0 - beta2) * grad * grad
    a = lr * np.sqrt(1.0 - beta2**t) / (1.0 - beta1**t)
    return theta - a * m / (np.sqrt(v) + eps), m, v, t


class OpenAIES:
    """The ES optimiser of one environment-agent pair: theta, Adam state, schedules, seed stream.

    Usage per step: `seeds = es.sample_seeds()`, evaluate `mirrored_population(es.theta, seeds,
    es.sigma)`, then `es.tell(seeds, returns[:n], returns[n:])`. `propose` is the same step
    without side effects, for transfer; `reset` accepts a transferred theta.
    """

    def __init__(
        self, theta: np.ndarray, seed: int | np.random.Generator, cfg: EsConfig, n_pairs: int
    ) -> None:
        self.n_pairs = n_pairs
        self.cfg = cfg
        self.rng = np.random.default_rng(seed)
        self.reset(theta)

    @property
    def num_params(self) -> int:
        return self.theta.size

    def reset(self, theta: np.ndarray) -> None:
        """Take `theta` as the agent: Adam state, lr and sigma restart; the seed stream goes on."""
        self.theta = check_theta(theta).copy()
        self.m = np.zeros_like(self.theta)
        self.v = np.zeros_like(self.theta)
        self.t = 0
        self.lr = self.cfg.lr
        self.sigma = self.cfg.sigma

    def sample_seeds(self) -> np.ndarray:
        """n_pairs perturbation seeds (int64) from this optimiser's own Generator."""
        return self.rng.integers(0, SEED_HIGH, size=self.n_pairs, dtype=np.int64)

    def _step(
        self,
        theta: np.ndarray,
        seeds: Sequence[int] | np.ndarray,
        returns_pos: np.ndarray,
        returns_neg: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:
        """(new theta, m, v, t, g) of one step from `theta`; no attribute is modified."""
        theta = check_theta(theta)
        if theta.size != self.num_params:
            raise ValueError(f"theta has {theta.size} parameters, the optimiser {self.num_params}.")
        g = es_gradient(seeds, returns_pos, returns_neg, self.sigma, self.num_params)
        new_theta, m, v, t = adam_step(
            theta,
            -g + self.cfg.l2_coeff * theta,
            self.m,
            self.v,
            self.t,
            self.lr,
            ADAM_BETA1,
            ADAM_BETA2,
            ADAM_EPS,
        )
        return new_theta, m, v, t, g

    def tell(
        self, seeds: Sequence[int] | np.ndarray, returns_pos: np.ndarray, returns_neg: np.ndarray
    ) -> dict[str, float]:
        """Apply one ES step from the returns of theta +- sigma*eps(seeds); return statistics."""
        new_theta, self.m, self.v, self.t, g = self._step(
            self.theta, seeds, returns_pos, returns_neg
        )
        update_norm = float(np.linalg.norm(new_theta - self.theta))
        stats = {
            "lr": self.lr,
            "sigma": self.sigma,
            "grad_norm": float(np.linalg.norm(g)),
            "update_norm": update_norm,
            "update_ratio": update_norm / max(float(np.linalg.norm(self.theta)), 1e-12),
            "theta_norm": float(np.linalg.norm(new_theta)),
        }
        self.theta = new_theta
        self.lr = max(self.lr * self.cfg.lr_decay, self.cfg.lr_floor)
        self.sigma = max(self.sigma * self.cfg.sigma_decay, self.cfg.sigma_floor)
        return stats

    def propose(
        self,
        seeds: Sequence[int] | np.ndarray,
        returns_pos: np.ndarray,
        returns_neg: np.ndarray,
        theta: np.ndarray | None = None,
        step: str = "adam",
    ) -> np.ndarray:
        """One step's theta without touching any state (transfer's and admission's "proposal").

        `theta` is the point the population was sampled around (default: this optimiser's theta).
        `step` "adam" is the step `tell` would take (this pair's Adam state and lr); "sgd" is
        the reference's default proposal, plain gradient descent at the initial lr with no
        state. Either way the population was sampled at this optimiser's sigma.
        """
        theta = self.theta if theta is None else theta
        if step == "adam":
            new_theta, *_ = self._step(theta, seeds, returns_pos, returns_neg)
            return new_theta
        if step != "sgd":
            raise ValueError(f"proposal step must be 'adam' or 'sgd', got {step!r}.")
        theta = check_theta(theta)
        g = es_gradient(seeds, returns_pos, returns_neg, self.sigma, theta.size)
        return theta - self.cfg.lr * (-g + self.cfg.l2_coeff * theta)

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue bit-for-bit: arrays, scalars and the Generator state."""
        return {
            "theta": self.theta.copy(),
            "m": self.m.copy(),
            "v": self.v.copy(),
            "t": self.t,
            "lr": self.lr,
            "sigma": self.sigma,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a `state_dict`; hyper-parameters come from the constructor, not the state."""
        missing = {"theta", "m", "v", "t", "lr", "sigma", "rng"} - set(state)
        if missing:
            raise ValueError(f"ES state is missing {sorted(missing)}.")
        theta = check_theta(state["theta"])
        for name in ("m", "v"):
            if np.shape(state[name]) != theta.shape:
                raise ValueError(
                    f"ES state {name!r} has shape {np.shape(state[name])}, theta {theta.shape}."
                )
        self.theta = theta.copy()
        self.m = np.array(state["m"], dtype=np.float64)
        self.v = np.array(state["v"], dtype=np.float64)
        self.t = int(state["t"])
        self.lr = float(state["lr"])
        self.sigma = float(state["sigma"])
        self.rng.bit_generator.state = state["rng"]
