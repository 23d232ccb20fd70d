"""PPO on the hexapod (paper Table 2): TorchRL's ClipPPOLoss inside the shared on-policy update.

Per batch of 2000 frames: GAE (gamma 0.99, lambda 0.95), then 10 epochs of minibatches of 64 on
the clipped objective (clip 0.2) + entropy bonus (0.005) + value loss; a [64, 64] tanh actor with
a state-independent log-std and a [64, 64] tanh critic, both reading running-normalised
observations. The update and the loop live in epoet/rl/common.py (`OnPolicyAgent`,
`train_loop`); this file is the PPO-specific part.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl.envs import EnvBase
from torchrl.objectives import ClipPPOLoss

from epoet.config import Config, PpoConfig
from epoet.rl.common import (BatchPlan, OnPolicyAgent, TrainResult, make_actor, make_value,
                             train_loop)

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def build_agent(cfg: Config, env: EnvBase, plan: BatchPlan) -> OnPolicyAgent:
    algo: PpoConfig = cfg.algo
    actor = make_actor(env, algo.hidden, algo.activation, state_independent_scale=True)
    critic = make_value(env, algo.hidden, algo.activation)
    loss = ClipPPOLoss(
        actor, critic, clip_epsilon=algo.clip, entropy_coeff=algo.entropy_coeff,
        critic_coeff=algo.critic_coeff, loss_critic_type="l2",
        normalize_advantage=algo.normalize_advantage)
    return OnPolicyAgent(algo, plan, actor, critic, loss)


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
          ) -> TrainResult:
    """The `algo=ppo` runner (see epoet.run.RUNNERS)."""
    return train_loop(cfg, tracker, run_dir, resume, build_agent)
