"""V-MPO on the hexapod: the `VMPOLoss` of epoet/rl/vmpo.py inside the shared on-policy update.

Per batch of 2000 frames: GAE (gamma 0.99, lambda 0.95), then 10 epochs of minibatches of 128;
the E-step keeps the top 50% advantages of each minibatch with a learned temperature eta
(init 1, eps_eta 0.02), the M-step fits them under a KL trust region with a learned multiplier
alpha (init 0.1, eps_alpha 0.01). Actor and critic are [64, 64] tanh as PPO's, on running-
normalised observations; the actor's loc and scale are written into the batch at collection
time, which is how VMPOLoss rebuilds the old policy for the KL.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl.envs import EnvBase

from epoet.config import Config, VmpoConfig
from epoet.rl.common import (BatchPlan, OnPolicyAgent, TrainResult, make_actor, make_value,
                             train_loop)
from epoet.rl.vmpo import VMPOLoss

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def build_agent(cfg: Config, env: EnvBase, plan: BatchPlan) -> OnPolicyAgent:
    algo: VmpoConfig = cfg.algo
    actor = make_actor(env, algo.hidden, algo.activation, state_independent_scale=True)
    critic = make_value(env, algo.hidden, algo.activation)
    loss = VMPOLoss(
        actor, critic, top_fraction=algo.top_fraction, eta_init=algo.eta_init,
        eps_eta=algo.eps_eta, alpha_init=algo.alpha_init, eps_alpha=algo.eps_alpha,
        critic_coeff=algo.critic_coeff)
    return OnPolicyAgent(algo, plan, actor, critic, loss)


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
          ) -> TrainResult:
    """The `algo=vmpo` runner (see epoet.run.RUNNERS)."""
    return train_loop(cfg, tracker, run_dir, resume, build_agent)
