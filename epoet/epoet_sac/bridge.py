"""Mappings between an ES agent's vector and the SAC actor's network, and Algorithm 3's crossover:
functions of weights and states alone (exchange.py's steps call them on the pool).

ES agents are small tanh networks stored as one flat float64 vector (epoet/rollout/policy.py);
the SAC actor is a larger ReLU tanh-Gaussian network (`algo.sac.hidden`). Neither can be copied
into the other, so every crossing is a mapping:

- `random_mapping` (the paper's "random parameter selection"; the reference samples each ES
  layer's values with replacement from the corresponding SAC layer): cheap, and by the paper's
  own limitations paragraph it loses most of what the SAC actor knows;
- `distill_into_es` (our default for the join): behaviour cloning of the SAC actor's
  deterministic actions tanh(loc(s)) into the ES network on replay states;
- `distill_into_actor` (the transfer step, "SAC_Actor = theta_top"): behaviour cloning of an ES
  agent's actions into the SAC actor's mean, tanh(loc(s)), on replay states; the actor's scale
  head is left as it is, so SAC keeps its exploration.

With observation normalisation the pool's ES vectors act on standardised observations and the
actor standardises inside its network with the same statistics (epoet.rl.nets.ObsStandardize):
`random_mapping` draws from those weights, `distill_into_es` fits on standardised states, and
`distill_into_actor` is given the raw-observation agent (the service's `policy(theta)`), so a
joined agent and a crossover child read the observations their parents read.
`crossover` is Algorithm 3's crossover_single.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from epoet.rollout.policy import Standardizer, forward, num_params, unflatten


@dataclass
class ReplacedAgent:
    """An agent that a crossover child replaced (Algorithm 3: "archive theta^m")."""

    env: int
    iteration: int
    theta: np.ndarray
    score: float


class Mapped(NamedTuple):
    """The SAC actor mapped to an ES vector, with the mapped agent's and the actor's scores on
    one terrain from the same starts (their gap: what the mapping loses)."""

    theta: np.ndarray
    error: float  # the fit's mean squared action error; NaN for `random`
    score: float
    sac_score: float
    cost: dict[str, float]  # DAgger's episodes, env steps, states and seconds (else empty)


def crossover(theta: np.ndarray, donor: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Algorithm 3's crossover_single: every weight and bias position takes the donor's value on
    a fair coin flip, else keeps its own."""
    return np.where(rng.random(theta.shape) < 0.5, donor, theta)


def _actor_linears(policy_net: nn.Module) -> list[nn.Linear]:
    return [m for m in policy_net.modules() if isinstance(m, nn.Linear)]


def random_mapping(
    policy_net: nn.Module, layer_sizes: Sequence[int], rng: np.random.Generator
) -> np.ndarray:
    """An ES vector whose layer l takes values drawn with replacement from the SAC actor's layer
    l (weights from weights, biases from biases; the output layer from the mean half only)."""
    linears = _actor_linears(policy_net)
    if len(linears) != len(layer_sizes) - 1:
        raise ValueError(
            f"the SAC actor has {len(linears)} layers, the ES agent "
            f"{len(layer_sizes) - 1}: the random mapping pairs them one to one."
        )
    theta = np.zeros(num_params(layer_sizes))
    act_dim = layer_sizes[-1]
    for i, ((w, b), linear) in enumerate(zip(unflatten(theta, layer_sizes), linears)):
        weight = linear.weight.detach().double().numpy()
        bias = linear.bias.detach().double().numpy()
        if i == len(linears) - 1:  # loc and scale outputs: the mean is the first act_dim rows
            weight, bias = weight[:act_dim], bias[:act_dim]
        w[...] = rng.choice(weight.ravel(), size=w.shape)
        b[...] = rng.choice(bias, size=b.shape)
    return theta


def es_module(theta: np.ndarray, layer_sizes: Sequence[int]) -> nn.Sequential:
    """The ES network of `theta` as float64 torch layers (tanh after every layer, as
    epoet/rollout/policy.py), to be trained by gradient."""
    layers: list[nn.Module] = []
    for n_in, n_out in zip(layer_sizes[:-1], layer_sizes[1:]):
        layers += [nn.Linear(n_in, n_out, dtype=torch.float64), nn.Tanh()]
    module = nn.Sequential(*layers)
    with torch.no_grad():  # the flat layout holds (in, out) weights, nn.Linear (out, in)
        for (w, b), linear in zip(unflatten(theta.copy(), layer_sizes), _actor_linears(module)):
            linear.weight.copy_(torch.from_numpy(w.T.copy()))
            linear.bias.copy_(torch.from_numpy(b.copy()))
    return module


def es_theta(module: nn.Module, layer_sizes: Sequence[int]) -> np.ndarray:
    """The flat ES vector of a module made by `es_module`."""
    theta = np.zeros(num_params(layer_sizes))
    for (w, b), linear in zip(unflatten(theta, layer_sizes), _actor_linears(module)):
        w[...] = linear.weight.detach().numpy().T
        b[...] = linear.bias.detach().numpy()
    return theta


def fit(
    module: nn.Module,
    predict,
    states: torch.Tensor,
    targets: torch.Tensor,
    *,
    epochs: int,
    batch: int,
    lr: float,
    generator: torch.Generator,
) -> float:
    """Adam on the mean squared action error over shuffled minibatches; the final full-batch
    error."""
    optimizer = torch.optim.Adam([p for p in module.parameters() if p.requires_grad], lr=lr)
    for _ in range(epochs):
        order = torch.randperm(len(states), generator=generator)
        for idx in order.split(batch):
            loss = (predict(states[idx]) - targets[idx]).square().mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        return float((predict(states) - targets).square().mean())


def distill_into_es(
    policy_net: nn.Module,
    states: np.ndarray,
    layer_sizes: Sequence[int],
    init: np.ndarray,
    *,
    epochs: int,
    batch: int,
    lr: float,
    seed: int,
    standardizer: Standardizer | None = None,
) -> tuple[np.ndarray, float]:
    """An ES vector trained, from `init`, to output the SAC actor's deterministic actions on
    `states` (raw observations); returns it and the final mean squared action error. With the
    pool's `standardizer` the vector acts on standardised observations, as the pool's do."""
    obs = torch.as_tensor(states, dtype=torch.float32)
    with torch.no_grad():
        loc, _ = policy_net(obs)
        targets = torch.tanh(loc).double()
    es_obs = torch.as_tensor(
        states if standardizer is None else (states - standardizer.mean) / standardizer.std,
        dtype=torch.float64,
    )
    student = es_module(init, layer_sizes)
    error = fit(
        student,
        student,
        es_obs,
        targets,
        epochs=epochs,
        batch=batch,
        lr=lr,
        generator=torch.Generator().manual_seed(seed),
    )
    return es_theta(student, layer_sizes), error


def distill_into_actor(
    policy_net: nn.Module,
    theta: np.ndarray,
    states: np.ndarray,
    layer_sizes: Sequence[int],
    *,
    epochs: int,
    batch: int,
    lr: float,
    seed: int,
) -> float:
    """Train the SAC actor's mean, tanh(loc(s)), towards the ES agent's actions on `states`
    (in place); returns the final mean squared action error."""
    targets = torch.as_tensor(forward(theta, states, layer_sizes), dtype=torch.float32)
    obs = torch.as_tensor(states, dtype=torch.float32)
    return fit(
        policy_net,
        lambda s: torch.tanh(policy_net(s)[0]),
        obs,
        targets,
        epochs=epochs,
        batch=batch,
        lr=lr,
        generator=torch.Generator().manual_seed(seed),
    )
