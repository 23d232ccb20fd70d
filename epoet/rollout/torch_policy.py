"""An exported torch policy (`policy.pt`, written by epoet.rl.policy_file) rebuilt as
`act(obs) -> action` with nothing but torch: evaluation, rendering and analysis run a baseline's
agent without TorchRL, the training state or the algorithm's package, as they run an ES agent.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import nn

from epoet.rollout.agent_files import read_torch_policy
from epoet.rollout.config import RL_ACTIVATIONS

# The activations' names as torch modules: nn.Tanh for "tanh", nn.ReLU for "relu", ...
ACTIVATIONS: dict[str, type[nn.Module]] = {
    name: next(getattr(nn, attr) for attr in dir(nn) if attr.lower() == name)
    for name in RL_ACTIVATIONS
}


def load_policy(path: str | Path) -> Callable[[np.ndarray], np.ndarray]:
    """Rebuild an exported policy as `act(obs) -> action` (numpy in, numpy out, batched or not).

    action = tanh(first act_dim outputs of the MLP applied to clip((obs - loc) / scale)).
    A file that is not such a policy for the task raises epoet.eval.agents.AgentError.
    """
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
