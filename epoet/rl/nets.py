"""The baselines' networks: the tanh-Gaussian actor, the state-value critic, and the optimiser
step that refuses non-finite losses and gradients.

Actions: a tanh-squashed Gaussian (TorchRL's TanhNormal) for all three algorithms, so actions
are always inside the actuators' [-1, 1] range; the deterministic action is tanh(loc). The
networks read the normalised observation when the env normalises (`policy_key`); ePOET-SAC's
actor instead standardises inside its network (`ObsStandardize`, the ES pool's statistics).

SAC's scale: TorchRL's NormalParamExtractor maps the scale half of the output layer with
`biased_softplus_1.0`, softplus(x + inv_softplus(0.99)) + 0.01 (1 at x = 0), then a floor of 1e-4.
The authors' SAC (their torchrl fork, GuassianContPolicy) read the same half as a log-std:
exp(clamp(x, -20, 2)). `LOG_STD_SCALE` registers that mapping with tensordict, so an actor
warm-started from their weights (epoet.epoet_sac.warm_start) keeps their scales exactly: no
weights of a linear layer turn one mapping into the other (softplus(z + b) + 0.01 = exp(x) needs
z = log(expm1(exp(x) - 0.01)) - b, not linear in x).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch
from tensordict.nn import (
    AddStateIndependentNormalScale,
    NormalParamExtractor,
    TensorDictModule,
    add_custom_mapping,
)
from torch import nn
from torchrl.envs import EnvBase, ExplorationType
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from epoet.rl.env import OBS, policy_key
from epoet.rollout.torch_policy import ACTIVATIONS

# TorchRL's default scale mapping, and the authors' (module docstring): a log-std clamped to
# [-20, 2] as their LOG_SIG_MIN / LOG_SIG_MAX, exponentiated.
SOFTPLUS_SCALE = "biased_softplus_1.0"
LOG_STD_SCALE = "log_std_exp"
LOG_STD_BOUNDS = (-20.0, 2.0)
add_custom_mapping(LOG_STD_SCALE, lambda x: x.clamp(*LOG_STD_BOUNDS).exp())
SCALE_FLOORS = {SOFTPLUS_SCALE: 1e-4, LOG_STD_SCALE: 0.0}  # NormalParamExtractor's scale_lb


class ObsStandardize(nn.Module):
    """(obs - mean) / std with the statistics as buffers (checkpointed with the network). No
    clip, as the ES pool's (epoet.es.obs_norm), so it folds into the next linear layer."""

    mean: torch.Tensor  # buffers, registered below
    std: torch.Tensor

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs - self.mean) / self.std


def mlp(in_features: int, out_features: int, hidden: list[int], activation: str) -> MLP:
    """[Linear, act] * len(hidden) + Linear: the layout `load_policy` rebuilds."""
    return MLP(
        in_features=in_features,
        out_features=out_features,
        num_cells=list(hidden),
        activation_class=ACTIVATIONS[activation],
    )


def make_actor(
    env: EnvBase,
    hidden: list[int],
    activation: str,
    *,
    state_independent_scale: bool,
    safe_tanh: bool = True,
    scale_mapping: str = SOFTPLUS_SCALE,
    standardize: ObsStandardize | None = None,
) -> ProbabilisticActor:
    """A tanh-Gaussian policy on [-1, 1]^act_dim (the hexapod's action space).

    PPO and VMPO learn one log-std per action dimension (`state_independent_scale`, paper
    Table 2); SAC's network outputs the scale too. `safe_tanh` (TorchRL's clamped tanh) is needed
    where the log-probability of stored actions is recomputed by inverting tanh (PPO, VMPO); SAC
    scores its own reparameterised samples from their pre-tanh values and uses plain tanh.
    `scale_mapping` (SAC's scale head) is SOFTPLUS_SCALE or LOG_STD_SCALE (module docstring);
    `standardize` goes in front of the MLP, so the actor reads raw observations.
    """
    spec = env.action_spec
    if not (bool((spec.space.low == -1).all()) and bool((spec.space.high == 1).all())):
        raise ValueError(f"the RL baselines expect actions in [-1, 1], got {spec.space}.")
    obs_dim = env.observation_spec[OBS].shape[-1]
    act_dim = spec.shape[-1]
    if state_independent_scale:
        net = nn.Sequential(
            mlp(obs_dim, act_dim, hidden, activation), AddStateIndependentNormalScale(act_dim)
        )
    else:
        net = nn.Sequential(
            mlp(obs_dim, 2 * act_dim, hidden, activation),
            NormalParamExtractor(scale_mapping, SCALE_FLOORS[scale_mapping]),
        )
    if standardize is not None:
        net = nn.Sequential(standardize, *net)
    # bounds as Python numbers: TanhNormal then skips per-call tensor checks on them
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=[policy_key(env)], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0, "safe_tanh": safe_tanh},
        return_log_prob=True,
        default_interaction_type=ExplorationType.RANDOM,
    )


def make_value(env: EnvBase, hidden: list[int], activation: str) -> ValueOperator:
    """V(s) for PPO and VMPO."""
    return ValueOperator(
        mlp(env.observation_spec[OBS].shape[-1], 1, hidden, activation), in_keys=[policy_key(env)]
    )


def step_if_finite(
    optimizer: torch.optim.Optimizer,
    total: torch.Tensor,
    clip: Sequence[Iterable[nn.Parameter]] = (),
    max_grad_norm: float | None = None,
) -> bool:
    """Backpropagate `total` and step, unless the loss or a clipped gradient norm is not finite:
    then nothing changes (weights and optimiser state) and False is returned, so one bad batch
    cannot poison the networks. The caller counts the skips (`skipped_updates`)."""
    optimizer.zero_grad(set_to_none=True)
    if not torch.isfinite(total):
        return False
    total.backward()
    if max_grad_norm is not None:
        for params in clip:  # each group clipped on its own norm (actor and critic, say)
            if not torch.isfinite(nn.utils.clip_grad_norm_(params, max_grad_norm)):
                optimizer.zero_grad(set_to_none=True)
                return False
    optimizer.step()
    return True
