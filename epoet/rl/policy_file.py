"""The exported policy of a baseline run: plain data (architecture, normaliser, weights) that
`load_policy` turns back into `act(obs) -> action` with nothing but torch, for evaluation and
rendering without TorchRL or the training state.

TorchRL and epoet.rl.env and nets (which import MuJoCo) are imported where used, so reading
POLICY_FORMAT to check a file (epoet.eval.agents) imports neither.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch
from torch import nn

from epoet.rollout.agent_files import POLICY_FORMAT, read_torch_policy
from epoet.core.files import atomic_write

if TYPE_CHECKING:
    from torchrl.envs import EnvBase
    from torchrl.modules import MLP, ProbabilisticActor

POLICY_FILE = "policy.pt"


def _actor_mlp(actor: ProbabilisticActor) -> MLP:
    from torchrl.modules import MLP
    return next(m for m in actor.modules() if isinstance(m, MLP))


def export_policy(path: Path, actor: ProbabilisticActor, env: EnvBase, hidden: list[int],
                  activation: str) -> Path:
    """Write the deterministic policy as plain data: architecture, normaliser and weights.

    `load_policy` rebuilds it with nothing but torch: a reader needs neither TorchRL nor the
    training state.
    """
    from epoet.rl.env import OBS, OBS_CLIP, obs_norm_of
    norm = obs_norm_of(env)
    net = _actor_mlp(actor)
    spec = {
        "format": POLICY_FORMAT,
        "obs_dim": env.observation_spec[OBS].shape[-1],
        "act_dim": env.action_spec.shape[-1],
        "hidden": list(hidden),
        "activation": activation,
        "obs_loc": None if norm is None else norm.loc.detach().clone(),
        "obs_scale": None if norm is None else norm.scale.detach().clone(),
        "obs_clip": None if norm is None else OBS_CLIP,
        "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
    }
    with atomic_write(path) as file:  # a killed run never leaves half a policy
        torch.save(spec, file)
    return path


def load_policy(path: str | Path) -> Callable[[np.ndarray], np.ndarray]:
    """Rebuild an exported policy as `act(obs) -> action` (numpy in, numpy out, batched or not).

    action = tanh(first act_dim outputs of the MLP applied to clip((obs - loc) / scale)).
    A file that is not such a policy for the task raises epoet.eval.agents.AgentError.
    """
    from epoet.rl.nets import ACTIVATIONS
    spec = read_torch_policy(Path(path))
    sizes = [spec["obs_dim"], *spec["hidden"]]
    layers: list[nn.Module] = []
    for n_in, n_out in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(n_in, n_out), ACTIVATIONS[spec["activation"]]()]
    out_features = spec["state_dict"][f"{2 * len(spec['hidden'])}.weight"].shape[0]
    net = nn.Sequential(*layers, nn.Linear(sizes[-1], out_features))
    net.load_state_dict(spec["state_dict"])
    net.eval()
    act_dim, clip = spec["act_dim"], spec["obs_clip"]
    loc, scale = spec["obs_loc"], spec["obs_scale"]

    @torch.no_grad()
    def act(obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        if loc is not None:
            x = ((x - loc) / scale).clamp(-clip, clip)
        return torch.tanh(net(x)[..., :act_dim]).numpy()

    return act
