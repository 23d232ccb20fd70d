"""Our SAC loss against TorchRL's SACLoss: the same actor, the same two critics, the same noise."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives import SACLoss, ValueEstimators

from epoet.config import load
from epoet.rl.env import make_env
from epoet.rl.nets import make_actor
from epoet.sac.loss import SacLoss, TwinQ

HIDDEN = [32, 32]


def test_sac_loss_equals_torchrls_sacloss_on_the_same_networks_and_noise() -> None:
    env = make_env(load(["algo=sac", "budget=smoke", "terrain.grid=40"]), obs_norm=False, seed=0)
    obs_dim, act_dim = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    torch.manual_seed(0)
    actor = make_actor(env, HIDDEN, "relu", state_independent_scale=False, safe_tanh=False)
    critics = TwinQ(obs_dim + act_dim, HIDDEN, nn.ReLU)
    ours = SacLoss(
        actor, critics, obs_key="observation", gamma=0.9, alpha_init=0.5, target_entropy=-7.0
    )
    qvalue = ValueOperator(
        MLP(
            in_features=obs_dim + act_dim,
            out_features=1,
            num_cells=HIDDEN,
            activation_class=nn.ReLU,
        ),
        in_keys=["observation", "action"],
    )
    theirs = SACLoss(
        actor,
        qvalue,
        num_qvalue_nets=2,
        loss_function="l2",
        alpha_init=0.5,
        action_spec=env.action_spec,
        target_entropy=-7.0,
        deactivate_vmap=True,
    )
    theirs.make_value_estimator(ValueEstimators.TD0, gamma=0.9)
    # TorchRL keeps each critic parameter stacked over the two networks, nn.Linear's (out, in)
    with torch.no_grad():
        for params in (theirs.qvalue_network_params, theirs.target_qvalue_network_params):
            flat = params.flatten_keys(".")
            weights = sorted(
                (k for k in flat.keys() if k.endswith("weight")),
                key=lambda k: int(k.split(".")[-2]),
            )
            for key, w, b in zip(weights, critics.weights, critics.biases):
                flat[key].copy_(w.transpose(1, 2))
                flat[key.replace("weight", "bias")].copy_(b.squeeze(1))
    # a target network that lags the online one, so the target path is tested too
    with torch.no_grad():
        for p in ours.target_critics.parameters():
            p.mul_(0.9)
        for p in theirs.target_qvalue_network_params.values(True, True):
            p.mul_(0.9)

    gen = torch.Generator().manual_seed(1)
    n = 64
    batch = TensorDict(
        {
            "observation": torch.randn(n, obs_dim, generator=gen),
            "action": torch.rand(n, act_dim, generator=gen) * 1.8 - 0.9,
            "next": {
                "observation": torch.randn(n, obs_dim, generator=gen),
                "reward": torch.randn(n, 1, generator=gen),
                "terminated": torch.rand(n, 1, generator=gen) < 0.2,
                "done": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )
    batch["next", "done"] = batch["next", "terminated"].clone()

    torch.manual_seed(7)
    got = ours(batch.clone())
    torch.manual_seed(7)
    want = theirs(batch.clone())
    for key in ("loss_qvalue", "loss_actor", "loss_alpha", "alpha", "entropy"):
        torch.testing.assert_close(
            got[key].detach(), want[key].detach().reshape(()), rtol=1e-5, atol=1e-6, msg=key
        )


def test_detached_critics_take_no_gradient_so_the_actor_loss_moves_only_the_actor() -> None:
    critics = TwinQ(5, [8], nn.ReLU)
    obs, action = torch.randn(4, 3), torch.rand(4, 2, requires_grad=True)
    critics(obs, action, detach=True).sum().backward()
    assert all(p.grad is None for p in critics.parameters())
    assert action.grad is not None and action.grad.abs().sum() > 0  # the path to the actor
    critics(obs, action).sum().backward()
    assert all(p.grad is not None for p in critics.parameters())
