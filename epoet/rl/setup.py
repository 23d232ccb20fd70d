"""What PPO, SAC and VMPO share: the environment, the networks, evaluation, the exported policy and
the training loop (collection, tracking, evaluation, checkpoints, progress).

An algorithm module (ppo.py, sac.py, vmpo_runner.py) only builds its `Agent` -- networks, TorchRL
loss, optimiser, its `learn(batch)` -- and hands it to `train_loop`; everything else is here, once.

Data flow of one run:

    HexapodEnv --GymWrapper--> TransformedEnv(DoubleToFloat, [ObservationNorm, Clip], RewardSum,
    StepCounter)
        --Collector(agent.actor)--> batch of frames_per_batch --> agent.learn(batch) --> metrics
        --> tracker; every budget.eval_every frames a deterministic evaluation on a second env.

Decisions (the paper's tables do not fix them):
- Terrain: the env draws a fresh terrain from the terrain config every episode (bowl-only by
  default; `terrain=cppn` gives a random CPPN terrain per episode) and its maximum height follows
  the schedule per episode (`make_terrain(cfg, seed, iteration=episode_index)`).
- Observation normalisation (`algo.obs_norm`, PPO and VMPO in the paper): the running mean and
  standard deviation of every raw observation collected so far (`RunningObsNorm`), applied by an
  ObservationNorm that writes `observation_norm` (the raw `observation` stays in the data),
  clipped to +-10 as common implementations do. The statistics are updated after each batch, so
  a batch is collected and learned with one normalisation (the first batch with none: loc 0,
  scale 1). Not VecNormV2: it computes E[x^2] - E[x]^2 in float32, which for a feature with a
  small spread around a large mean cancels to a negative variance and NaN observations (seen on
  this env in the first steps). The statistics are checkpointed and written into the policy.
- Actions: a tanh-squashed Gaussian (TorchRL's TanhNormal) for all three algorithms, so actions
  are always inside the actuators' [-1, 1] range; the deterministic action is tanh(loc).
- Checkpoints: every `cfg.checkpoint_every` collector batches and at the end. To make a resumed
  run continue exactly like an uninterrupted one, a checkpoint ends the running episode: the
  collector resets its env right after saving (and a resumed run resets right after loading), so
  no mid-episode simulator state needs saving. The cut episode is not counted in the training
  episode statistics; its transitions are still learned from.
- Evaluation: `budget.eval_episodes` episodes of the deterministic policy on a separate env whose
  terrains come from a fixed seed, at the training env's current point of the height schedule,
  at frame 0, every `budget.eval_every` frames and at the end. It runs under `fork_rng`, so it
  never changes the training's random streams.
"""
from __future__ import annotations

import dataclasses
import math
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Protocol

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import (Categorical, Composite, LazyTensorStorage, SamplerWithoutReplacement,
                          TensorDictReplayBuffer)
from torchrl.envs import (ClipTransform, Compose, DoubleToFloat, EnvBase, ExplorationType,
                          GymWrapper, ObservationNorm, RewardSum, StepCounter,
                          TransformedEnv)
from torchrl.envs.gym_like import BaseInfoDictReader
from torchrl.envs.utils import set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import LossModule
from torchrl.objectives.value import GAE
from tqdm import tqdm

from epoet.checkpoint import save_run_state
from epoet.config import Config, OnPolicyConfig
from epoet.envs import HexapodEnv
from epoet.es.workers import default_workers

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker

OBS = "observation"
OBS_NORM = "observation_norm"
OBS_CLIP = 10.0             # normalised observations are clipped to +-OBS_CLIP
POLICY_FILE = "policy.pt"
POLICY_FORMAT = "epoet-policy/1"
EVAL_SEED_OFFSET = 1_000_003  # evaluation terrains never coincide with the training env's seeds

_ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


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


def make_env(cfg: Config, *, obs_norm: bool, seed: int) -> TransformedEnv:
    """The hexapod task as a TorchRL env: a fresh terrain from `cfg.terrain` every episode.

    Episodes last at most agent.max_episode_steps (= budget.episode_steps). Adds
    `episode_reward` (RewardSum) and `step_count` (StepCounter) for episode statistics and, with
    `obs_norm`, `observation_norm`.
    GymWrapper around the env object (not GymEnv on the registered id) keeps gymnasium's checker
    wrappers out of the per-step path.
    """
    base = GymWrapper(HexapodEnv(agent=cfg.agent, terrain=cfg.terrain, resample_terrain=True))
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
               activation_class=_ACTIVATIONS[activation])


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


def make_qvalue(env: EnvBase, hidden: list[int], activation: str) -> ValueOperator:
    """Q(s, a) for SAC (the MLP concatenates its inputs)."""
    in_features = env.observation_spec[OBS].shape[-1] + env.action_spec.shape[-1]
    return ValueOperator(mlp(in_features, 1, hidden, activation),
                         in_keys=[policy_key(env), "action"])


def _actor_mlp(actor: ProbabilisticActor) -> MLP:
    return next(m for m in actor.modules() if isinstance(m, MLP))


# --- the exported policy --------------------------------------------------------------------------

def export_policy(path: Path, actor: ProbabilisticActor, env: EnvBase, hidden: list[int],
                  activation: str) -> Path:
    """Write the deterministic policy as plain data: architecture, normaliser and weights.

    `load_policy` rebuilds it with nothing but torch: a reader needs neither TorchRL nor the
    training state.
    """
    norm = obs_norm_of(env)
    net = _actor_mlp(actor)
    spec = {
        "format": POLICY_FORMAT,
        "obs_dim": env.observation_spec[OBS].shape[-1],
        "act_dim": env.action_spec.shape[-1],
        "hidden": list(hidden),
        "activation": activation,
        "obs_loc": None if norm is None else norm.loc.detach().clone(),
        "obs_scale": None if norm is None else norm.scale.detach().clone(),
        "obs_clip": None if norm is None else OBS_CLIP,
        "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
    }
    torch.save(spec, path)
    return path


def load_policy(path: str | Path) -> Callable[[np.ndarray], np.ndarray]:
    """Rebuild an exported policy as `act(obs) -> action` (numpy in, numpy out, batched or not).

    action = tanh(first act_dim outputs of the MLP applied to clip((obs - loc) / scale)).
    """
    spec = torch.load(Path(path), weights_only=True)
    if not isinstance(spec, dict) or spec.get("format") != POLICY_FORMAT:
        raise ValueError(f"{path} is not an epoet policy file ({POLICY_FORMAT}).")
    sizes = [spec["obs_dim"], *spec["hidden"]]
    layers: list[nn.Module] = []
    for n_in, n_out in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(n_in, n_out), _ACTIVATIONS[spec["activation"]]()]
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


# --- on-policy learning (PPO and VMPO) ------------------------------------------------------------

class OnPolicyAgent:
    """The on-policy update PPO and VMPO share; only the TorchRL loss module differs.

    Per collector batch: GAE advantages and value targets once (with the critic before the
    update, as CleanRL), then `epochs` passes over the batch in shuffled minibatches drawn
    without replacement from a TensorDictReplayBuffer; each minibatch steps one Adam on the sum of
    the loss's `loss_*` terms. One Adam over actor and critic equals the paper's two optimisers
    with the same learning rate (Table 2 lists a policy and a value learning rate, both 3e-4):
    the networks share no parameters and Adam is per parameter. For the same reason gradients
    are clipped per network, so one network's gradient never scales the other's; the loss's own
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
        with torch.no_grad():
            batch = self.gae(batch)
        self.buffer.empty()
        self.buffer.extend(batch.reshape(-1))
        sums: dict[str, torch.Tensor] = {}
        for _ in range(self.epochs):
            for _ in range(self.minibatches):
                out = self.loss(self.buffer.sample())
                total = sum(v for k, v in out.items() if k.startswith("loss_"))
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                if self.max_grad_norm is not None:
                    nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
                    nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
                self.optimizer.step()
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + v.detach().float().mean()
        steps = self.epochs * self.minibatches
        return {k: float(v) / steps for k, v in sums.items()}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])


# --- the training loop ----------------------------------------------------------------------------

class Agent(Protocol):
    """What an algorithm gives the loop."""

    actor: ProbabilisticActor       # the collector's policy; deterministic for evaluation

    def learn(self, batch: TensorDictBase) -> dict[str, float]:
        """Learn from one collector batch; returns metrics (losses, entropy, ...)."""

    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers, learned multipliers, replay buffer: all a resume needs."""

    def load_state_dict(self, state: dict[str, Any]) -> None: ...


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


@dataclass
class LoopState:
    """The loop's counters (checkpointed with the agent)."""

    frames: int = 0
    batches: int = 0
    episodes: int = 0               # finished training episodes
    next_eval: int = 0              # frame count of the next evaluation
    last_eval_frames: int = -1
    last_eval: dict[str, float] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0          # seconds of training, summed over resumes


@dataclass
class TrainResult:
    """What a baseline runner returns."""

    frames: int
    batches: int
    final_eval: dict[str, float]
    policy_path: Path
    agent: Agent


BuildAgent = Callable[[Config, EnvBase, BatchPlan], Agent]


def _rng_state(env: EnvBase) -> dict[str, Any]:
    gym_env = hexapod(env)
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(),
            "python": random.getstate(), "env": gym_env.np_random.bit_generator.state,
            "env_episodes": gym_env.episodes}


def _set_rng_state(env: EnvBase, state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    gym_env = hexapod(env)
    gym_env.np_random.bit_generator.state = state["env"]
    gym_env.episodes = state["env_episodes"]


def _episode_metrics(batch: TensorDictBase) -> dict[str, float]:
    done = batch["next", "done"].squeeze(-1)
    if not bool(done.any()):
        return {}
    return {"episode_return": float(batch["next", "episode_reward"][done].mean()),
            "episode_length": float(batch["next", "step_count"][done].float().mean()),
            "finish_rate": float(batch["next", "finished"][done].float().mean())}


def train_loop(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None,
               build_agent: BuildAgent) -> TrainResult:
    """Collect, learn, track, evaluate and checkpoint until budget.frames; export the policy.

    Metrics go to the tracker at step = frames: `train/*` (episode return and length, the
    agent's losses and diagnostics), `eval/*` (return_mean, return_std, length_mean,
    finish_rate), `frames`, `fps`, and `final/*` (the last evaluation) at the end.
    """
    set_threads(cfg)
    plan = batch_plan(cfg)
    seeds = Seeds.from_seed(cfg.seed)
    seeds.apply()
    env = make_env(cfg, obs_norm=cfg.algo.obs_norm, seed=seeds.env)
    eval_env = make_env(cfg, obs_norm=cfg.algo.obs_norm, seed=seeds.eval)
    agent = build_agent(cfg, env, plan)
    state = LoopState(**resume["loop"]) if resume is not None else LoopState()
    if resume is None:
        tracker.log_dict(dataclasses.asdict(seeds), "seeds.json")
    # uniform random actions for the first init_random_frames (SAC); none left after a resume
    # that is past them
    random_frames = max(0, plan.scaled(getattr(cfg.algo, "init_random_frames", 0)) - state.frames)
    collector = Collector(env, agent.actor, frames_per_batch=plan.frames_per_batch,
                          total_frames=-1, init_random_frames=random_frames,
                          exploration_type=ExplorationType.RANDOM,
                          auto_register_policy_transforms=False)  # the policy is not recurrent
    obs_stats = RunningObsNorm(obs_norm_of(env)) if cfg.algo.obs_norm else None
    if resume is not None:
        # Restore after the collector's construction, which resets the env and may draw random
        # numbers; then start a new episode exactly as the interrupted run did right after
        # writing the checkpoint.
        agent.load_state_dict(resume["agent"])
        if obs_stats is not None:
            obs_stats.load_state_dict(resume["obs_norm"])
        _set_rng_state(env, resume["rng"])
        collector.reset()

    def eval_if_due() -> None:
        if state.frames < state.next_eval:
            return
        run_eval()
        while state.next_eval <= state.frames:
            state.next_eval += cfg.budget.eval_every

    def run_eval() -> None:
        if obs_stats is not None:  # the evaluation env normalises as the training env
            obs_norm_of(eval_env).load_state_dict(obs_norm_of(env).state_dict())
        state.last_eval = evaluate(eval_env, agent.actor, cfg.budget.eval_episodes, seeds.eval,
                                   hexapod(env).episodes, cfg.budget.episode_steps)
        state.last_eval_frames = state.frames
        tracker.log_metrics(state.frames, {f"eval/{k}": v for k, v in state.last_eval.items()})
        progress.write(f"[{cfg.algo.name}] frames={state.frames} eval return="
                       f"{state.last_eval['return_mean']:.1f} "
                       f"finish={state.last_eval['finish_rate']:.2f}")

    def checkpoint() -> None:
        save_run_state(run_dir, tracker, cfg, {
            "loop": dataclasses.asdict(state), "agent": agent.state_dict(),
            "obs_norm": None if obs_stats is None else obs_stats.state_dict(),
            "rng": _rng_state(env),
            "seeds": dataclasses.asdict(seeds)})

    progress = tqdm(total=plan.total_frames, initial=state.frames, unit="frame",
                    desc=cfg.algo.name, disable=None, dynamic_ncols=True)
    try:
        eval_if_due()
        batches = iter(collector)
        while state.batches < plan.batches:
            start = time.perf_counter()
            batch = next(batches)
            metrics = {f"train/{k}": v for k, v in _episode_metrics(batch).items()}
            state.episodes += int(batch["next", "done"].sum())
            learned = agent.learn(batch)
            broken = sorted(k for k, v in learned.items() if not math.isfinite(v))
            if broken:  # stop rather than train on (and checkpoint) NaN weights
                raise FloatingPointError(
                    f"{cfg.algo.name} produced non-finite {broken} in the batch ending at frame "
                    f"{state.frames + batch.numel()}.")
            metrics.update({f"train/{k}": v for k, v in learned.items()})
            if obs_stats is not None:
                obs_stats.update(batch[OBS])
            elapsed = time.perf_counter() - start
            state.frames += batch.numel()
            state.batches += 1
            state.wall_time += elapsed
            metrics.update({"frames": state.frames, "fps": batch.numel() / elapsed,
                            "wall_time": state.wall_time, "train/episodes": state.episodes})
            tracker.log_metrics(state.frames, metrics)
            progress.update(batch.numel())
            eval_if_due()
            if state.batches % cfg.checkpoint_every == 0 and state.batches < plan.batches:
                checkpoint()
                collector.reset()  # see the module docstring: checkpoints end the episode
        if state.last_eval_frames != state.frames:
            run_eval()
        tracker.log_metrics(state.frames, {f"final/{k}": v for k, v in state.last_eval.items()})
        checkpoint()
        policy_path = export_policy(run_dir / POLICY_FILE, agent.actor, env, cfg.algo.hidden,
                                    cfg.algo.activation)
        tracker.log_artifact(policy_path)
        tracker.flush()
    finally:
        progress.close()
        collector.shutdown()
        eval_env.close()
    return TrainResult(state.frames, state.batches, dict(state.last_eval), policy_path, agent)
