"""The on-policy learner PPO (epoet/ppo/) and V-MPO (epoet/vmpo/) share: their networks and their update;
only their TorchRL loss module differs. A baseline run (baseline_run.py) calls `learn` on each
collector batch."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, SamplerWithoutReplacement, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import LossModule
from torchrl.objectives.value import GAE

from epoet.rl.config import OnPolicyConfig
from epoet.rl.harness import BatchPlan
from epoet.rl.nets import make_actor, make_value, step_if_finite


class OnPolicyLearner:
    """A tanh actor with a state-independent log-std and a tanh critic, both on the env's
    (normalised) observations, and a loss module on them (`make_loss(actor, critic)`); GAE on
    each collector batch, then epochs of shuffled minibatches on the loss.

    Per collector batch: GAE advantages and value targets once (with the critic before the
    update, as CleanRL), then `epochs` passes over the batch in shuffled minibatches drawn
    without replacement from a TensorDictReplayBuffer; each minibatch steps one Adam on the sum of
    the loss's `loss_*` terms. One Adam over actor and critic equals the paper's two optimisers
    with the same learning rate (Table 2 lists a policy and a value learning rate, equal): the
    networks share no parameters and Adam is per parameter. For the same reason gradients are
    clipped per network, so one network's gradient never scales the other's; the loss's own
    learned scalars (VMPO's eta and alpha) are not clipped.
    """

    random_frames = 0  # the actor acts from the first frame

    def __init__(
        self,
        cfg: OnPolicyConfig,
        env: EnvBase,
        plan: BatchPlan,
        make_loss: Callable[[ProbabilisticActor, ValueOperator], LossModule],
    ) -> None:
        actor = make_actor(env, cfg.hidden, cfg.activation, state_independent_scale=True)
        critic = make_value(env, cfg.hidden, cfg.activation)
        loss = make_loss(actor, critic)
        self.actor, self.critic, self.loss = actor, critic, loss
        self.gae = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=critic)
        self.optimizer = torch.optim.Adam(loss.parameters(), lr=cfg.lr)
        self.epochs = cfg.epochs
        self.max_grad_norm = cfg.max_grad_norm
        minibatch = min(cfg.minibatch, plan.frames_per_batch)
        # a pass of ceil(batch / minibatch) draws covers the batch once (the last draw is short)
        self.minibatches = math.ceil(plan.frames_per_batch / minibatch)
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(plan.frames_per_batch),
            sampler=SamplerWithoutReplacement(),
            batch_size=minibatch,
        )

    def learn(self, batch: TensorDictBase) -> dict[str, float]:
        """One batch: advantages, then the epochs of minibatch steps; the mean of each loss
        output over the steps."""
        with torch.no_grad():
            batch = self.gae(batch)
        self.buffer.empty()
        self.buffer.extend(batch.reshape(-1))
        sums: dict[str, torch.Tensor] = {}
        steps = skipped = 0
        for _ in range(self.epochs):
            for _ in range(self.minibatches):
                out = self.loss(self.buffer.sample())
                total = sum(v for k, v in out.items() if k.startswith("loss_"))
                if not step_if_finite(
                    self.optimizer,
                    total,
                    (self.actor.parameters(), self.critic.parameters()),
                    self.max_grad_norm,
                ):
                    skipped += 1
                    continue
                steps += 1
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + v.detach().float().mean()
        return {**{k: float(v) / steps for k, v in sums.items()}, "skipped_updates": skipped}

    def artifacts(self, run_dir: Path) -> list[Path]:
        """Nothing beside the policy."""
        return []

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])
