"""SAC on the hexapod (paper Table 3), read top to bottom: the learner, then `train`.

TorchRL's SACLoss with a ReLU tanh-Gaussian actor and twin ReLU Q networks, a uniform replay
buffer, soft target updates and automatic entropy tuning (target entropy -(action dimensions)
unless set). Rewards are multiplied by the reward scale when they enter the replay buffer (the
logged returns are the env's). Each collector batch is followed by `updates_per_batch` gradient
updates; the first batch comes from uniform random actions (Table 3: one pre-training epoch).
Settings: conf/algo/sac.yaml. `SacLearner.gradient_steps` is what bench/sac_updates.py times.

Speed (DESIGN.md: the update rate should match a plain-PyTorch SAC), each measured with the
bench on this 2-core machine:
- one fused Adam steps the actor, both critics and the temperature together. This equals three
  separate Adams with the same learning rate: SACLoss keeps the three losses' gradients apart
  (the actor loss sees detached critics and temperature, the critic target is computed without
  gradient, the temperature loss sees a detached log-prob) and Adam is per parameter;
- replay samples are drawn 50 batches per call and split (~8%);
- the actor's tanh is plain (`safe_tanh=False`): SAC scores its own samples from their pre-tanh
  values, so TorchRL's clamped tanh (for inverting stored actions) is not needed;
- `deactivate_vmap=True`: SACLoss evaluates the two critics in a loop instead of vmapping one
  stacked ensemble; on this CPU the loop was as fast with 2 threads and ~3% faster with 1.
What remains is SACLoss's own per-call overhead (TensorDict plumbing, functional parameter
swaps, distribution objects), ~3.5 ms per update against ~14 ms of compute at one thread.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.objectives import SACLoss, SoftUpdate, ValueEstimators

from epoet.config import Config, SacConfig
from epoet.rl.run_state import TrainingRun, TrainResult
from epoet.rl.setup import BatchPlan, make_actor, make_qvalue

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker

METRICS = ("loss_actor", "loss_qvalue", "loss_alpha", "alpha", "entropy")
SAMPLE_CHUNK = 50  # batches drawn from the replay buffer per call


class SacLearner:
    """SAC's networks, loss, optimiser, target updater and replay buffer."""

    def __init__(self, algo: SacConfig, env: EnvBase, plan: BatchPlan) -> None:
        self.actor = make_actor(env, algo.hidden, algo.activation, state_independent_scale=False,
                                safe_tanh=False)
        qvalue = make_qvalue(env, algo.hidden, algo.activation)
        self.loss = SACLoss(
            self.actor, qvalue, num_qvalue_nets=2, loss_function="l2",
            alpha_init=algo.alpha_init, action_spec=env.action_spec, deactivate_vmap=True,
            target_entropy="auto" if algo.target_entropy is None else algo.target_entropy)
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=algo.gamma)
        self.target_update = SoftUpdate(self.loss, tau=algo.tau)
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=algo.lr, fused=True)
        # never more room than the run has frames: LazyTensorStorage allocates it all at once
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(min(algo.buffer_size, plan.total_frames)))
        self.keys = self.loss.in_keys
        self.reward_scale = algo.reward_scale
        self.batch_size = algo.batch_size
        self.updates_per_batch = plan.scaled(algo.updates_per_batch, minimum=1)

    def learn(self, batch: TensorDictBase) -> dict[str, float]:
        """Store the batch, then `updates_per_batch` updates once the buffer holds a batch."""
        data = batch.reshape(-1).select(*self.keys)  # what the loss reads, nothing more
        data["next", "reward"] = data["next", "reward"] * self.reward_scale
        self.buffer.extend(data)
        if len(self.buffer) < self.batch_size:
            return {}
        return self.gradient_steps(self.updates_per_batch)

    def gradient_steps(self, n: int) -> dict[str, float]:
        """`n` updates on uniform samples from the buffer; returns the mean of `METRICS`.

        Samples are drawn SAMPLE_CHUNK batches at a time and split: the same i.i.d. uniform
        draws as one `sample()` per update, with the buffer's per-call overhead paid once per
        chunk (worth ~8% of the update rate, see bench/sac_updates.py).
        """
        total = torch.zeros(len(METRICS))
        done = 0
        while done < n:
            chunk = min(SAMPLE_CHUNK, n - done)
            for sample in self.buffer.sample(chunk * self.batch_size).split(self.batch_size):
                out = self.update(sample)
                with torch.no_grad():
                    total += torch.stack([out[k] for k in METRICS])
            done += chunk
        return dict(zip(METRICS, (total / n).tolist()))

    def update(self, sample: TensorDictBase) -> TensorDictBase:
        """One gradient step of actor, critics and temperature, then the soft target update."""
        out = self.loss(sample)
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        self.target_update.step()
        return out

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict(),
                "buffer": self.buffer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.buffer.load_state_dict(state["buffer"])


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
          ) -> TrainResult:
    """The `algo=sac` runner (see epoet.run.RUNNERS)."""
    algo: SacConfig = cfg.algo
    with TrainingRun(cfg, tracker, run_dir, resume) as run:
        learner = SacLearner(algo, run.env, run.plan)

        collector = run.start(learner.actor, learner, algo.init_random_frames)
        for batch in run.batches(collector):
            learned = learner.learn(batch)
            run.log(batch, learned)
            run.evaluate_if_due(learner.actor)
            run.checkpoint_if_due(learner)
        return run.finish(learner.actor, learner)
