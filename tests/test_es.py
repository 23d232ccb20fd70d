"""The ES policy (compiled MLP) and the OpenAI-ES optimiser."""

from dataclasses import replace

import numpy as np
import pytest

from conftest import ES_SIZES
from epoet.config import load
from epoet.es.optimizer import OpenAIES, adam_step, centered_ranks, es_gradient
from epoet.rollout.policy import (
    forward,
    forward_rows,
    init_params,
    num_params,
    sizes_array,
    unflatten,
)
from epoet.rollout.populations import mirrored_population, noise

SMALL = (5, 4, 3)  # a 2-layer net keeps policy tests tiny
ES = load(["budget=paper"]).algo.es  # the paper's ES settings


# ---------------------------------------------------------------- policy


def test_num_params_of_paper_policy_and_custom_sizes():
    assert num_params(ES_SIZES) == 4538
    assert num_params(ES_SIZES) == 53 * 40 + 40 + 40 * 40 + 40 + 40 * 18 + 18
    assert num_params(SMALL) == 5 * 4 + 4 + 4 * 3 + 3


def test_init_is_seeded_gaussian_with_std_0_1():
    a, b = init_params(3, ES_SIZES), init_params(3, ES_SIZES)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, init_params(4, ES_SIZES))
    assert a.shape == (4538,) and a.dtype == np.float64
    assert abs(a.std() - 0.1) < 0.005 and abs(a.mean()) < 0.01


def test_unflatten_layout_is_w_then_b_per_layer():
    params = np.arange(num_params(SMALL), dtype=np.float64)
    (w1, b1), (w2, b2) = unflatten(params, SMALL)
    np.testing.assert_array_equal(w1, np.arange(20).reshape(5, 4))
    np.testing.assert_array_equal(b1, [20, 21, 22, 23])
    np.testing.assert_array_equal(w2, np.arange(24, 36).reshape(4, 3))
    np.testing.assert_array_equal(b2, [36, 37, 38])
    w1[0, 0] = -1.0  # views: crossover can write through them
    assert params[0] == -1.0


def test_forward_matches_hand_computation():
    # 2 -> 1 net: W = [[1], [2]], b = [0.5]; obs (1, -1) -> tanh(1 - 2 + 0.5).
    params = np.array([1.0, 2.0, 0.5])
    np.testing.assert_allclose(forward(params, np.array([1.0, -1.0]), (2, 1)), [np.tanh(-0.5)])


@pytest.mark.parametrize("std", [0.3, 30.0])  # 30: saturated units, tanh of |x| in the hundreds
def test_forward_equals_the_numpy_mlp(std: float):
    rng = np.random.default_rng(5)
    params = rng.normal(0, std, num_params(ES_SIZES))
    obs = rng.standard_normal((8, 53))
    h = obs
    for w, b in unflatten(params, ES_SIZES):
        h = np.tanh(h @ w + b)
    got = forward(params, obs, ES_SIZES)
    np.testing.assert_allclose(got, h, rtol=0, atol=1e-14)
    assert np.all(np.abs(got) <= 1.0)


def test_forward_single_and_batch_of_observations_agree():
    params = init_params(0, ES_SIZES)
    obs = np.random.default_rng(1).standard_normal((4, 53))
    batch = forward(params, obs, ES_SIZES)
    assert batch.shape == (4, 18)
    for i in range(4):
        np.testing.assert_allclose(forward(params, obs[i], ES_SIZES), batch[i], rtol=0, atol=1e-12)
    assert np.all(np.abs(batch) < 1.0)  # tanh on the output layer


def test_forward_rows_equals_forward_row_by_row():
    rng = np.random.default_rng(2)
    params = rng.normal(0, 0.3, size=(6, num_params(ES_SIZES)))
    obs = rng.standard_normal((6, 53))
    actions = np.empty((6, 18))
    forward_rows(params, sizes_array(ES_SIZES), obs, actions)
    for i in range(6):  # one implementation: the engine's actions are forward's, bit for bit
        np.testing.assert_array_equal(actions[i], forward(params[i], obs[i], ES_SIZES))


def test_forward_rows_rows_do_not_depend_on_each_other():
    rng = np.random.default_rng(3)
    params = rng.standard_normal((3, num_params(SMALL)))
    obs = rng.standard_normal((3, 5)).astype(np.float32)  # float32 observations are accepted
    before, after = np.empty((3, 3)), np.empty((3, 3))
    forward_rows(params, sizes_array(SMALL), obs, before)
    params[1] += 1.0
    forward_rows(params, sizes_array(SMALL), obs, after)
    np.testing.assert_array_equal(after[[0, 2]], before[[0, 2]])
    assert not np.allclose(after[1], before[1])
    np.testing.assert_allclose(
        after[1], forward(params[1], obs[1].astype(np.float64), SMALL), rtol=0, atol=1e-15
    )


@pytest.mark.parametrize(
    "call",
    [
        lambda: forward(np.zeros(10), np.zeros(53), ES_SIZES),
        lambda: forward(init_params(0, ES_SIZES), np.zeros(52), ES_SIZES),
        lambda: forward(np.zeros((2, num_params(SMALL))), np.zeros(5), SMALL),
        lambda: sizes_array((53,)),
        lambda: num_params((53,)),
    ],
)
def test_policy_bad_input_raises_value_error(call):
    with pytest.raises(ValueError):
        call()


# ---------------------------------------------------------------- ES pieces


def test_noise_is_a_function_of_the_seed():
    np.testing.assert_array_equal(noise(7, 5), np.random.default_rng(7).standard_normal(5))
    np.testing.assert_array_equal(noise(7, 5), noise(np.int64(7), 5))
    assert not np.array_equal(noise(7, 5), noise(8, 5))


def test_mirrored_population_is_theta_plus_then_minus_sigma_eps():
    theta = np.array([1.0, -2.0, 0.5])
    pop = mirrored_population(theta, [4, 9], 0.1)
    assert pop.shape == (4, 3)
    for i, seed in enumerate([4, 9]):
        np.testing.assert_allclose(pop[i], theta + 0.1 * noise(seed, 3))
        np.testing.assert_allclose(pop[2 + i], theta - 0.1 * noise(seed, 3))


def test_centered_ranks_values_ties_and_single_value():
    np.testing.assert_allclose(centered_ranks(np.array([3.0, 1.0, 2.0])), [0.5, -0.5, 0.0])
    # ties ranked by position (argsort order), as OpenAI-ES
    np.testing.assert_allclose(centered_ranks(np.array([1.0, 1.0, 1.0])), [-0.5, 0.0, 0.5])
    np.testing.assert_array_equal(centered_ranks(np.array([42.0])), [0.0])
    m = centered_ranks(np.array([[4.0, 1.0], [3.0, 2.0]]))
    np.testing.assert_allclose(m, [[0.5, -0.5], [1 / 6, -1 / 6]])


def test_gradient_equals_hand_computation():
    seeds, sigma = [11, 22], 0.05
    pos, neg = np.array([10.0, 0.0]), np.array([5.0, 20.0])
    # all four returns [10, 0, 5, 20] have ranks [2, 0, 1, 3] -> /3 - 0.5 = [1/6, -1/2, -1/6, 1/2]
    # weights r+ - r- = [1/6 + 1/6, -1/2 - 1/2] = [1/3, -1]
    e1, e2 = noise(11, 3), noise(22, 3)
    expected = (e1 / 3.0 - e2) / (2 * sigma)
    np.testing.assert_allclose(es_gradient(seeds, pos, neg, sigma, 3), expected, rtol=1e-12)


def test_tell_applies_adam_on_minus_g_plus_l2_theta_then_decays():
    theta = np.array([0.3, -0.2, 0.1])
    es = OpenAIES(theta, 0, ES, n_pairs=2)
    seeds, pos, neg = [11, 22], np.array([10.0, 0.0]), np.array([5.0, 20.0])
    g = es_gradient(seeds, pos, neg, 0.02, 3)
    grad = -g + 0.01 * theta
    # first Adam step by hand: m = 0.1 G, v = 0.001 G^2, a = lr sqrt(1 - 0.999) / (1 - 0.9)
    a = 0.01 * np.sqrt(0.001) / 0.1
    expected = theta - a * (0.1 * grad) / (np.sqrt(0.001 * grad**2) + 1e-8)
    stats = es.tell(seeds, pos, neg)
    np.testing.assert_allclose(es.theta, expected, rtol=1e-12)
    assert stats["lr"] == 0.01 and stats["sigma"] == 0.02
    assert es.lr == pytest.approx(0.01 * 0.9999) and es.sigma == pytest.approx(0.02 * 0.999)
    assert es.t == 1


def test_schedules_stop_at_their_floors():
    cfg = replace(
        ES, lr=0.01, lr_decay=0.5, lr_floor=0.004, sigma=0.02, sigma_decay=0.5, sigma_floor=0.008
    )
    es = OpenAIES(np.zeros(3), 0, cfg, n_pairs=1)
    for _ in range(3):
        es.tell(es.sample_seeds(), [1.0], [0.0])
    assert es.lr == 0.004 and es.sigma == 0.008


def _quadratic(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    return -np.sum((points - target) ** 2, axis=-1)


def test_es_climbs_a_quadratic():
    target = np.random.default_rng(5).normal(0, 0.5, size=10)
    es = OpenAIES(np.zeros(10), 1, ES, n_pairs=16)
    start = np.linalg.norm(es.theta - target)
    for _ in range(300):
        seeds = es.sample_seeds()
        returns = _quadratic(mirrored_population(es.theta, seeds, es.sigma), target)
        es.tell(seeds, returns[:16], returns[16:])
    assert np.linalg.norm(es.theta - target) < 0.05 * start


def _equal_states(a: dict, b: dict) -> bool:
    return (
        all(np.array_equal(a[k], b[k]) if isinstance(a[k], np.ndarray) else a[k] == b[k] for k in a)
        and a.keys() == b.keys()
    )


def _advance(es: OpenAIES, steps: int) -> None:
    target = np.linspace(-1, 1, es.num_params)
    for _ in range(steps):
        seeds = es.sample_seeds()
        returns = _quadratic(mirrored_population(es.theta, seeds, es.sigma), target)
        es.tell(seeds, returns[: es.n_pairs], returns[es.n_pairs :])


def test_propose_changes_nothing_and_equals_tell():
    es = OpenAIES(np.full(4, 0.2), 2, ES, n_pairs=3)
    _advance(es, 2)
    seeds, pos, neg = [1, 2, 3], np.array([1.0, 4.0, 2.0]), np.array([3.0, 0.0, 5.0])
    before = es.state_dict()
    proposal = es.propose(seeds, pos, neg)
    assert _equal_states(before, es.state_dict())
    es.tell(seeds, pos, neg)
    np.testing.assert_array_equal(proposal, es.theta)


def test_propose_from_a_candidate_theta_uses_this_pairs_adam_state():
    es = OpenAIES(np.full(4, 0.2), 2, ES, n_pairs=3)
    _advance(es, 2)
    candidate = np.array([1.0, -1.0, 0.5, 0.0])
    seeds, pos, neg = [1, 2, 3], np.array([1.0, 4.0, 2.0]), np.array([3.0, 0.0, 5.0])
    g = es_gradient(seeds, pos, neg, es.sigma, 4)
    expected, *_ = adam_step(
        candidate, -g + 0.01 * candidate, es.m, es.v, es.t, es.lr, 0.9, 0.999, 1e-8
    )
    np.testing.assert_array_equal(es.propose(seeds, pos, neg, theta=candidate), expected)


def test_an_sgd_proposal_ignores_the_adam_state_and_the_decayed_lr():
    """The reference's default proposal (SimpleSGD at the initial lr): a pair that has taken
    steps proposes what a fresh optimiser at the same sigma would, along the ES gradient."""
    seeds, pos, neg = [1, 2, 3], np.array([1.0, 4.0, 2.0]), np.array([3.0, 0.0, 5.0])
    candidate = np.array([1.0, -1.0, 0.5, 0.0])
    used, fresh = OpenAIES(np.full(4, 0.2), 2, ES, n_pairs=3), OpenAIES(np.zeros(4), 9, ES, 3)
    _advance(used, 3)
    fresh.sigma = used.sigma
    assert used.lr < ES.lr and used.t == 3
    proposal = used.propose(seeds, pos, neg, theta=candidate, step="sgd")
    np.testing.assert_array_equal(
        proposal, fresh.propose(seeds, pos, neg, theta=candidate, step="sgd")
    )
    assert not np.array_equal(proposal, used.propose(seeds, pos, neg, theta=candidate))
    # Without the L2 term the step is the initial lr times the gradient itself (Adam's first
    # step would instead move every coordinate by about lr).
    no_l2 = OpenAIES(np.zeros(4), 2, replace(ES, l2_coeff=0.0), n_pairs=3)
    g = es_gradient(seeds, pos, neg, no_l2.sigma, 4)
    np.testing.assert_allclose(
        no_l2.propose(seeds, pos, neg, theta=candidate, step="sgd") - candidate,
        ES.lr * g,
        rtol=1e-12,
    )


def test_reset_restores_initial_lr_sigma_and_adam_state():
    es = OpenAIES(np.zeros(4), 3, ES, n_pairs=2)
    _advance(es, 3)
    new_theta = np.ones(4)
    es.reset(new_theta)
    new_theta[0] = 9.0  # the optimiser keeps its own copy
    np.testing.assert_array_equal(es.theta, np.ones(4))
    assert es.lr == 0.01 and es.sigma == 0.02 and es.t == 0
    assert not es.m.any() and not es.v.any()


def test_state_dict_round_trip_gives_identical_subsequent_steps():
    a = OpenAIES(np.zeros(5), 4, ES, n_pairs=2)
    _advance(a, 3)
    state = a.state_dict()
    b = OpenAIES(np.ones(5), 99, ES, n_pairs=2)
    b.load_state_dict(state)
    _advance(a, 3)
    assert not np.array_equal(state["theta"], a.theta)  # the saved state is a copy
    _advance(b, 3)
    assert _equal_states(a.state_dict(), b.state_dict())


def test_seed_stream_is_a_function_of_the_seed():
    a, b = OpenAIES(np.zeros(2), 5, ES, n_pairs=4), OpenAIES(np.zeros(2), 5, ES, n_pairs=4)
    s = a.sample_seeds()
    assert s.dtype == np.int64 and s.shape == (4,)
    np.testing.assert_array_equal(s, b.sample_seeds())
    assert not np.array_equal(a.sample_seeds(), s)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: OpenAIES(np.zeros((3, 2)), 0, ES, n_pairs=1), "theta"),
        (
            lambda: OpenAIES(np.zeros(3), 0, ES, n_pairs=2).tell([1, 2], [0.0, 1.0], [0.0]),
            "one value per seed",
        ),
        (lambda: OpenAIES(np.zeros(3), 0, ES, n_pairs=1).tell([1], [np.nan], [0.0]), "finite"),
        (
            lambda: OpenAIES(np.zeros(3), 0, ES, n_pairs=1).propose(
                [1], [0.0], [1.0], theta=np.zeros(4)
            ),
            "parameters",
        ),
        (
            lambda: OpenAIES(np.zeros(3), 0, ES, n_pairs=1).load_state_dict({"theta": np.zeros(3)}),
            "missing",
        ),
    ],
)
def test_optimizer_bad_input_raises_clear_value_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()
