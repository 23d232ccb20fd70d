"""A baseline run's bookkeeping around its algorithm's loop: seeds and environments, counters,
metrics, evaluations, checkpoints and exact resume, the progress bar and the exported policy.

The algorithm (ppo.py, sac.py, vmpo.py) owns the loop and the update; `TrainingRun` is what each
step of that loop calls:

    with TrainingRun(cfg, tracker, run_dir, resume) as run:     # seeds, envs, counters
        ... build networks, loss, optimiser ...
        run.start(actor, learner)                               # restores a resumed run
        for batch in run.batches():                             # collect
            learned = learner.learn(batch)                      # learn
            run.log(batch, learned)                             # log
            run.evaluate_if_due(actor)                          # evaluate
            run.checkpoint_if_due(learner)                      # checkpoint
        return run.finish(actor, learner)

Checkpoints: every `cfg.checkpoint_every` collector batches and at the end. To make a resumed run
continue exactly like an uninterrupted one, a checkpoint ends the running episode: the collector
resets its env right after saving (and a resumed run resets right after loading), so no
mid-episode simulator state needs saving. The cut episode is not counted in the training episode
statistics; its transitions are still learned from.
"""
from __future__ import annotations

import dataclasses
import math
import random
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor
from tqdm import tqdm

from epoet.checkpoint import save_run_state
from epoet.config import Config
from epoet.lifecycle import raise_if_stopped, report_stop, stop_requested
from epoet.rl.policy_file import POLICY_FILE, export_policy
from epoet.rl.env import (OBS, RunningObsNorm, Seeds, episode_metrics, hexapod, make_env,
                          obs_norm_of)
from epoet.rl.setup import batch_plan, evaluate, make_collector, set_threads

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


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
    episodes: int = 0               # finished training episodes
    next_eval: int = 0              # frame count of the next evaluation
    last_eval_frames: int = -1
    last_eval: dict[str, float] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0          # seconds of training, summed over resumes
    best_score: float = -math.inf   # the best evaluation return so far


@dataclass
class TrainResult:
    """What a baseline runner returns."""

    frames: int
    batches: int
    final_eval: dict[str, float]
    policy_path: Path
    learner: Any


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


class TrainingRun:
    """Seeds, the training and evaluation envs, counters, tracking, checkpoints and progress of
    one baseline run. Metrics go to the tracker at step = frames: `train/*` (episode return and
    length, the learner's losses and diagnostics), `eval/*` (return_mean, return_std,
    length_mean, finish_rate), `score` (eval/return_mean) and `best_score` (its best so far),
    `frames`, `fps`, `time/batch`, and `final/*` (the last evaluation) at the end."""

    def __init__(self, cfg: Config, tracker: Tracker, run_dir: Path,
                 resume: dict[str, Any] | None) -> None:
        set_threads(cfg)
        self.cfg, self.tracker, self.run_dir, self.resume = cfg, tracker, run_dir, resume
        self.plan = batch_plan(cfg)
        self.seeds = Seeds.from_seed(cfg.seed)
        self.seeds.apply()
        # the envs before the networks: their construction draws from the seeded streams
        self.env = make_env(cfg, obs_norm=cfg.algo.obs_norm, seed=self.seeds.env)
        self.eval_env = make_env(cfg, obs_norm=cfg.algo.obs_norm, seed=self.seeds.eval)
        self.state = LoopState(**resume["loop"]) if resume is not None else LoopState()
        self.obs_stats = RunningObsNorm(obs_norm_of(self.env)) if cfg.algo.obs_norm else None
        self.collector: Collector | None = None
        self.progress: tqdm | None = None
        self._batch_start = 0.0
        if resume is None:
            tracker.log_dict(dataclasses.asdict(self.seeds), "seeds.json")

    def __enter__(self) -> TrainingRun:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if self.progress is not None:
            self.progress.close()
        if self.collector is not None:
            self.collector.shutdown()
        self.eval_env.close()

    # --- start ------------------------------------------------------------------------------------

    def start(self, actor: ProbabilisticActor, learner: Learner,
              init_random_frames: int = 0) -> None:
        """Make the collector of `actor`, restore a resumed run's state, evaluate at frame 0.

        `init_random_frames` (from the config, scaled to the batch) of uniform random actions
        come first; none are left after a resume that is past them.
        """
        random_frames = max(0, self.plan.scaled(init_random_frames) - self.state.frames)
        self.collector = make_collector(self.env, actor, self.plan, random_frames)
        if self.resume is not None:
            # After the collector's construction, which resets the env and may draw random
            # numbers; then a new episode starts exactly as the interrupted run's did right
            # after writing the checkpoint.
            learner.load_state_dict(self.resume["learner"])
            if self.obs_stats is not None:
                self.obs_stats.load_state_dict(self.resume["obs_norm"])
            _set_rng_state(self.env, self.resume["rng"])
            self.collector.reset()
        self.progress = tqdm(total=self.plan.total_frames, initial=self.state.frames,
                             unit="frame", desc=self.cfg.algo.name, disable=None,
                             dynamic_ncols=True)
        self.evaluate_if_due(actor)

    # --- the loop's steps -------------------------------------------------------------------------

    def batches(self) -> Iterator[TensorDictBase]:
        """Collector batches until the budget's frames are collected or its hours are used."""
        stream = iter(self.collector)
        while not self._done():
            self._batch_start = time.perf_counter()
            yield next(stream)

    def log(self, batch: TensorDictBase, learned: dict[str, float]) -> None:
        """Count the batch, update the observation statistics, send the batch's metrics.

        Stops the run on a non-finite learner metric rather than train on (and checkpoint)
        NaN weights.
        """
        broken = sorted(k for k, v in learned.items() if not math.isfinite(v))
        if broken:
            raise FloatingPointError(
                f"{self.cfg.algo.name} produced non-finite {broken} in the batch ending at "
                f"frame {self.state.frames + batch.numel()}.")
        metrics = {f"train/{k}": v for k, v in {**episode_metrics(batch), **learned}.items()}
        if self.obs_stats is not None:
            self.obs_stats.update(batch[OBS])
        elapsed = time.perf_counter() - self._batch_start
        state = self.state
        state.episodes += int(batch["next", "done"].sum())
        state.frames += batch.numel()
        state.batches += 1
        state.wall_time += elapsed
        # env_steps and elapsed are the x-axes every algorithm logs (ePOET too), so MLflow can
        # chart all algorithms against environment steps or training time.
        metrics.update({"frames": state.frames, "fps": batch.numel() / elapsed,
                        "time/batch": elapsed, "train/episodes": state.episodes,
                        "env_steps": state.frames, "elapsed": state.wall_time})
        self.tracker.log_metrics(state.frames, metrics)
        self.progress.update(batch.numel())

    def evaluate_if_due(self, actor: ProbabilisticActor) -> None:
        if self.state.frames < self.state.next_eval:
            return
        self._evaluate(actor)
        while self.state.next_eval <= self.state.frames:
            self.state.next_eval += self.cfg.budget.eval_every

    def checkpoint_if_due(self, learner: Learner) -> None:
        """Every `checkpoint_every` batches but the last (`finish` writes that one), and when a
        signal asked the run to stop."""
        if ((self.state.batches % self.cfg.checkpoint_every == 0 or stop_requested())
                and not self._done()):
            self._checkpoint(learner)
            raise_if_stopped(f"at frame {self.state.frames}")
            self.collector.reset()  # see the module docstring: checkpoints end the episode

    def finish(self, actor: ProbabilisticActor, learner: Learner) -> TrainResult:
        """Evaluate the final policy (unless just done), checkpoint, export the policy."""
        if self.state.last_eval_frames != self.state.frames:
            self._evaluate(actor)
        self.tracker.log_metrics(self.state.frames,
                                 {f"final/{k}": v for k, v in self.state.last_eval.items()})
        self._checkpoint(learner)
        policy_path = export_policy(self.run_dir / POLICY_FILE, actor, self.env,
                                    self.cfg.algo.hidden, self.cfg.algo.activation)
        self.tracker.log_artifact(policy_path)
        report_stop(self.tracker, self.cfg.algo.name, self.cfg.budget,
                    self.state.batches < self.plan.batches, self.state.frames, "frames",
                    self.state.wall_time)
        self.tracker.flush()
        return TrainResult(self.state.frames, self.state.batches, dict(self.state.last_eval),
                           policy_path, learner)

    # --- helpers ----------------------------------------------------------------------------------

    def _done(self) -> bool:
        return (self.state.batches >= self.plan.batches
                or self.cfg.budget.time_is_up(self.state.wall_time))

    def _evaluate(self, actor: ProbabilisticActor) -> None:
        if self.obs_stats is not None:  # the evaluation env normalises as the training env
            obs_norm_of(self.eval_env).load_state_dict(obs_norm_of(self.env).state_dict())
        state = self.state
        state.last_eval = evaluate(self.eval_env, actor, self.cfg.budget.eval_episodes,
                                   self.seeds.eval, hexapod(self.env).episodes,
                                   self.cfg.budget.episode_steps)
        state.last_eval_frames = state.frames
        state.best_score = max(state.best_score, state.last_eval["return_mean"])
        metrics = {**{f"eval/{k}": v for k, v in state.last_eval.items()},
                   "score": state.last_eval["return_mean"], "best_score": state.best_score}
        if state.batches == 0:  # later evaluations follow a batch that logged the axes already
            metrics.update({"env_steps": state.frames, "elapsed": state.wall_time})
        self.tracker.log_metrics(state.frames, metrics)
        self.progress.write(f"[{self.cfg.algo.name}] frames={state.frames} eval return="
                            f"{state.last_eval['return_mean']:.1f} "
                            f"finish={state.last_eval['finish_rate']:.2f}")

    def _checkpoint(self, learner: Learner) -> None:
        save_run_state(self.run_dir, self.tracker, self.cfg, {
            "loop": dataclasses.asdict(self.state), "learner": learner.state_dict(),
            "obs_norm": None if self.obs_stats is None else self.obs_stats.state_dict(),
            "rng": _rng_state(self.env), "seeds": dataclasses.asdict(self.seeds)})
