"""Tests of the V-MPO loss (epoet.vmpo.loss) against the equations of Song et al. (2019)."""

import math

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import distributions as d
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import (
    MLP,
    IndependentNormal,
    ProbabilisticActor,
    TanhNormal,
    ValueOperator,
)
from torchrl.objectives.value import GAE

from epoet.vmpo.loss import VMPOLoss
from epoet.vmpo.loss_parts import top_half_weights

torch.set_num_threads(1)

OBS_DIM, ACTION_DIM = 3, 2


@pytest.fixture(autouse=True)
def _seed() -> None:
    torch.manual_seed(0)


def make_actor(
    distribution_class: type = TanhNormal, cells: tuple[int, ...] = (64, 64), **kwargs
) -> ProbabilisticActor:
    """The baseline's policy: a tanh MLP for the mean and a state-independent log-std."""
    net = nn.Sequential(
        MLP(
            in_features=OBS_DIM,
            out_features=ACTION_DIM,
            num_cells=list(cells),
            activation_class=nn.Tanh,
        ),
        AddStateIndependentNormalScale(ACTION_DIM),
    )
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=distribution_class,
        distribution_kwargs=kwargs,
        return_log_prob=True,
    )


def make_critic() -> ValueOperator:
    return ValueOperator(
        MLP(in_features=OBS_DIM, out_features=1, num_cells=[64, 64], activation_class=nn.Tanh),
        in_keys=["observation"],
    )


def collect(actor: ProbabilisticActor, n: int = 16) -> TensorDict:
    """A batch as a collector writes it: the actor's outputs and one transition per row."""
    data = TensorDict({"observation": torch.randn(n, OBS_DIM)}, [n])
    # collectors sample actions; a ProbabilisticActor alone returns its deterministic one
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        actor(data)
    data["next"] = TensorDict(
        {
            "observation": torch.randn(n, OBS_DIM),
            "reward": torch.randn(n, 1),
            "done": torch.zeros(n, 1, dtype=torch.bool),
            "terminated": torch.zeros(n, 1, dtype=torch.bool),
        },
        [n],
    )
    return data


def with_advantage(data: TensorDict, advantage: torch.Tensor) -> TensorDict:
    data["advantage"] = advantage.reshape(-1, 1)
    data["value_target"] = torch.zeros_like(data["advantage"])
    return data


def widen_policy(actor: ProbabilisticActor, shift: float) -> None:
    """Moves the current policy away from the one that collected the data."""
    with torch.no_grad():
        for name, param in actor.named_parameters():
            if name.endswith("state_independent_scale"):
                param.add_(shift)


def np_softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max())
    return e / e.sum()


# --- E-step -------------------------------------------------------------------------------


def test_top_half_weights_are_a_softmax_over_the_better_half():
    advantage = torch.tensor([3.0, -1.0, 0.5, 2.0, -4.0, 1.0]).unsqueeze(-1)
    eta = 0.7
    weights, mask = top_half_weights(advantage, eta)

    a = advantage.squeeze(-1).numpy().astype(np.float64)
    top = np.argsort(-a)[:3]  # the better half: 3.0, 2.0, 1.0
    expected = np.zeros_like(a)
    expected[top] = np_softmax(a[top] / eta)

    assert weights.shape == mask.shape == advantage.shape
    assert mask.squeeze(-1).tolist() == [True, False, False, True, False, True]
    np.testing.assert_allclose(weights.squeeze(-1).numpy(), expected, rtol=1e-6, atol=1e-7)
    assert weights[~mask].abs().max() == 0.0
    assert math.isclose(float(weights.sum()), 1.0, rel_tol=1e-6)


def test_top_half_weights_fraction_odd_sizes_and_valid_mask():
    advantage = torch.tensor([5.0, 4.0, 3.0, 2.0, 1.0])
    # odd batch: floor(0.5 * 5) = 2 samples kept
    assert top_half_weights(advantage, 1.0)[1].tolist() == [True, True, False, False, False]
    # fraction 1 keeps everything: a plain softmax
    weights, mask = top_half_weights(advantage, 2.0, fraction=1.0)
    assert bool(mask.all())
    np.testing.assert_allclose(weights.numpy(), np_softmax(advantage.numpy() / 2.0), rtol=1e-6)
    # an invalid (padded) sample is never kept, and N counts only the valid ones
    valid = torch.tensor([False, True, True, True, True])
    weights, mask = top_half_weights(advantage, 1.0, valid=valid)
    assert mask.tolist() == [False, True, True, False, False]
    np.testing.assert_allclose(weights[1:3].numpy(), np_softmax(np.array([4.0, 3.0])), rtol=1e-6)


def test_top_half_weights_carry_no_gradient():
    eta = torch.tensor(1.0, requires_grad=True)
    advantage = torch.randn(8, requires_grad=True)
    weights, _ = top_half_weights(advantage, eta)
    assert not weights.requires_grad


@pytest.mark.parametrize(
    "kwargs",
    [
        {"fraction": 0.0},
        {"fraction": 1.5},
        {"eta": 0.0},
        {"eta": -1.0},
        {"valid": torch.zeros(4, dtype=torch.bool)},
    ],
)
def test_top_half_weights_bad_arguments(kwargs):
    arguments = {"advantage": torch.randn(4), "eta": 1.0, **kwargs}
    with pytest.raises(ValueError):
        top_half_weights(**arguments)


# --- the temperature eta -----------------------------------------------------------------


@pytest.mark.parametrize("eps_eta, grows", [(0.02, True), (10.0, False)])
def test_eta_loss_moves_eta_towards_its_constraint(eps_eta, grows):
    """dL_eta/deta = eps_eta - KL(psi || uniform on the kept half).

    The spread advantages give a peaked psi, KL(psi || U) ~ 1.1 nats: above eps_eta = 0.02,
    eta must grow to flatten psi; below eps_eta = 10 (the bound cannot bind), eta shrinks.
    """
    actor = make_actor(cells=(8,))
    loss = VMPOLoss(actor, make_critic(), eps_eta=eps_eta)
    advantage = torch.linspace(-5.0, 5.0, 16)
    data = with_advantage(collect(actor), advantage)

    loss(data)["loss_eta"].backward()
    eta = float(loss.eta)
    top = np.sort(advantage.numpy().astype(np.float64))[-8:]
    psi = np_softmax(top / eta)
    kl_to_uniform = float(np.sum(psi * np.log(psi * len(top))))
    # d loss / d log_eta = eta * d loss / d eta
    assert math.isclose(float(loss.log_eta.grad), eta * (eps_eta - kl_to_uniform), rel_tol=1e-4)

    torch.optim.SGD([loss.log_eta], lr=0.1).step()
    assert (float(loss.eta) > eta) is grows
    assert float(loss.eta) != eta


def test_eta_shrinks_when_all_advantages_are_equal():
    # psi is uniform, KL(psi || U) = 0 < eps_eta: the constraint is slack
    actor = make_actor(cells=(8,))
    loss = VMPOLoss(actor, make_critic())
    data = with_advantage(collect(actor), torch.ones(16))
    loss(data)["loss_eta"].backward()
    torch.optim.SGD([loss.log_eta], lr=0.1).step()
    assert float(loss.eta) < 1.0


# --- the KL multiplier alpha -------------------------------------------------------------


@pytest.mark.parametrize("shift, grows", [(1.0, True), (0.0, False)])
def test_alpha_grows_iff_kl_exceeds_eps_alpha(shift, grows):
    actor = make_actor(cells=(8,))
    loss = VMPOLoss(actor, make_critic())
    data = with_advantage(collect(actor), torch.randn(16))
    widen_policy(actor, shift)

    out = loss(data)
    kl = float(out["kl"])
    assert (kl > loss.eps_alpha) is grows
    out["loss_alpha"].backward()
    alpha = float(loss.alpha)
    assert math.isclose(
        float(loss.log_alpha.grad), alpha * (loss.eps_alpha - kl), rel_tol=1e-4, abs_tol=1e-9
    )
    torch.optim.SGD([loss.log_alpha], lr=0.1).step()
    assert (float(loss.alpha) > alpha) is grows


def test_kl_of_tanh_normal_is_the_gaussian_kl_of_its_pre_tanh_distributions():
    actor = make_actor(cells=(8,))
    loss = VMPOLoss(actor, make_critic())
    data = with_advantage(collect(actor), torch.randn(16))
    widen_policy(actor, 0.3)
    current = actor(data.copy())

    mu0, s0, mu1, s1 = data["loc"], data["scale"], current["loc"], current["scale"]
    per_dim = torch.log(s1 / s0) + (s0**2 + (mu0 - mu1) ** 2) / (2 * s1**2) - 0.5
    expected = per_dim.sum(-1).mean()
    assert torch.allclose(loss(data)["kl"], expected, rtol=1e-5)


def test_kl_without_closed_form_is_estimated_from_the_batch_log_probs():
    # StudentT has no registered KL: the estimate is mean(log pi_old(a) - log pi(a))
    actor = make_actor(d.StudentT, cells=(8,), df=5.0)
    loss = VMPOLoss(actor, make_critic())
    data = with_advantage(collect(actor), torch.randn(16))
    widen_policy(actor, 0.5)
    with torch.no_grad():
        log_prob = actor.get_dist(data.copy()).log_prob(data["action"]).sum(-1)
    expected = (data["action_log_prob"].sum(-1) - log_prob).mean()
    assert torch.allclose(loss(data)["kl"], expected, rtol=1e-5)


# --- the whole loss ----------------------------------------------------------------------


@pytest.mark.parametrize("distribution_class", [TanhNormal, IndependentNormal, d.Normal])
def test_full_loss_on_a_collected_batch(distribution_class):
    actor, critic = make_actor(distribution_class), make_critic()
    loss = VMPOLoss(actor, critic)
    data = GAE(gamma=0.99, lmbda=0.95, value_network=critic)(collect(actor))
    stored_loc = data["loc"]

    out = loss(data)
    assert set(out.keys()) == set(loss.out_keys)
    assert data["loc"] is stored_loc  # the caller's batch is left as it was
    # the policy has not moved since it collected the batch
    assert abs(float(out["kl"])) < 1e-6
    for key in ("eta", "alpha", "kl", "entropy"):
        assert not out[key].requires_grad
    assert math.isclose(float(out["eta"]), 1.0, rel_tol=1e-6)
    assert math.isclose(float(out["alpha"]), 0.1, rel_tol=1e-6)

    # L_pi = -sum psi log pi and L_V = 1/2 mean (V - G)^2, by hand
    with torch.no_grad():
        weights, _ = top_half_weights(data["advantage"], 1.0)
        log_prob = actor.get_dist(data.copy()).log_prob(data["action"])
        if log_prob.ndim == 2:  # torch's Normal scores each action dimension
            log_prob = log_prob.sum(-1)
        value = critic(data.copy())["state_value"]
    assert torch.allclose(out["loss_policy"], -(weights.squeeze(-1) * log_prob).sum(), rtol=1e-5)
    expected_critic = 0.5 * ((value - data["value_target"]) ** 2).mean()
    assert torch.allclose(out["loss_critic"], expected_critic, rtol=1e-5)

    sum(value for key, value in out.items() if key.startswith("loss_")).backward()
    for network in (actor, critic):
        for name, param in network.named_parameters():
            assert param.grad is not None and param.grad.abs().sum() > 0, name
    assert loss.log_eta.grad is not None and loss.log_eta.grad != 0
    assert loss.log_alpha.grad is not None and loss.log_alpha.grad != 0


def test_advantage_is_computed_by_the_value_estimator_when_missing():
    actor, critic = make_actor(cells=(8,)), make_critic()
    loss = VMPOLoss(actor, critic)  # default estimator: GAE, gamma 0.99, lambda 0.95
    data = collect(actor)
    precomputed = GAE(gamma=0.99, lmbda=0.95, value_network=critic)(data.clone())
    out, expected = loss(data), loss(precomputed)
    for key in ("loss_policy", "loss_critic", "loss_eta", "loss_alpha"):
        assert torch.allclose(out[key], expected[key]), key


def test_masked_samples_take_no_part_in_the_loss():
    actor = make_actor(cells=(8,))
    loss = VMPOLoss(actor, make_critic())
    data = with_advantage(collect(actor, n=9), torch.randn(9))
    # a padded row whose advantage and target would dominate every term if it counted
    data["advantage"][0] = 1e6
    data["value_target"][0] = 1e6
    data["shifted_valid"] = torch.tensor([False] + [True] * 8)

    masked = loss(data)
    reference = loss(data[1:].exclude("shifted_valid"))
    for key in ("loss_policy", "loss_critic", "loss_eta", "loss_alpha", "kl"):
        assert torch.allclose(masked[key], reference[key]), key


# --- arguments ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [
        {"top_fraction": 0.0},
        {"top_fraction": 1.01},
        {"top_fraction": float("nan")},
        {"eta_init": 0.0},
        {"eta_init": -1.0},
        {"eps_eta": 0.0},
        {"eps_eta": float("inf")},
        {"alpha_init": 0.0},
        {"eps_alpha": -0.01},
        {"eps_alpha": float("nan")},
        {"critic_coeff": 0.0},
        {"loss_critic_type": "huber"},
    ],
)
def test_bad_arguments_raise_value_error(kwargs):
    with pytest.raises(ValueError):
        VMPOLoss(make_actor(cells=(8,)), make_critic(), **kwargs)


def test_a_deterministic_actor_is_rejected():
    actor = TensorDictModule(nn.Linear(OBS_DIM, ACTION_DIM), ["observation"], ["action"])
    with pytest.raises(TypeError):
        VMPOLoss(actor, make_critic())
