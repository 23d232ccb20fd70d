"""The exported policy of a baseline run: plain data (architecture, normaliser, weights) that
epoet.rollout.torch_policy.load_policy turns back into `act(obs) -> action` with nothing but
torch, for evaluation and rendering without TorchRL, the training state or this package.

TorchRL and epoet.rl.env and nets (which import MuJoCo) are imported where used, so reading
POLICY_FORMAT to check a file (epoet.eval.agents) imports neither.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import torch
from torch import nn

from epoet.core.files import atomic_write
from epoet.rollout.agent_files import INTEGRATOR, LAYOUT, POLICY_FORMAT

if TYPE_CHECKING:
    from torchrl.envs import EnvBase
    from torchrl.modules import MLP, ProbabilisticActor

POLICY_FILE = "policy.pt"
CRITICS_FILE = "critics.pt"
CRITICS_FORMAT = "epoet-twin-q/1"  # TwinQ's state dict (epoet.sac.loss), plus its layout


def _actor_mlp(actor: ProbabilisticActor) -> MLP:
    from torchrl.modules import MLP

    return next(m for m in actor.modules() if isinstance(m, MLP))


def export_policy(
    path: Path, actor: ProbabilisticActor, env: EnvBase, hidden: list[int], activation: str
) -> Path:
    """Write the deterministic policy as plain data: architecture, normaliser and weights.

    `load_policy` (epoet.rollout.torch_policy) rebuilds it with nothing but torch: a reader
    needs neither TorchRL nor the training state. An actor that standardises inside its network (ePOET-SAC's ObsStandardize)
    is written as a raw-observation policy, the standardisation folded into the first layer
    (W / std, b - W mean / std), as ePOET's ES agents are.
    """
    from epoet.envs.spaces import layout_of
    from epoet.rl.env import OBS, OBS_CLIP, obs_norm_of, terrain_env
    from epoet.rl.nets import ObsStandardize

    norm = obs_norm_of(env)
    net = _actor_mlp(actor)
    weights = {k: v.detach().clone() for k, v in net.state_dict().items()}
    inner = next((m for m in actor.modules() if isinstance(m, ObsStandardize)), None)
    if inner is not None:
        w, mean, std = weights["0.weight"], inner.mean.detach(), inner.std.detach()
        weights["0.bias"] = weights["0.bias"] - w @ (mean / std)
        weights["0.weight"] = w / std
    spec = {
        "format": POLICY_FORMAT,
        "obs_dim": env.observation_spec[OBS].shape[-1],
        "act_dim": env.action_spec.shape[-1],
        "hidden": list(hidden),
        "activation": activation,
        "obs_loc": None if norm is None else norm.loc.detach().clone(),
        "obs_scale": None if norm is None else norm.scale.detach().clone(),
        "obs_clip": None if norm is None else OBS_CLIP,
        "state_dict": weights,
        LAYOUT: layout_of(terrain_env(env).agent_cfg),
        INTEGRATOR: terrain_env(env).agent_cfg.integrator,
    }
    with atomic_write(path) as file:  # a killed run never leaves half a policy
        torch.save(spec, file)
    return path


def export_critics(path: Path, critics: nn.Module, hidden: list[int], activation: str) -> Path:
    """Write SAC's twin Q networks (a TwinQ on raw observations and actions) as plain data, the
    format of the authors' converted critics (epoet/reference/agents/sac/42.critics.pt), so a
    warm start (`algo.sac_init`) can load a run's critics without its checkpoint."""
    spec = {
        "format": CRITICS_FORMAT,
        "activation": activation,
        "hidden": list(hidden),
        "state_dict": {k: v.detach().clone() for k, v in critics.state_dict().items()},
    }
    with atomic_write(path) as file:
        torch.save(spec, file)
    return path


def read_critics(path: Path) -> dict:
    """A critics file's plain data ({format, activation, hidden, state_dict}); ValueError in
    one sentence for a file that is not one."""
    try:
        spec = torch.load(path, weights_only=True, map_location="cpu")
    except Exception:  # torch raises many types
        raise ValueError(f"{path} is not a readable torch file.") from None
    if (
        not isinstance(spec, dict)
        or spec.get("format") != CRITICS_FORMAT
        or not all(k in spec for k in ("activation", "hidden", "state_dict"))
    ):
        raise ValueError(f"{path} is not an epoet critics file ({CRITICS_FORMAT}).")
    return spec
