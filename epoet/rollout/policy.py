"""The ES policy: a tanh MLP stored as one flat float64 parameter vector.

ES perturbs, averages and ships whole parameter vectors, so the vector is the policy; the layers
are views into it. float64 is used throughout so that a run is bit-for-bit reproducible from its
seed and a checkpoint round-trips exactly (the matmuls are small; float32 would gain little).

Flat layout, for layer sizes (n_0, n_1, ..., n_L): for each layer l = 1..L in order, first the
weight matrix W_l of shape (n_{l-1}, n_l) in C order, then the bias b_l of shape (n_l,).
A layer computes h_l = tanh(h_{l-1} @ W_l + b_l); tanh is applied on every layer including the
output, so actions lie in [-1, 1], the range the task maps onto every actuator's ctrlrange.
One compiled function (`forward_rows`) computes it for the engine's batches and for `forward`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from epoet.envs.config import AgentConfig
from epoet.envs.spaces import robot_sizes

INIT_STD = 0.1


def policy_sizes(agent: AgentConfig, hidden: Sequence[int]) -> tuple[int, ...]:
    """The robot's policy sizes: its observations -> `hidden` (algo.es.hidden) -> its actions."""
    obs_dim, act_dim = robot_sizes(agent)
    return (obs_dim, *(int(h) for h in hidden), act_dim)


def _check_sizes(layer_sizes: Sequence[int]) -> tuple[int, ...]:
    sizes = tuple(int(n) for n in layer_sizes)
    if len(sizes) < 2 or min(sizes) < 1:
        raise ValueError(f"layer_sizes must list at least two positive sizes, got {layer_sizes}.")
    return sizes


def _layer_slices(layer_sizes: Sequence[int]) -> list[tuple[int, int, int, int]]:
    """(n_in, n_out, weight offset, bias offset) of each layer in the flat vector."""
    sizes = _check_sizes(layer_sizes)
    offsets = []
    start = 0
    for n_in, n_out in zip(sizes[:-1], sizes[1:]):
        bias_start = start + n_in * n_out
        offsets.append((n_in, n_out, start, bias_start))
        start = bias_start + n_out
    return offsets


def num_params(layer_sizes: Sequence[int]) -> int:
    """Length of the flat parameter vector (the hexapod's 53 -> 40 -> 40 -> 18: 4538)."""
    sizes = _check_sizes(layer_sizes)
    return sum(n_in * n_out + n_out for n_in, n_out in zip(sizes[:-1], sizes[1:]))


def init_params(
    seed: int | np.random.Generator, layer_sizes: Sequence[int], std: float = INIT_STD
) -> np.ndarray:
    """A fresh parameter vector, every entry (weights and biases) drawn from N(0, std^2)."""
    if std < 0:
        raise ValueError(f"std must be >= 0, got {std}.")
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, std, size=num_params(layer_sizes))


def _check_flat(params: np.ndarray, layer_sizes: Sequence[int], ndim: int) -> np.ndarray:
    params = np.asarray(params)
    expected = num_params(layer_sizes)
    if params.ndim != ndim or params.shape[-1] != expected:
        want = "(P,)" if ndim == 1 else "(B, P)"
        raise ValueError(f"params must have shape {want} with P = {expected}, got {params.shape}.")
    return params


def unflatten(
    params: np.ndarray, layer_sizes: Sequence[int]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per-layer (W, b) views into `params` (P,); writing to them writes to `params`."""
    params = _check_flat(params, layer_sizes, ndim=1)
    return [
        (params[w0:b0].reshape(n_in, n_out), params[b0 : b0 + n_out])
        for n_in, n_out, w0, b0 in _layer_slices(layer_sizes)
    ]


def sizes_array(layer_sizes: Sequence[int]) -> np.ndarray:
    """Layer sizes as `forward_rows` takes them."""
    return np.array(_check_sizes(layer_sizes), dtype=np.int64)


def forward(params: np.ndarray, obs: np.ndarray, layer_sizes: Sequence[int]) -> np.ndarray:
    """Actions of one parameter vector for one observation (n_0,) or a batch (N, n_0); the
    same computation as the rollout engine's, so an episode replayed step by step (the gym env,
    evaluation, rendering) takes the engine's actions bit for bit."""
    params = _check_flat(params, layer_sizes, ndim=1)
    obs = np.asarray(obs, dtype=np.float64)
    if obs.ndim not in (1, 2) or obs.shape[-1] != layer_sizes[0]:
        raise ValueError(
            f"obs must have shape ({layer_sizes[0]},) or (N, {layer_sizes[0]}), got {obs.shape}."
        )
    rows = np.atleast_2d(obs)
    out = np.empty((len(rows), layer_sizes[-1]))
    forward_rows(np.ascontiguousarray(params)[None], sizes_array(layer_sizes), rows, out)
    return out.reshape(*obs.shape[:-1], layer_sizes[-1])


@njit(cache=True)
def _tanh(v: float) -> float:
    """tanh(v) as 1 - 2 / (exp(2v) + 1): within 4e-16 of np.tanh, and half the time of libm's
    tanh, which cost as much as the matmuls (exp overflowing to inf still gives 1)."""
    return 1.0 - 2.0 / (np.exp(2.0 * v) + 1.0)


@njit(cache=True)
def forward_rows(
    params: np.ndarray, layer_sizes: np.ndarray, obs: np.ndarray, out: np.ndarray
) -> None:
    """out[b] = the actions of parameters params[b] (B, P) for obs[b] (B, n_0); params of
    shape (1, P) act on every row.

    The rollout engine's policy: B episodes stepped in lockstep, each with its own perturbed
    parameters, in one compiled call (numpy's stacked matmul made a BLAS call per row and layer,
    and the policy cost a tenth of the physics' time). Each row is computed on its own, so an
    episode's actions do not depend on the batch it runs in; `forward` is this same function.
    """
    width = layer_sizes.max()
    h, z = np.empty(width), np.empty(width)
    for b in range(obs.shape[0]):
        p = params[b if params.shape[0] > 1 else 0]
        n_in = layer_sizes[0]
        h[:n_in] = obs[b]
        start = 0
        for layer in range(1, layer_sizes.size):
            n_out = layer_sizes[layer]
            bias = start + n_in * n_out
            w = p[start:bias].reshape((n_in, n_out))
            z[:n_out] = 0.0
            # h @ w one row of w at a time: contiguous, so the inner loop vectorises (indexing
            # a 2-D view with loop counters also spares numba's negative-index checks)
            for i in range(n_in):
                hi = h[i]
                for j in range(n_out):
                    z[j] += hi * w[i, j]
            for j in range(n_out):
                h[j] = _tanh(z[j] + p[bias + j])
            start, n_in = bias + n_out, n_out
        out[b, :] = h[:n_in]


# --- a policy on standardised observations, folded into its first layer (epoet.es.obs_norm) ---
def fold(
    theta: np.ndarray, mean: np.ndarray, std: np.ndarray, layer_sizes: Sequence[int]
) -> np.ndarray:
    """The raw-observation parameters of `theta` (P,) or (K, P), a policy on standardised
    observations: fold(theta)(obs) = theta((obs - mean) / std)."""
    thetas = np.array(theta, dtype=np.float64, ndmin=2)
    for row in thetas:
        (w, b), *_ = unflatten(row, layer_sizes)
        b -= (mean / std) @ w  # before w changes: uses the standardised-space weights
        w /= std[:, None]
    return thetas.reshape(np.shape(theta))


@dataclass(frozen=True)
class Standardizer:
    """The statistics of one iteration, as the workers apply them to ES parameters."""

    mean: np.ndarray
    std: np.ndarray
    layer_sizes: tuple[int, ...]

    def fold(self, theta: np.ndarray) -> np.ndarray:
        return fold(theta, self.mean, self.std, self.layer_sizes)
