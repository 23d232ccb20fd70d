"""SAC on the hexapod (paper Table 3): the learner `algo=sac` (train.py) and ePOET-SAC train.

A ReLU tanh-Gaussian actor (TorchRL's ProbabilisticActor, which the collector runs) and twin
ReLU Q networks, the SAC losses of loss.py, a uniform TorchRL replay buffer, soft target
updates and automatic entropy tuning (target entropy -(action dimensions)
unless set). Rewards are multiplied by the reward scale when they enter the replay buffer (the
logged returns are the env's). Each collector batch is followed by `updates_per_batch` gradient
updates; the first batch comes from uniform random actions (Table 3: one pre-training epoch).
Settings: conf/learner/sac.yaml (networks, losses, replay; shared with ePOET-SAC) and
conf/algo/sac.yaml (collection and updates). `SacLearner.gradient_steps` is what
bench/sac_updates.py times.

Speed (the project's target: the update rate of a plain-PyTorch SAC; bench/sac_updates.py):
the loss is ours (loss.py: the twin critics as one batched ensemble, no functional
parameter swaps or distribution objects), one fused Adam steps the actor, both critics and the
temperature together (the three losses touch disjoint parameters), and replay samples are drawn
SAMPLE_CHUNK batches per call and split.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import EnvBase
from torchrl.modules import MLP

from epoet.rl.env import OBS, policy_key
from epoet.rl.nets import ACTIVATIONS, SOFTPLUS_SCALE, ObsStandardize, make_actor, step_if_finite
from epoet.sac.config import SacLearnerConfig
from epoet.sac.loss import SacLoss, TwinQ

METRICS = ("loss_actor", "loss_qvalue", "loss_alpha", "alpha", "entropy")
SAMPLE_CHUNK = 50  # batches drawn from the replay buffer per call


class SacLearner:
    """SAC's networks, loss, optimiser, target updater and replay buffer (also ePOET-SAC's).

    ePOET-SAC's options: `standardize` puts an ObsStandardize in front of the actor and the
    critics (the ES pool's statistics, `set_obs_statistics`; the replay keeps raw observations),
    `scale_mapping` is the actor's scale head (epoet.rl.nets), `actor_lr` gives the actor its own
    learning rate (a fine-tune of loaded weights; None: `algo.lr` for every parameter),
    `anchor_weight` regularises the actor towards the one it was given (loss.py), and
    `warm_start` loads trained weights."""

    def __init__(
        self,
        algo: SacLearnerConfig,
        env: EnvBase,
        *,
        standardize: bool = False,
        scale_mapping: str = SOFTPLUS_SCALE,
        actor_lr: float | None = None,
        anchor_weight: float = 0.0,
    ) -> None:
        obs_dim, act_dim = env.observation_spec[OBS].shape[-1], env.action_spec.shape[-1]
        self.obs_dim = obs_dim
        self.standardize = ObsStandardize(obs_dim) if standardize else None
        self.actor = make_actor(
            env,
            algo.hidden,
            algo.activation,
            state_independent_scale=False,
            safe_tanh=False,
            scale_mapping=scale_mapping,
            standardize=self.standardize,
        )
        critics = TwinQ(obs_dim + act_dim, algo.hidden, ACTIVATIONS[algo.activation])
        target_entropy = -float(act_dim) if algo.target_entropy is None else algo.target_entropy
        self.loss = SacLoss(
            self.actor,
            critics,
            obs_key=policy_key(env),
            gamma=algo.gamma,
            alpha_init=algo.alpha_init,
            target_entropy=target_entropy,
            standardize=self.standardize,
            anchor_weight=anchor_weight,
        )
        self.tau = algo.tau
        trainable = [p for p in self.loss.parameters() if p.requires_grad]
        groups: list[dict[str, Any]] = [{"params": trainable}]
        if actor_lr is not None:  # the actor's weights in a group of their own
            actor = {id(p) for p in self.loss.policy_net.parameters()}
            groups = [
                {"params": [p for p in trainable if id(p) in actor], "lr": actor_lr},
                {"params": [p for p in trainable if id(p) not in actor]},
            ]
        self.optimizer = torch.optim.Adam(groups, lr=algo.lr, fused=True)
        # LazyTensorStorage reserves all rows at the first write; memory becomes resident as
        # rows are written, and checkpoints hold the written rows only (state_dict)
        self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(algo.buffer_size))
        self.keys = self.loss.in_keys
        self.reward_scale = algo.reward_scale
        self.batch_size = algo.batch_size

    @property
    def mlp(self) -> MLP:
        """The actor's MLP (obs -> [loc, scale pre-activations]), the exported policy's layout."""
        return next(m for m in self.actor.modules() if isinstance(m, MLP))

    @torch.no_grad()
    def warm_start(
        self,
        actor: dict[str, torch.Tensor],
        critics: dict[str, torch.Tensor],
        alpha: float | None = None,
    ) -> None:
        """Start from trained weights: the actor's MLP (the exported policy's state dict) and
        the twin critics (TwinQ's), the target critics a copy of them; weights that act on raw
        observations (they are re-expressed for the current statistics when standardising).
        `alpha`: the temperature the weights were trained with (None: `algo.alpha_init`); a
        trained actor under a far larger temperature is pulled towards entropy and loses its
        gait (docs/results/epoet-sac-warm-start/). The optimiser's state stays fresh."""
        if alpha is not None:
            self.loss.log_alpha.fill_(math.log(alpha))
        self.mlp.load_state_dict(actor)
        self.loss.critics.load_state_dict(critics)
        self.loss.target_critics.load_state_dict(critics)
        if self.standardize is not None:  # raw-observation weights: from mean 0, std 1
            mean, std = self.standardize.mean.clone(), self.standardize.std.clone()
            self.standardize.mean.zero_(), self.standardize.std.fill_(1.0)
            self.set_obs_statistics(mean, std)
        self.loss.reset_anchor()

    @torch.no_grad()
    def set_obs_statistics(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Standardise with new statistics, keeping every network's function of the raw
        observation: the first layers of the actor, critics and target critics are re-expressed
        (W' = W diag(std' / std), b' = b + W (mean' - mean) / std), so what SAC learned stays
        learned while the statistics move. Adam's moments are not re-expressed."""
        new_mean = torch.as_tensor(mean, dtype=torch.float32)
        new_std = torch.as_tensor(std, dtype=torch.float32)
        old = self.standardize
        assert old is not None, "set_obs_statistics needs a learner made with standardize=True"
        if torch.equal(new_mean, old.mean) and torch.equal(new_std, old.std):
            return
        ratio, shift = new_std / old.std, (new_mean - old.mean) / old.std
        first = self.mlp[0]  # (out, in)
        first.bias += first.weight @ shift
        first.weight *= ratio
        for twin in (self.loss.critics, self.loss.target_critics):
            w, b = twin.weights[0], twin.biases[0]  # (n, in, out), (n, 1, out)
            obs_w = w[:, : self.obs_dim, :]
            b += (shift @ obs_w)[:, None, :]
            obs_w *= ratio[:, None]
        old.mean.copy_(new_mean)
        old.std.copy_(new_std)

    def add(self, data: TensorDictBase) -> None:
        """Store transitions (the loss's keys, nothing more), rewards times the reward scale."""
        data = data.reshape(-1).select(*self.keys)
        data["next", "reward"] = data["next", "reward"] * self.reward_scale
        self.buffer.extend(data)

    def learn(
        self, batch: TensorDictBase, updates: int, critic_updates: int = 0
    ) -> dict[str, float]:
        """Store the batch, then (once the buffer holds a batch) `critic_updates` critic-only
        updates (`warm_loss_qvalue`: their mean critic loss) and `updates` updates."""
        self.add(batch)
        learned: dict[str, float] = {}
        if len(self.buffer) < self.batch_size:
            return learned
        if critic_updates:
            warm = self.gradient_steps(critic_updates, critics_only=True)
            learned["warm_loss_qvalue"] = warm.get("loss_qvalue", math.nan)
        if updates:
            learned.update(self.gradient_steps(updates))
        return learned

    def _samples(self, n: int) -> Iterator[TensorDictBase]:
        """`n` uniform batches from the buffer, drawn SAMPLE_CHUNK batches at a time and split:
        the same i.i.d. uniform draws as one `sample()` per update, with the buffer's per-call
        overhead paid once per chunk (worth ~8% of the update rate, see bench/sac_updates.py)."""
        done = 0
        while done < n:
            chunk = min(SAMPLE_CHUNK, n - done)
            yield from self.buffer.sample(chunk * self.batch_size).split(self.batch_size)
            done += chunk

    def gradient_steps(self, n: int, critics_only: bool = False) -> dict[str, float]:
        """`n` updates on uniform samples from the buffer; returns the mean of `METRICS`.
        `critics_only`: the critics (and their targets) learn, the actor and the temperature
        stay as they are (a warm start's critics meeting new terrains before the actor moves)."""
        total = torch.zeros(len(METRICS))
        stepped = 0
        for sample in self._samples(n):
            out = self.update(sample, critics_only)
            if out is not None:
                stepped += 1
                with torch.no_grad():
                    total += torch.stack([out[k] for k in METRICS])
        means = dict(zip(METRICS, (total / stepped).tolist())) if stepped else {}
        return {**means, "skipped_updates": n - stepped}

    def update(
        self, sample: TensorDictBase, critics_only: bool = False
    ) -> dict[str, torch.Tensor] | None:
        """One gradient step of actor, critics and temperature (`critics_only`: of the critics;
        Adam skips the parameters left without a gradient), then the soft target update; None
        (and no change) when the loss is not finite."""
        out = self.loss(sample)
        total = out["loss_qvalue"]
        if not critics_only:
            total = total + out["loss_actor"] + out["loss_alpha"]
        if not step_if_finite(self.optimizer, total):
            return None
        self.loss.update_targets(self.tau)
        return out

    def state_dict(self) -> dict[str, Any]:
        """Networks, optimiser and the replay buffer's filled rows only (in storage order, with
        the write cursor), so a checkpoint grows with the data, not with the capacity. The rows
        are copied: a slice shares the storage's memory, and pickling a view writes the whole
        reserved storage, however few rows it holds."""
        rows = self.buffer[:].exclude("index").clone() if len(self.buffer) else None
        return {
            "loss": self.loss.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "replay": rows,
            "writer": self.buffer.writer.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])
        if state["replay"] is not None:
            self.buffer.extend(state["replay"])  # rows 0..n-1, as they were stored
        self.buffer.writer.load_state_dict(state["writer"])
