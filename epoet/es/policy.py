"""The ES policy: a tanh MLP stored as one flat float64 parameter vector.

ES perturbs, averages and ships whole parameter vectors, so the vector is the policy; the layers
are views into it. float64 is used throughout so that a run is bit-for-bit reproducible from its
seed and a checkpoint round-trips exactly (the matmuls are small; float32 would gain little).

Flat layout, for layer sizes (n_0, n_1, ..., n_L): for each layer l = 1..L in order, first the
weight matrix W_l of shape (n_{l-1}, n_l) in C order, then the bias b_l of shape (n_l,).
A layer computes h_l = tanh(h_{l-1} @ W_l + b_l); tanh is applied on every layer including the
output, so actions lie in (-1, 1) as the hexapod's actuators expect (REFERENCE.md section 5).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

LAYER_SIZES: tuple[int, ...] = (53, 40, 40, 18)
INIT_STD = 0.1


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


def num_params(layer_sizes: Sequence[int] = LAYER_SIZES) -> int:
    """Length of the flat parameter vector (4538 for 53 -> 40 -> 40 -> 18)."""
    sizes = _check_sizes(layer_sizes)
    return sum(n_in * n_out + n_out for n_in, n_out in zip(sizes[:-1], sizes[1:]))


def init_params(seed: int | np.random.Generator, layer_sizes: Sequence[int] = LAYER_SIZES,
                std: float = INIT_STD) -> np.ndarray:
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


def unflatten(params: np.ndarray, layer_sizes: Sequence[int] = LAYER_SIZES
              ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per-layer (W, b) views into `params` (P,); writing to them writes to `params`."""
    params = _check_flat(params, layer_sizes, ndim=1)
    return [(params[w0:b0].reshape(n_in, n_out), params[b0:b0 + n_out])
            for n_in, n_out, w0, b0 in _layer_slices(layer_sizes)]


def forward(params: np.ndarray, obs: np.ndarray, layer_sizes: Sequence[int] = LAYER_SIZES
            ) -> np.ndarray:
    """Actions of one parameter vector for one observation (n_0,) or a batch (N, n_0)."""
    obs = np.asarray(obs, dtype=np.float64)
    if obs.ndim not in (1, 2) or obs.shape[-1] != layer_sizes[0]:
        raise ValueError(f"obs must have shape ({layer_sizes[0]},) or (N, {layer_sizes[0]}), "
                         f"got {obs.shape}.")
    h = obs
    for w, b in unflatten(params, layer_sizes):
        h = np.tanh(h @ w + b)
    return h


class BatchedPolicy:
    """B different parameter vectors evaluated on B observations in one pass, allocation-free.

    The rollout engine steps B episodes in lockstep, each with its own perturbed parameters.
    This object owns a (B, P) parameter buffer; the per-layer weights are (B, in, out) views into
    it, so `set_params` is one copy and `__call__` runs one batched matmul per layer into
    preallocated workspace. The returned action array is that workspace: it is overwritten by
    the next call, so copy it if it must outlive the step.

    Biases are contiguous copies refreshed by `set_params`, not views: a ufunc reading a strided
    (row stride P) operand allocates a 64 KB iteration buffer on every call, which would put an
    allocation in each of the ~2000 steps of an episode batch.
    """

    def __init__(self, batch: int, layer_sizes: Sequence[int] = LAYER_SIZES) -> None:
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}.")
        self.layer_sizes = _check_sizes(layer_sizes)
        self.batch = int(batch)
        self.num_params = num_params(self.layer_sizes)
        self._params = np.zeros((self.batch, self.num_params))
        self._weights = []
        self._bias_views = []
        for n_in, n_out, w0, b0 in _layer_slices(self.layer_sizes):
            self._weights.append(self._params[:, w0:b0].reshape(self.batch, n_in, n_out))
            self._bias_views.append(self._params[:, b0:b0 + n_out])
        self._biases = [np.zeros(view.shape) for view in self._bias_views]
        # Activations are kept as (B, 1, n) so each layer is a stacked (1, in) @ (in, out) matmul.
        self._obs = np.zeros((self.batch, 1, self.layer_sizes[0]))
        self._hidden = [np.zeros((self.batch, 1, n)) for n in self.layer_sizes[1:]]
        self._hidden_2d = [h[:, 0, :] for h in self._hidden]

    def set_params(self, params: np.ndarray) -> None:
        """Copy (B, P) parameters in (row i drives episode i); the layer views stay valid."""
        _check_flat(params, self.layer_sizes, ndim=2)
        if params.shape[0] != self.batch:
            raise ValueError(f"params must have {self.batch} rows, got {params.shape[0]}.")
        np.copyto(self._params, params)
        for bias, view in zip(self._biases, self._bias_views):
            np.copyto(bias, view)

    def __call__(self, obs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Actions (B, n_L) for observations (B, n_0); written into `out` if given."""
        obs = np.asarray(obs)
        if obs.shape != (self.batch, self.layer_sizes[0]):
            raise ValueError(f"obs must have shape {(self.batch, self.layer_sizes[0])}, "
                             f"got {obs.shape}.")
        np.copyto(self._obs[:, 0, :], obs)  # also casts float32 observations without a temporary
        h = self._obs
        for w, b, z, z2d in zip(self._weights, self._biases, self._hidden, self._hidden_2d):
            np.matmul(h, w, out=z)
            np.add(z2d, b, out=z2d)
            np.tanh(z, out=z)
            h = z
        actions = self._hidden_2d[-1]
        if out is None:
            return actions
        np.copyto(out, actions)
        return out

