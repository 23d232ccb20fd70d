"""Setup the three baselines share, in the role of sota-implementations' `utils.py`: the compute
plan, seeds, the environment and its observation normaliser, the networks, evaluation and the
collector. PPO's and SAC's loops and updates live in their own files (ppo.py, sac.py; vmpo.py
runs PPO's loop with the V-MPO loss of vmpo_loss.py); a run's bookkeeping (counters, checkpoints, resume) in run_state.py; the exported policy in
policy_file.py.

Data flow of one run:

    HexapodEnv --GymWrapper--> TransformedEnv(DoubleToFloat, [ObservationNorm, Clip], RewardSum,
    StepCounter)
        --Collector(actor)--> batch of frames_per_batch --> the algorithm's update --> metrics
        --> tracker; every budget.eval_every frames a deterministic evaluation on a second env.

Decisions (the paper's tables do not fix them):
- Terrain: the env draws a fresh terrain from the terrain config every episode (bowl-only by
  default; `terrain=cppn` gives a random CPPN terrain per episode) and its maximum height follows
  the schedule per episode (`make_terrain(cfg, seed, iteration=episode_index)`).
- Observation normalisation (`algo.obs_norm`, PPO and VMPO in the paper): the running mean and
  standard deviation of every raw observation collected so far (`RunningObsNorm`), applied by an
  ObservationNorm that writes `observation_norm` (the raw `observation` stays in the data),
  clipped to +-OBS_CLIP as common implementations do. The statistics are updated after each
  batch, so a batch is collected and learned with one normalisation (the first batch with none:
  loc 0, scale 1). Not VecNormV2: it computes E[x^2] - E[x]^2 in float32, which for a feature
  with a small spread around a large mean cancels to a negative variance and NaN observations
  (seen on this env in the first steps). The statistics are checkpointed and written into the
  policy.
- Actions: a tanh-squashed Gaussian (TorchRL's TanhNormal) for all three algorithms, so actions
  are always inside the actuators' [-1, 1] range; the deterministic action is tanh(loc).
- Evaluation: `budget.eval_episodes` episodes of the deterministic policy on a separate env whose
  terrains come from a fixed seed, at the training env's current point of the height schedule,
  at frame 0, every `budget.eval_every` frames and at the end. It runs under `fork_rng`, so it
  never changes the training's random streams.
"""
from __future__ import annotations

import math
import random
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import Categorical, Composite
from torchrl.envs import (ClipTransform, Compose, DoubleToFloat, EnvBase, ExplorationType,
                          GymWrapper, ObservationNorm, RewardSum, StepCounter,
                          TransformedEnv)
from torchrl.envs.gym_like import BaseInfoDictReader
from torchrl.envs.utils import set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from epoet.config import Config
from epoet.envs.hexapod_env import HexapodEnv
from epoet.core.compute import default_workers

OBS = "observation"
OBS_NORM = "observation_norm"
OBS_CLIP = 10.0             # normalised observations are clipped to +-OBS_CLIP
EVAL_SEED_OFFSET = 1_000_003  # evaluation terrains never coincide with the training env's seeds

ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


# --- compute plan ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class BatchPlan:
    """How a budget maps onto collector batches.

    budget.frames is the total; a batch is `algo.frames_per_batch` frames unless the budget is
    smaller, then the batch is the whole budget. `scale` (batch / algo.frames_per_batch) shrinks
    what is counted per batch in the config (SAC's updates and random frames), so the ratios of
    the paper -- e.g. 1000 SAC updates per 2000 frames -- hold at every budget. The run ends after
    `batches` batches, the first multiple of the batch at or above budget.frames.
    """

    frames_per_batch: int
    batches: int
    scale: float

    @property
    def total_frames(self) -> int:
        return self.frames_per_batch * self.batches

    def scaled(self, count: int, minimum: int = 0) -> int:
        """A per-batch count from the config, scaled to this batch size."""
        return max(minimum, round(count * self.scale))


def batch_plan(cfg: Config) -> BatchPlan:
    frames = min(cfg.algo.frames_per_batch, cfg.budget.frames)
    return BatchPlan(frames, math.ceil(cfg.budget.frames / frames),
                     frames / cfg.algo.frames_per_batch)


def set_threads(cfg: Config) -> int:
    """torch threads = workers.num, else the cores this process may use; returns the count."""
    threads = cfg.workers.num or default_workers()
    torch.set_num_threads(threads)
    return threads


# --- seeds ----------------------------------------------------------------------------------------

@dataclass
class Seeds:
    """Every seed a run uses, derived from cfg.seed and logged as `seeds.json`."""

    torch: int
    numpy: int
    python: int
    env: int
    eval: int

    @classmethod
    def from_seed(cls, seed: int) -> Seeds:
        return cls(torch=seed, numpy=seed, python=seed, env=seed, eval=seed + EVAL_SEED_OFFSET)

    def apply(self) -> None:
        torch.manual_seed(self.torch)
        np.random.seed(self.numpy)
        random.seed(self.python)


# --- environment ----------------------------------------------------------------------------------

class _FinishedReader(BaseInfoDictReader):
    """Copies the env's `finished` flag (finish line crossed) from `info` into the tensordict."""

    def __init__(self) -> None:
        self._spec = Composite(finished=Categorical(2, shape=(1,), dtype=torch.bool))

    def __call__(self, info_dict: dict[str, Any], tensordict: TensorDictBase) -> TensorDictBase:
        tensordict.set("finished", torch.tensor([bool(info_dict.get("finished", False))]))
        return tensordict

    def reset(self) -> None:
        """Nothing is cached between episodes."""

    @property
    def info_spec(self) -> Composite:
        return self._spec


def make_env(cfg: Config, *, obs_norm: bool, seed: int, resample_terrain: bool = True
             ) -> TransformedEnv:
    """The hexapod task as a TorchRL env: a fresh terrain from `cfg.terrain` every episode
    (`resample_terrain=False`: the terrain last given to `hexapod(env).set_terrain`, ePOET-SAC).

    Episodes last at most agent.max_episode_steps (= budget.episode_steps). Adds
    `episode_reward` (RewardSum) and `step_count` (StepCounter) for episode statistics and, with
    `obs_norm`, `observation_norm`.
    GymWrapper around the env object (not GymEnv on the registered id) keeps gymnasium's checker
    wrappers out of the per-step path.
    """
    base = GymWrapper(HexapodEnv(agent=cfg.agent, terrain=cfg.terrain,
                                 resample_terrain=resample_terrain))
    base.set_info_dict_reader(_FinishedReader())
    transforms: list = [DoubleToFloat()]
    if obs_norm:
        obs_dim = base.observation_spec[OBS].shape[-1]
        transforms += [ObservationNorm(loc=torch.zeros(obs_dim), scale=torch.ones(obs_dim),
                                       in_keys=[OBS], out_keys=[OBS_NORM], standard_normal=True),
                       ClipTransform(in_keys=[OBS_NORM], low=-OBS_CLIP, high=OBS_CLIP)]
    transforms += [RewardSum(), StepCounter()]
    env = TransformedEnv(base, Compose(*transforms))
    env.set_seed(seed)
    return env


def hexapod(env: EnvBase) -> HexapodEnv:
    """The gymnasium env inside a TorchRL env (its RNG and episode counter are run state)."""
    inner = env.base_env if isinstance(env, TransformedEnv) else env
    return inner._env


def obs_norm_of(env: EnvBase) -> ObservationNorm | None:
    """The env's observation normaliser, if it has one."""
    if isinstance(env, TransformedEnv):
        for t in env.transform:
            if isinstance(t, ObservationNorm):
                return t
    return None


class RunningObsNorm:
    """Running mean and standard deviation of raw observations, written into an ObservationNorm.

    Batches are merged with Chan et al.'s parallel update in float64; the scale is
    sqrt(var + 1e-8) (a constant feature gets scale 1e-4, as VecNorm's eps).
    """

    def __init__(self, transform: ObservationNorm) -> None:
        self.transform = transform
        dim = transform.loc.shape[-1]
        self.count = 0
        self.mean = torch.zeros(dim, dtype=torch.float64)
        self.m2 = torch.zeros(dim, dtype=torch.float64)   # sum of squared deviations

    def update(self, obs: torch.Tensor) -> None:
        obs = obs.reshape(-1, obs.shape[-1]).double()
        n = obs.shape[0]
        mean = obs.mean(0)
        delta = mean - self.mean
        total = self.count + n
        self.m2 += ((obs - mean) ** 2).sum(0) + delta ** 2 * self.count * n / total
        self.mean += delta * n / total
        self.count = total
        self._write()

    def _write(self) -> None:
        with torch.no_grad():
            self.transform.loc.copy_(self.mean)
            self.transform.scale.copy_((self.m2 / max(self.count, 1) + 1e-8).sqrt())

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "mean": self.mean.clone(), "m2": self.m2.clone()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count, self.mean, self.m2 = state["count"], state["mean"].clone(), state["m2"].clone()
        self._write()


def policy_key(env: EnvBase) -> str:
    """The observation the networks read: normalised if the env normalises."""
    return OBS_NORM if obs_norm_of(env) is not None else OBS


# --- networks -------------------------------------------------------------------------------------

def mlp(in_features: int, out_features: int, hidden: list[int], activation: str) -> MLP:
    """[Linear, act] * len(hidden) + Linear: the layout `load_policy` rebuilds."""
    return MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden),
               activation_class=ACTIVATIONS[activation])


def make_actor(env: EnvBase, hidden: list[int], activation: str, *,
               state_independent_scale: bool, safe_tanh: bool = True) -> ProbabilisticActor:
    """A tanh-Gaussian policy on [-1, 1]^act_dim (the hexapod's action space).

    PPO and VMPO learn one log-std per action dimension (`state_independent_scale`, paper
    Table 2); SAC's network outputs the scale too. `safe_tanh` (TorchRL's clamped tanh) is needed
    where the log-probability of stored actions is recomputed by inverting tanh (PPO, VMPO); SAC
    scores its own reparameterised samples from their pre-tanh values and uses plain tanh.
    """
    spec = env.action_spec
    if not (bool((spec.space.low == -1).all()) and bool((spec.space.high == 1).all())):
        raise ValueError(f"the RL baselines expect actions in [-1, 1], got {spec.space}.")
    obs_dim = env.observation_spec[OBS].shape[-1]
    act_dim = spec.shape[-1]
    if state_independent_scale:
        net = nn.Sequential(mlp(obs_dim, act_dim, hidden, activation),
                            AddStateIndependentNormalScale(act_dim))
    else:
        net = nn.Sequential(mlp(obs_dim, 2 * act_dim, hidden, activation), NormalParamExtractor())
    # bounds as Python numbers: TanhNormal then skips per-call tensor checks on them
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=[policy_key(env)], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], spec=spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0, "safe_tanh": safe_tanh},
        return_log_prob=True, default_interaction_type=ExplorationType.RANDOM)


def make_value(env: EnvBase, hidden: list[int], activation: str) -> ValueOperator:
    """V(s) for PPO and VMPO."""
    return ValueOperator(mlp(env.observation_spec[OBS].shape[-1], 1, hidden, activation),
                         in_keys=[policy_key(env)])


# --- evaluation -----------------------------------------------------------------------------------

def evaluate(env: EnvBase, actor: ProbabilisticActor, episodes: int, seed: int,
             episode_index: int, max_steps: int) -> dict[str, float]:
    """Mean return, length and finish rate of `episodes` deterministic-policy episodes.

    Terrains come from `seed` at height-schedule position `episode_index`, so evaluations at the
    same schedule point see the same terrains.
    """
    returns, lengths, finished = [], [], []
    with torch.random.fork_rng(devices=[]), torch.no_grad(), \
            set_exploration_type(ExplorationType.DETERMINISTIC):
        env.set_seed(seed)
        hexapod(env).episodes = episode_index
        for _ in range(episodes):
            td = env.rollout(max_steps, policy=actor)
            returns.append(float(td["next", "reward"].sum()))
            lengths.append(td.shape[0])
            finished.append(bool(td["next", "finished"].any()))
    return {"return_mean": float(np.mean(returns)), "return_std": float(np.std(returns)),
            "length_mean": float(np.mean(lengths)), "finish_rate": float(np.mean(finished))}


# --- collection -----------------------------------------------------------------------------------

def make_collector(env: EnvBase, actor: ProbabilisticActor, plan: BatchPlan,
                   random_frames: int = 0) -> Collector:
    """Batches of `plan.frames_per_batch` frames from the stochastic actor, forever (the loop
    counts); the first `random_frames` frames use uniform random actions (SAC)."""
    return Collector(env, actor, frames_per_batch=plan.frames_per_batch, total_frames=-1,
                     init_random_frames=random_frames, exploration_type=ExplorationType.RANDOM,
                     auto_register_policy_transforms=False)  # the policy is not recurrent


def episode_metrics(batch: TensorDictBase) -> dict[str, float]:
    """Return, length and finish rate of the episodes that ended in `batch` (none: {})."""
    done = batch["next", "done"].squeeze(-1)
    if not bool(done.any()):
        return {}
    return {"episode_return": float(batch["next", "episode_reward"][done].mean()),
            "episode_length": float(batch["next", "step_count"][done].float().mean()),
            "finish_rate": float(batch["next", "finished"][done].float().mean())}


def step_if_finite(optimizer: torch.optim.Optimizer, total: torch.Tensor,
                   clip: Sequence[Iterable[nn.Parameter]] = (),
                   max_grad_norm: float | None = None) -> bool:
    """Backpropagate `total` and step, unless the loss or a clipped gradient norm is not finite:
    then nothing changes (weights and optimiser state) and False is returned, so one bad batch
    cannot poison the networks. The caller counts the skips (`skipped_updates`)."""
    optimizer.zero_grad(set_to_none=True)
    if not torch.isfinite(total):
        return False
    total.backward()
    if max_grad_norm is not None:
        for params in clip:  # each group clipped on its own norm (actor and critic, say)
            if not torch.isfinite(nn.utils.clip_grad_norm_(params, max_grad_norm)):
                optimizer.zero_grad(set_to_none=True)
                return False
    optimizer.step()
    return True
