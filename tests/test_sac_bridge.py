"""Crossing between the ES pool and the SAC actor: crossover, random mapping, distillation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import ES_SIZES
from epoet.config import load
from epoet.epoet_sac.bridge import crossover, distill_into_actor, distill_into_es, random_mapping
from epoet.rl.env import make_env
from epoet.rl.nets import make_actor
from epoet.rollout.policy import forward, init_params, unflatten


def sac_actor(hidden: tuple[int, ...] = (64, 64)):
    env = make_env(load(["algo=sac", "budget=smoke", "terrain.grid=40"]), obs_norm=False, seed=0)
    torch.manual_seed(0)
    return make_actor(env, list(hidden), "relu", state_independent_scale=False, safe_tanh=False)


def states(n: int = 512) -> np.ndarray:
    return np.random.default_rng(1).standard_normal((n, ES_SIZES[0]))


def test_crossover_takes_each_position_from_one_parent_by_a_fair_coin():
    a, b = np.zeros(4000), np.ones(4000)
    child = crossover(a, b, np.random.default_rng(0))
    assert set(np.unique(child)) == {0.0, 1.0}
    assert 0.45 < child.mean() < 0.55
    np.testing.assert_array_equal(child, crossover(a, b, np.random.default_rng(0)))


def test_random_mapping_draws_each_layer_from_the_matching_sac_layer():
    net = sac_actor().module[0].module
    theta = random_mapping(net, ES_SIZES, np.random.default_rng(2))
    linears = [m for m in net.modules() if isinstance(m, torch.nn.Linear)]
    for i, ((w, b), linear) in enumerate(zip(unflatten(theta, ES_SIZES), linears)):
        weight, bias = (
            linear.weight.detach().double().numpy(),
            linear.bias.detach().double().numpy(),
        )
        if i == len(linears) - 1:
            weight, bias = weight[: ES_SIZES[-1]], bias[: ES_SIZES[-1]]
        assert np.isin(w, weight).all() and np.isin(b, bias).all()


def test_distillation_imitates_the_sac_actor_far_better_than_the_random_mapping():
    net = sac_actor().module[0].module
    obs = states()
    with torch.no_grad():
        want = torch.tanh(net(torch.as_tensor(obs, dtype=torch.float32))[0]).double().numpy()
    mapped = random_mapping(net, ES_SIZES, np.random.default_rng(3))
    distilled, error = distill_into_es(
        net, obs, ES_SIZES, init_params(4, ES_SIZES), epochs=30, batch=64, lr=3e-3, seed=5
    )
    random_error = np.mean((forward(mapped, obs, ES_SIZES) - want) ** 2)
    distilled_error = np.mean((forward(distilled, obs, ES_SIZES) - want) ** 2)
    assert distilled_error == pytest.approx(error, rel=1e-6)
    assert distilled_error < 0.25 * random_error


def test_distilling_an_es_agent_into_the_actor_moves_its_mean_towards_the_agent():
    actor = sac_actor()
    net = actor.module[0].module
    theta, obs = init_params(6, ES_SIZES), states()
    want = forward(theta, obs, ES_SIZES)

    def error() -> float:
        with torch.no_grad():
            got = torch.tanh(net(torch.as_tensor(obs, dtype=torch.float32))[0]).numpy()
        return float(np.mean((got - want) ** 2))

    before = error()
    final = distill_into_actor(net, theta, obs, ES_SIZES, epochs=30, batch=64, lr=1e-3, seed=7)
    assert final == pytest.approx(error(), rel=1e-5)
    assert error() < 0.25 * before
