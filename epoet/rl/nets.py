"""The baselines' networks: the tanh-Gaussian actor, the state-value critic, and the optimiser
step that refuses non-finite losses and gradients.

Actions: a tanh-squashed Gaussian (TorchRL's TanhNormal) for all three algorithms, so actions
are always inside the actuators' [-1, 1] range; the deterministic action is tanh(loc). The
networks read the normalised observation when the env normalises (`policy_key`).
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.envs import EnvBase, ExplorationType
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from epoet.rl.config import RL_ACTIVATIONS
from epoet.rl.env import OBS, policy_key

# The schema's choices (epoet.rl.config.RL_ACTIVATIONS) as torch modules: nn.Tanh for "tanh",
# nn.ReLU for "relu", ...
ACTIVATIONS: dict[str, type[nn.Module]] = {
    name: next(getattr(nn, attr) for attr in dir(nn) if attr.lower() == name)
    for name in RL_ACTIVATIONS}


def mlp(in_features: int, out_features: int, hidden: list[int], activation: str) -> MLP:
    """[Linear, act] * len(hidden) + Linear: the layout `load_policy` rebuilds."""
    return MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden),
               activation_class=ACTIVATIONS[activation])


def make_actor(env: EnvBase, hidden: list[int], activation: str, *,
               state_independent_scale: bool, safe_tanh: bool = True) -> ProbabilisticActor:
    """A tanh-Gaussian policy on [-1, 1]^act_dim (the hexapod's action space).

    PPO and VMPO learn one log-std per action dimension (`state_independent_scale`, paper
    Table 2); SAC's network outputs the scale too. `safe_tanh` (TorchRL's clamped tanh) is needed
    where the log-probability of stored actions is recomputed by inverting tanh (PPO, VMPO); SAC
    scores its own reparameterised samples from their pre-tanh values and uses plain tanh.
    """
    spec = env.action_spec
    if not (bool((spec.space.low == -1).all()) and bool((spec.space.high == 1).all())):
        raise ValueError(f"the RL baselines expect actions in [-1, 1], got {spec.space}.")
    obs_dim = env.observation_spec[OBS].shape[-1]
    act_dim = spec.shape[-1]
    if state_independent_scale:
        net = nn.Sequential(mlp(obs_dim, act_dim, hidden, activation),
                            AddStateIndependentNormalScale(act_dim))
    else:
        net = nn.Sequential(mlp(obs_dim, 2 * act_dim, hidden, activation), NormalParamExtractor())
    # bounds as Python numbers: TanhNormal then skips per-call tensor checks on them
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=[policy_key(env)], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], spec=spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0, "safe_tanh": safe_tanh},
        return_log_prob=True, default_interaction_type=ExplorationType.RANDOM)


def make_value(env: EnvBase, hidden: list[int], activation: str) -> ValueOperator:
    """V(s) for PPO and VMPO."""
    return ValueOperator(mlp(env.observation_spec[OBS].shape[-1], 1, hidden, activation),
                         in_keys=[policy_key(env)])


def step_if_finite(optimizer: torch.optim.Optimizer, total: torch.Tensor,
                   clip: Sequence[Iterable[nn.Parameter]] = (),
                   max_grad_norm: float | None = None) -> bool:
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
