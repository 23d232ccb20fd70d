"""The robot's task as the baselines' TorchRL env: its construction, the run's seeds, the running
observation normaliser, the statistics of the episodes a batch ended and the deterministic
policy's evaluation.

    TerrainEnv --GymWrapper--> TransformedEnv(DoubleToFloat, [ObservationNorm, Clip], RewardSum,
    StepCounter)

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
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical, Composite
from torchrl.envs import (
    ClipTransform,
    Compose,
    DoubleToFloat,
    EnvBase,
    ExplorationType,
    GymWrapper,
    ObservationNorm,
    RewardSum,
    StepCounter,
    TransformedEnv,
)
from torchrl.envs.gym_like import BaseInfoDictReader
from torchrl.envs.utils import set_exploration_type
from torchrl.modules import ProbabilisticActor

from epoet.config import Config
from epoet.envs.terrain_env import TerrainEnv

OBS = "observation"
OBS_NORM = "observation_norm"
OBS_CLIP = 10.0  # normalised observations are clipped to +-OBS_CLIP
EVAL_SEED_OFFSET = 1_000_003  # evaluation terrains never coincide with the training env's seeds


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


def make_env(
    cfg: Config, *, obs_norm: bool, seed: int, resample_terrain: bool = True
) -> TransformedEnv:
    """The robot's task as a TorchRL env: a fresh terrain from `cfg.terrain` every episode
    (`resample_terrain=False`: the terrain last given to `terrain_env(env).set_terrain`,
    ePOET-SAC).

    Episodes last at most agent.max_episode_steps (= budget.episode_steps). Adds
    `episode_reward` (RewardSum) and `step_count` (StepCounter) for episode statistics and, with
    `obs_norm`, `observation_norm`.
    GymWrapper around the env object (not GymEnv on the registered id) keeps gymnasium's checker
    wrappers out of the per-step path.
    """
    base = GymWrapper(
        TerrainEnv(agent=cfg.agent, terrain=cfg.terrain, resample_terrain=resample_terrain)
    )
    base.set_info_dict_reader(_FinishedReader())
    transforms: list = [DoubleToFloat()]
    if obs_norm:
        obs_dim = base.observation_spec[OBS].shape[-1]
        transforms += [
            ObservationNorm(
                loc=torch.zeros(obs_dim),
                scale=torch.ones(obs_dim),
                in_keys=[OBS],
                out_keys=[OBS_NORM],
                standard_normal=True,
            ),
            ClipTransform(in_keys=[OBS_NORM], low=-OBS_CLIP, high=OBS_CLIP),
        ]
    transforms += [RewardSum(), StepCounter()]
    env = TransformedEnv(base, Compose(*transforms))
    env.set_seed(seed)
    return env


def terrain_env(env: EnvBase) -> TerrainEnv:
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


def policy_key(env: EnvBase) -> str:
    """The observation the networks read: normalised if the env normalises."""
    return OBS_NORM if obs_norm_of(env) is not None else OBS


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
        self.m2 = torch.zeros(dim, dtype=torch.float64)  # sum of squared deviations

    def update(self, obs: torch.Tensor) -> None:
        obs = obs.reshape(-1, obs.shape[-1]).double()
        n = obs.shape[0]
        mean = obs.mean(0)
        delta = mean - self.mean
        total = self.count + n
        self.m2 += ((obs - mean) ** 2).sum(0) + delta**2 * self.count * n / total
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


def episode_metrics(batch: TensorDictBase) -> dict[str, float]:
    """Return, length and finish rate of the episodes that ended in `batch` (none: {}), from the
    keys `make_env`'s transforms and info reader add."""
    done = batch["next", "done"].squeeze(-1)
    if not bool(done.any()):
        return {}
    return {
        "episode_return": float(batch["next", "episode_reward"][done].mean()),
        "episode_length": float(batch["next", "step_count"][done].float().mean()),
        "finish_rate": float(batch["next", "finished"][done].float().mean()),
    }


def evaluate(
    env: EnvBase,
    actor: ProbabilisticActor,
    episodes: int,
    seed: int,
    episode_index: int,
    max_steps: int,
) -> dict[str, float]:
    """Mean return, length and finish rate of `episodes` deterministic-policy episodes.

    Terrains come from `seed` at height-schedule position `episode_index`, so evaluations at the
    same schedule point see the same terrains.
    """
    returns, lengths, finished = [], [], []
    with (
        torch.random.fork_rng(devices=[]),
        torch.no_grad(),
        set_exploration_type(ExplorationType.DETERMINISTIC),
    ):
        env.set_seed(seed)
        terrain_env(env).episodes = episode_index
        for _ in range(episodes):
            td = env.rollout(max_steps, policy=actor)
            returns.append(float(td["next", "reward"].sum()))
            lengths.append(td.shape[0])
            finished.append(bool(td["next", "finished"].any()))
    return {
        "return_mean": float(np.mean(returns)),
        "return_std": float(np.std(returns)),
        "length_mean": float(np.mean(lengths)),
        "finish_rate": float(np.mean(finished)),
    }


def rng_state(env: EnvBase) -> dict[str, Any]:
    """Every random stream a baseline's training draws from, for an exact resume."""
    gym_env = terrain_env(env)
    return {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
        "env": gym_env.np_random.bit_generator.state,
        "env_episodes": gym_env.episodes,
    }


def set_rng_state(env: EnvBase, state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    gym_env = terrain_env(env)
    gym_env.np_random.bit_generator.state = state["env"]
    gym_env.episodes = state["env_episodes"]
