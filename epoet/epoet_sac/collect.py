"""Train_SAC's frames, stepped on the gym env directly; and the pool's recorded ES transitions
as the same replay rows (`es_transitions`).

The same transitions TorchRL's `env.rollout(frames, policy=actor, break_when_any_done=False)`
gives on ePOET-SAC's SAC env (DoubleToFloat, RewardSum, StepCounter; a new episode after each
done one), with the keys the learner stores and `episode_metrics` reads, and none of the
per-step TensorDict work: 0.32 against 1.5 ms per frame on the workstation's learner
(bench/epoet_sac_cost.py, `collect`). Actions: uniform on [-1, 1] (`policy` None, the first
frames of a cold start), else a draw of the actor's tanh-Gaussian, tanh(loc + scale * eps), as
TorchRL's TanhNormal samples it on [-1, 1]; both from torch's generator, which the loop seeds.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict
from torch import nn

from epoet.envs.terrain_env import TerrainEnv
from epoet.rl.env import OBS
from epoet.rollout.engine import Episodes


@torch.no_grad()
def collect(
    env: TerrainEnv, policy: nn.Module | None, frames: int, spawn_seed: int, act_dim: int
) -> TensorDict:
    """`frames` transitions from a reset with `spawn_seed` on the env's terrain; `policy` maps
    a raw observation to (loc, scale)."""
    obs_dim = env.task.obs_dim
    obs = np.empty((frames + 1, obs_dim), dtype=np.float32)
    next_obs = np.empty((frames, obs_dim), dtype=np.float32)
    reward = np.empty(frames, dtype=np.float32)
    flags = np.zeros((4, frames), dtype=bool)  # terminated, truncated, done, finished
    episode_reward = np.empty(frames, dtype=np.float32)
    step_count = np.empty(frames, dtype=np.int64)
    actions = (
        torch.rand(frames, act_dim) * 2.0 - 1.0 if policy is None else torch.empty(frames, act_dim)
    )
    obs[0] = env.reset(seed=spawn_seed)[0]
    total, steps = 0.0, 0
    for i in range(frames):
        if policy is not None:
            loc, scale = policy(torch.from_numpy(obs[i]))
            actions[i] = torch.tanh(loc + scale * torch.empty_like(loc).normal_())
        o, r, terminated, truncated, info = env.step(actions[i].numpy())
        total, steps = total + r, steps + 1
        next_obs[i], reward[i] = o, r
        flags[:, i] = terminated, truncated, terminated or truncated, info["finished"]
        episode_reward[i], step_count[i] = total, steps
        if terminated or truncated:
            o, total, steps = env.reset()[0], 0.0, 0
        obs[i + 1] = o
    terminated, truncated, done, finished = (torch.from_numpy(f)[:, None] for f in flags)
    return TensorDict(
        {
            OBS: torch.from_numpy(obs[:-1]),
            "action": actions,
            "next": {
                OBS: torch.from_numpy(next_obs),
                "reward": torch.from_numpy(reward)[:, None],
                "terminated": terminated,
                "truncated": truncated,
                "done": done,
                "finished": finished,
                "episode_reward": torch.from_numpy(episode_reward)[:, None],
                "step_count": torch.from_numpy(step_count)[:, None],
            },
        },
        batch_size=[frames],
    )


def es_transitions(episodes: list[Episodes]) -> TensorDict | None:
    """The transitions the workers recorded (float32) as the replay's rows; None if none were."""
    recorded = [e.transitions for e in episodes if e.transitions is not None]
    if not recorded:
        return None
    t = {k: np.concatenate([r[k] for r in recorded]) for k in recorded[0]}
    return TensorDict(
        {
            OBS: torch.from_numpy(t["obs"]),
            "action": torch.from_numpy(t["action"]),
            "next": {
                OBS: torch.from_numpy(t["next_obs"]),
                "reward": torch.from_numpy(t["reward"])[:, None],
                "terminated": torch.from_numpy(t["terminated"])[:, None],
            },
        },
        batch_size=[len(t["reward"])],
    )
