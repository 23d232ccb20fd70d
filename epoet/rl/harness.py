"""What every baseline's training loop shares: how the budget maps onto collector batches, the
collector, the seeded envs, counters, metrics, evaluation, checkpoints with exact resume, stop
handling and the exported policy. The loop itself -- when to collect, learn, log, evaluate and
checkpoint -- is written out in each algorithm's file (ppo.py, sac.py, vmpo.py):

    with Harness(cfg, tracker, run_dir, resume) as run:      # threads, seeds, envs, counters
        ... networks, learner, collector ...
        run.start(collector, learner, actor)                 # restores a resumed run
        while not run.budget_spent():
            batch = next(batches); learner.learn(batch); run.log(...)
            if due: run.evaluate(actor)
            if run.checkpoint_due(): run.checkpoint(learner); raise_if_stopped(); reset
        return run.finish(learner)

Checkpoints: every `cfg.checkpoint_every` collector batches and at the end. To make a resumed run
continue exactly like an uninterrupted one, a checkpoint ends the running episode: the collector
resets its env right after saving (and a resumed run resets right after loading), so no
mid-episode simulator state needs saving. The cut episode is not counted in the training episode
statistics; its transitions are still learned from.

Evaluation (the paper's tables do not fix it): `budget.eval_episodes` episodes of the
deterministic policy on a separate env whose terrains come from a fixed seed, at the training
env's current point of the height schedule, at frame 0, every `budget.eval_every` frames and at
the end. It runs under `fork_rng`, so it never changes the training's random streams.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, cast

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, ExplorationType
from torchrl.modules import ProbabilisticActor
from tqdm import tqdm

from epoet.config import BaselineBudgetConfig, Config
from epoet.core.clock import CpuMeter
from epoet.core.compute import default_workers
from epoet.core.lifecycle import stop_requested
from epoet.rl.candidates import Candidates
from epoet.rl.config import RlConfig, SacConfig
from epoet.rl.env import (
    RunningObsNorm,
    Seeds,
    episode_metrics,
    evaluate,
    make_env,
    obs_norm_of,
    rng_state,
    set_rng_state,
    terrain_env,
)
from epoet.rl.policy_file import POLICY_FILE, export_policy
from epoet.run_state import report_stop, save_run_state, take_snapshots
from epoet.terrain import max_height_at

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


# --- the compute plan and the collector -----------------------------------------------------------


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


def baseline(cfg: Config) -> RlConfig | SacConfig:
    """The run's baseline settings: PPO's or VMPO's (`RlConfig`), or SAC's."""
    algo = cfg.algo
    if not isinstance(algo, (RlConfig, SacConfig)):
        raise TypeError(f"algo={algo.name} is not a baseline.")  # a runner's bug
    return algo


def batch_plan(cfg: Config) -> BatchPlan:
    budget = cast(BaselineBudgetConfig, cfg.budget)  # a baseline's record: the baselines family
    per_batch = baseline(cfg).frames_per_batch
    frames = min(per_batch, budget.frames)
    return BatchPlan(frames, math.ceil(budget.frames / frames), frames / per_batch)


def set_threads(cfg: Config) -> int:
    """torch threads = workers.num, else the cores this process may use; returns the count."""
    threads = cfg.workers.num or default_workers()
    torch.set_num_threads(threads)
    return threads


def make_collector(
    env: EnvBase, actor: ProbabilisticActor, plan: BatchPlan, random_frames: int = 0
) -> Collector:
    """Batches of `plan.frames_per_batch` frames from the stochastic actor, forever (the loop
    counts); the first `random_frames` frames use uniform random actions (SAC)."""
    return Collector(
        env,
        actor,
        frames_per_batch=plan.frames_per_batch,
        total_frames=-1,
        init_random_frames=random_frames,
        exploration_type=ExplorationType.RANDOM,
        auto_register_policy_transforms=False,
    )  # the policy is not recurrent


# --- the run's state ------------------------------------------------------------------------------


class Learner(Protocol):
    """What a run checkpoints of an algorithm: networks, optimisers, learned multipliers, the
    replay buffer; everything a resume needs."""

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> None: ...


@dataclass
class LoopState:
    """The loop's counters (checkpointed with the learner)."""

    frames: int = 0
    batches: int = 0
    episodes: int = 0  # finished training episodes
    next_eval: int = 0  # frame count of the next evaluation
    last_eval_frames: int = -1
    last_eval: dict[str, float] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0  # seconds of training, summed over resumes
    cpu_time: float = 0.0  # CPU seconds of the run's processes (evaluations too), over resumes
    best_score: float = -math.inf  # the best evaluation return so far


@dataclass
class TrainResult:
    """What a baseline runner returns."""

    frames: int
    batches: int
    final_eval: dict[str, float]
    policy_path: Path
    learner: Any


class Harness:
    """Seeds, the training and evaluation envs, counters, tracking, checkpoints and progress of
    one baseline run. Metrics go to the tracker at step = frames: `train/*` (episode return and
    length, the learner's losses and diagnostics), `eval/*` (return_mean, return_std,
    length_mean, finish_rate), `score` (eval/return_mean) and `best_score` (its best so far),
    `frames`, `fps`, `time/batch`, and `final/*` (the last evaluation) at the end."""

    def __init__(
        self, cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
    ) -> None:
        set_threads(cfg)
        self.cfg, self.tracker, self.run_dir, self.resume = cfg, tracker, run_dir, resume
        self.plan = batch_plan(cfg)
        self.seeds = Seeds.from_seed(cfg.seed)
        self.seeds.apply()
        # the envs before the networks: their construction draws from the seeded streams
        self.algo = baseline(cfg)
        self.env = make_env(cfg, obs_norm=self.algo.obs_norm, seed=self.seeds.env)
        self.eval_env = make_env(cfg, obs_norm=self.algo.obs_norm, seed=self.seeds.eval)
        self.state = LoopState(**resume["loop"]) if resume is not None else LoopState()
        self.obs_stats = RunningObsNorm(obs_norm_of(self.env)) if self.algo.obs_norm else None
        self.collector: Collector | None = None
        self.actor: ProbabilisticActor | None = None
        self.progress: tqdm | None = None
        self.cpu_meter = CpuMeter()
        self.candidates = Candidates(cfg, run_dir)  # the policies it may export (`selection`)
        if resume is None:
            tracker.log_dict(dataclasses.asdict(self.seeds), "seeds.json")

    def __enter__(self) -> Harness:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if self.progress is not None:
            self.progress.close()
        if self.collector is not None:
            self.collector.shutdown()
        self.eval_env.close()

    def start(self, collector: Collector, learner: Learner, actor: ProbabilisticActor) -> None:
        """Restore a resumed run's state and open the progress bar; the harness shuts
        `collector` down when it exits and exports `actor` at checkpoints and snapshots."""
        self.collector, self.actor = collector, actor
        if self.resume is not None:
            # After the collector's construction, which resets the env and may draw random
            # numbers; then a new episode starts exactly as the interrupted run's did right
            # after writing the checkpoint.
            learner.load_state_dict(self.resume["learner"])
            if self.obs_stats is not None:
                self.obs_stats.load_state_dict(self.resume["obs_norm"])
            set_rng_state(self.env, self.resume["rng"])
            collector.reset()
        self.progress = tqdm(
            total=self.plan.total_frames,
            initial=self.state.frames,
            unit="frame",
            desc=self.cfg.algo.name,
            disable=None,
            dynamic_ncols=True,
        )

    def budget_spent(self) -> bool:
        """The budget's batches are collected or its hours (or CPU hours) are used."""
        return self.state.batches >= self.plan.batches or self.out_of_time() is not None

    def out_of_time(self) -> str | None:
        return self.cfg.budget.time_is_up(self.state.wall_time, self.state.cpu_time)

    def checkpoint_due(self) -> bool:
        """Every `checkpoint_every` batches but the last (`finish` writes that one), and when a
        signal asked the run to stop."""
        return (
            self.state.batches % self.cfg.checkpoint_every == 0 or stop_requested()
        ) and not self.budget_spent()

    def log(self, batch: TensorDictBase, learned: dict[str, float], started: float) -> None:
        """Count the batch (collected from time.perf_counter() = `started` on) and send its
        metrics.

        Stops the run on a non-finite learner metric rather than train on (and checkpoint)
        NaN weights.
        """
        broken = sorted(k for k, v in learned.items() if not math.isfinite(v))
        if broken:
            raise FloatingPointError(
                f"{self.cfg.algo.name} produced non-finite {broken} in the batch ending at "
                f"frame {self.state.frames + batch.numel()}."
            )
        metrics = {f"train/{k}": v for k, v in {**episode_metrics(batch), **learned}.items()}
        elapsed = time.perf_counter() - started
        state = self.state
        state.episodes += int(batch["next", "done"].sum())
        state.frames += batch.numel()
        state.batches += 1
        state.wall_time += elapsed
        state.cpu_time += self.cpu_meter.lap()  # since the last batch: its evaluation too
        # env_steps and elapsed are the x-axes every algorithm logs (ePOET too), so MLflow can
        # chart all algorithms against environment steps or training time.
        metrics.update(
            {
                "frames": state.frames,
                "fps": batch.numel() / elapsed,
                "time/batch": elapsed,
                "train/episodes": state.episodes,
                "env_steps": state.frames,
                "elapsed": state.wall_time,
                "cpu_time": state.cpu_time,
                "max_height": max_height_at(self.cfg.terrain, terrain_env(self.env).episodes),
            }
        )
        self.tracker.log_metrics(state.frames, metrics)
        assert self.progress is not None  # opened before the first batch
        self.progress.update(batch.numel())
        info = {k: float(metrics[k]) for k in ("cpu_time", "elapsed", "env_steps", "max_height")}
        for minutes in take_snapshots(
            self.run_dir,
            self.cfg.snapshot_cpu_minutes,
            state.cpu_time,
            self.export_agent,
            {**info, "frames": float(state.frames)},
        ):
            self.progress.write(f"[{self.cfg.algo.name}] snapshot at {minutes} CPU minutes")

    def evaluate(self, actor: ProbabilisticActor) -> None:
        """Evaluate `actor` (see the module docstring) and log it; the next evaluation is due
        `budget.eval_every` frames on."""
        if self.obs_stats is not None:  # the evaluation env normalises as the training env
            eval_norm, train_norm = obs_norm_of(self.eval_env), obs_norm_of(self.env)
            assert eval_norm is not None and train_norm is not None  # both envs normalise
            eval_norm.load_state_dict(train_norm.state_dict())
        state = self.state
        state.last_eval = evaluate(
            self.eval_env,
            actor,
            self.cfg.budget.eval_episodes,
            self.seeds.eval,
            terrain_env(self.env).episodes,
            self.cfg.budget.episode_steps,
        )
        state.last_eval_frames = state.frames
        self.candidates.keep(state.frames, self.write_policy)
        state.best_score = max(state.best_score, state.last_eval["return_mean"])
        while state.next_eval <= state.frames:
            state.next_eval += cast(BaselineBudgetConfig, self.cfg.budget).eval_every
        metrics = {
            **{f"eval/{k}": v for k, v in state.last_eval.items()},
            "score": state.last_eval["return_mean"],
            "best_score": state.best_score,
        }
        if state.batches == 0:  # later evaluations follow a batch that logged the axes already
            metrics.update({"env_steps": state.frames, "elapsed": state.wall_time})
        self.tracker.log_metrics(state.frames, metrics)
        assert self.progress is not None  # opened before the first batch
        self.progress.write(
            f"[{self.cfg.algo.name}] frames={state.frames} eval return="
            f"{state.last_eval['return_mean']:.1f} "
            f"finish={state.last_eval['finish_rate']:.2f}"
        )

    def write_policy(self, path: Path) -> Path:
        """The actor as a policy file (epoet.rl.policy_file)."""
        assert self.actor is not None  # given to `start`
        return export_policy(path, self.actor, self.env, self.algo.hidden, self.algo.activation)

    def export_agent(self, folder: Path) -> None:
        """The policy the run exports into `folder` (`selection`: epoet.rl.candidates)."""
        self.write_policy(folder / POLICY_FILE)
        record = self.candidates.export(folder)
        assert self.progress is not None  # opened before the first batch
        self.progress.write(
            f"[{self.cfg.algo.name}] exports the policy of {record['exported']} (held-out "
            f"choice: {record.get('validation', 'none')}; {record['cpu_s']:.0f} CPU s)"
        )

    def checkpoint(self, learner: Learner) -> None:
        """Save the counters, `learner`, the normaliser and every random stream, and the policy
        beside them, so the run's agent evaluates mid-training."""
        save_run_state(
            self.run_dir,
            self.tracker,
            self.cfg,
            {
                "loop": dataclasses.asdict(self.state),
                "learner": learner.state_dict(),
                "obs_norm": None if self.obs_stats is None else self.obs_stats.state_dict(),
                "rng": rng_state(self.env),
                "seeds": dataclasses.asdict(self.seeds),
            },
        )
        self.write_policy(self.run_dir / POLICY_FILE)

    def finish(self, learner: Learner) -> TrainResult:
        """Log the last evaluation as `final/*`, checkpoint, export the policy, say why the run
        stopped."""
        self.tracker.log_metrics(
            self.state.frames, {f"final/{k}": v for k, v in self.state.last_eval.items()}
        )
        self.checkpoint(learner)
        self.export_agent(self.run_dir)
        policy_path = self.run_dir / POLICY_FILE
        self.tracker.log_artifact(policy_path)
        report_stop(
            self.tracker,
            self.cfg.algo.name,
            self.cfg.budget,
            self.out_of_time() if self.state.batches < self.plan.batches else None,
            self.state.frames,
            "frames",
            self.state.wall_time,
            self.state.cpu_time,
        )
        self.tracker.flush()
        return TrainResult(
            self.state.frames, self.state.batches, dict(self.state.last_eval), policy_path, learner
        )
