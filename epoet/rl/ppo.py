"""PPO on the hexapod (paper Table 2), read top to bottom: the on-policy update, then `train`.

Per collector batch: GAE advantages, then epochs of shuffled minibatches on TorchRL's
ClipPPOLoss (clipped objective + entropy bonus + value loss); a tanh actor with a
state-independent log-std and a tanh critic, both reading running-normalised observations.
Sizes and coefficients: conf/algo/ppo.yaml. V-MPO (vmpo.py) runs this same update with its own
loss.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, SamplerWithoutReplacement, TensorDictReplayBuffer
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss, LossModule
from torchrl.objectives.value import GAE

from epoet.config import Config, OnPolicyConfig, PpoConfig
from epoet.rl.run_state import TrainingRun, TrainResult
from epoet.rl.nets import make_actor, make_value, step_if_finite
from epoet.rl.setup import BatchPlan

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


class OnPolicyLearner:
    """The on-policy update of PPO and V-MPO; only the TorchRL loss module differs.

    Per collector batch: GAE advantages and value targets once (with the critic before the
    update, as CleanRL), then `epochs` passes over the batch in shuffled minibatches drawn
    without replacement from a TensorDictReplayBuffer; each minibatch steps one Adam on the sum of
    the loss's `loss_*` terms. One Adam over actor and critic equals the paper's two optimisers
    with the same learning rate (Table 2 lists a policy and a value learning rate, equal): the
    networks share no parameters and Adam is per parameter. For the same reason gradients are
    clipped per network, so one network's gradient never scales the other's; the loss's own
    learned scalars (VMPO's eta and alpha) are not clipped.
    """

    def __init__(self, cfg: OnPolicyConfig, plan: BatchPlan, actor: ProbabilisticActor,
                 critic: ValueOperator, loss: LossModule) -> None:
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
            sampler=SamplerWithoutReplacement(), batch_size=minibatch)

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
                if not step_if_finite(self.optimizer, total,
                                      (self.actor.parameters(), self.critic.parameters()),
                                      self.max_grad_norm):
                    skipped += 1
                    continue
                steps += 1
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + v.detach().float().mean()
        return {**{k: float(v) / steps for k, v in sums.items()}, "skipped_updates": skipped}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])


def clip_ppo_loss(algo: PpoConfig, actor: ProbabilisticActor, critic: ValueOperator
                  ) -> LossModule:
    """PPO's clipped objective + entropy bonus + value loss (paper Table 2)."""
    return ClipPPOLoss(actor, critic, clip_epsilon=algo.clip, entropy_coeff=algo.entropy_coeff,
                       critic_coeff=algo.critic_coeff, loss_critic_type="l2",
                       normalize_advantage=algo.normalize_advantage)


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None,
          make_loss: Callable[[Any, ProbabilisticActor, ValueOperator], LossModule]
          = clip_ppo_loss) -> TrainResult:
    """The `algo=ppo` runner (see epoet.run.RUNNERS); V-MPO runs it with its loss (vmpo.py)."""
    algo: OnPolicyConfig = cfg.algo
    with TrainingRun(cfg, tracker, run_dir, resume) as run:
        actor = make_actor(run.env, algo.hidden, algo.activation, state_independent_scale=True)
        critic = make_value(run.env, algo.hidden, algo.activation)
        learner = OnPolicyLearner(algo, run.plan, actor, critic, make_loss(algo, actor, critic))

        run.start(actor, learner)
        for batch in run.batches():
            learned = learner.learn(batch)
            run.log(batch, learned)
            run.evaluate_if_due(actor)
            run.checkpoint_if_due(learner)
        return run.finish(actor, learner)
