"""A baseline's run: PPO, SAC and VMPO each give it a learner (epoet/{ppo,sac,vmpo}/train.py), and
the driver (epoet/driver.py) runs it as it runs every algorithm. One driver step here:

    collect     a batch of `frames_per_batch` frames from the stochastic actor
    learn       the algorithm's update on the batch
    normalise   the observation statistics, after learning: one update per batch
    count       frames, batches, episodes, wall and CPU time; the batch's metrics
    evaluate    every `budget.eval_every` frames (and at frame 0 and the end)

The driver snapshots, checkpoints, stops and exports around these steps.

Checkpoints (the driver's: every `cfg.checkpoint_every` collector batches and at the end): to
make a resumed run continue exactly like an uninterrupted one, a checkpoint ends the running
episode: the collector resets its env right after saving (and a resumed run resets right after
loading), so no mid-episode simulator state needs saving. The cut episode is not counted in the training episode
statistics; its transitions are still learned from.

Evaluation (the paper's tables do not fix it): `budget.eval_episodes` episodes of the
deterministic policy on a separate env whose terrains come from a fixed seed, at the training
env's current point of the height schedule. It runs under `fork_rng`, so it never changes the
training's random streams. Each evaluation point's policy is kept (candidates.py), and the
exported policy is chosen among them at snapshots and at the end (`selection`).

Metrics go to the tracker at step = frames: `train/*` (episode return and length, the learner's
losses and diagnostics), `eval/*` (return_mean, return_std, length_mean, finish_rate), `score`
(eval/return_mean) and `best_score` (its best so far) and the axes (the driver adds them from
the counters: epoet/core/algorithm.py), `frames`, `fps`, `time/batch`, and `final/*` (the last
evaluation) at the end.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from contextlib import closing
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, cast

from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.modules import ProbabilisticActor
from tqdm import tqdm

from epoet.config import BaselineBudgetConfig, Config
from epoet.core.clock import CpuMeter
from epoet.driver import Counters, Logged, drive
from epoet.rl.candidates import Candidates
from epoet.rl.env import (
    OBS,
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
from epoet.rl.harness import (
    BatchPlan,
    LoopState,
    TrainResult,
    baseline,
    batch_plan,
    make_collector,
    set_threads,
)
from epoet.rl.policy_file import POLICY_FILE, export_policy
from epoet.terrain import max_height_at

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


class Learner(Protocol):
    """What an algorithm gives a baseline's run: its policy, its update on a collector batch, and its
    state (networks, optimisers, learned multipliers, the replay buffer), all a resume needs."""

    actor: ProbabilisticActor  # stochastic: collects; deterministic: is evaluated and exported
    random_frames: int  # uniform random actions before the actor acts (SAC); 0: none

    def learn(self, batch: TensorDictBase) -> dict[str, float]:
        """Learn from one collector batch; the metrics to log (without `train/`)."""
        ...

    def artifacts(self, run_dir: Path) -> list[Path]:
        """Files the algorithm writes beside the policy at the end (SAC: its critics)."""
        ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: dict[str, Any]) -> None: ...


def train(
    cfg: Config,
    tracker: Tracker,
    run_dir: Path,
    resume: dict[str, Any] | None,
    make_learner: Callable[[EnvBase, BatchPlan], Learner],
) -> TrainResult:
    """A baseline's run: `make_learner(env, plan)` builds the algorithm on the training env,
    and the driver (epoet/driver.py) runs it to the end of the budget."""
    with closing(BaselineRun(cfg, tracker, run_dir, resume)) as run:  # seeds, envs, counters
        learner = make_learner(run.env, run.plan)  # after the envs: both draw seeded numbers
        random_frames = max(0, learner.random_frames - run.state.frames)  # none left past them
        run.start(make_collector(run.env, learner.actor, run.plan, random_frames), learner)
        drive(run, cfg, tracker, run_dir, resumed=resume is not None)
        state = run.state
        return TrainResult(
            state.frames, state.batches, dict(state.last_eval), run_dir / POLICY_FILE, learner
        )


class BaselineRun:
    """One baseline run as the driver's `Trainable`: its seeds, envs, counters, learner and
    progress bar; each driver step collects a batch, learns from it and evaluates when due."""

    unit = "frames"

    def __init__(
        self, cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
    ) -> None:
        set_threads(cfg)
        self.cfg, self.tracker, self.run_dir, self.resume = cfg, tracker, run_dir, resume
        self.name = cfg.algo.name
        self.plan = batch_plan(cfg)
        self.total = self.plan.total_frames  # whole batches: the first multiple at or above
        self.seeds = Seeds.from_seed(cfg.seed)
        self.seeds.apply()
        # the envs before the networks: their construction draws from the seeded streams
        self.algo = baseline(cfg)
        self.env = make_env(cfg, obs_norm=self.algo.obs_norm, seed=self.seeds.env)
        self.eval_env = make_env(cfg, obs_norm=self.algo.obs_norm, seed=self.seeds.eval)
        self.state = LoopState(**resume["loop"]) if resume is not None else LoopState()
        self.obs_stats = RunningObsNorm(obs_norm_of(self.env)) if self.algo.obs_norm else None
        self.collector: Collector | None = None
        self.batches: Iterator[TensorDictBase] | None = None
        self.learner: Learner | None = None
        self.progress: tqdm | None = None
        self.cpu_meter = CpuMeter()
        self.candidates = Candidates(cfg, run_dir)  # the policies it may export (`selection`)
        if resume is None:
            tracker.log_dict(dataclasses.asdict(self.seeds), "seeds.json")

    def close(self) -> None:
        """Close the progress bar, the collector and the evaluation env (the run ended or
        failed)."""
        if self.progress is not None:
            self.progress.close()
        if self.collector is not None:
            self.collector.shutdown()
        self.eval_env.close()

    @property
    def actor(self) -> ProbabilisticActor:
        assert self.learner is not None  # given to `start`
        return self.learner.actor

    def start(self, collector: Collector, learner: Learner) -> None:
        """Restore a resumed run's state and open the progress bar; the run shuts `collector`
        down when it exits and exports the learner's actor."""
        self.collector, self.learner = collector, learner
        if self.resume is not None:
            # After the collector's construction, which resets the env and may draw random
            # numbers; then a new episode starts exactly as the interrupted run's did right
            # after writing the checkpoint.
            learner.load_state_dict(self.resume["learner"])
            if self.obs_stats is not None:
                self.obs_stats.load_state_dict(self.resume["obs_norm"])
            set_rng_state(self.env, self.resume["rng"])
            collector.reset()
        self.batches = iter(collector)
        self.progress = tqdm(
            total=self.plan.total_frames,
            initial=self.state.frames,
            unit="frame",
            desc=self.cfg.algo.name,
            disable=None,
            dynamic_ncols=True,
        )

    # --- the driver's steps -----------------------------------------------------------------

    def counters(self) -> Counters:
        state = self.state
        return Counters(
            state.batches,
            state.frames,
            state.frames,
            state.wall_time,
            state.cpu_time,
            state.best_score,
        )

    def begin(self) -> Logged | None:
        """The evaluation at frame 0 (a resumed run has its evaluations already)."""
        return self.evaluate() if self.state.frames >= self.state.next_eval else None

    def step(self) -> Logged:
        """Collect a batch, learn from it, normalise, count it; evaluate when due."""
        assert self.batches is not None and self.learner is not None  # given to `start`
        started = time.perf_counter()
        batch = next(self.batches)  # collect
        learned = self.learner.learn(batch)  # learn
        if self.obs_stats is not None:  # normalise: after learning, one update per batch
            self.obs_stats.update(batch[OBS])
        metrics = self.count(batch, learned, started)
        if self.state.frames < self.state.next_eval:
            return Logged(self.state.frames, metrics)
        evaluated = self.evaluate()  # evaluate
        return Logged(self.state.frames, {**metrics, **evaluated.metrics}, evaluated.score)

    def end(self) -> Logged | None:
        """The final policy's evaluation (unless just evaluated), also logged as `final/*`."""
        state = self.state
        logged = self.evaluate() if state.last_eval_frames != state.frames else None
        final = {f"final/{k}": v for k, v in state.last_eval.items()}
        if logged is None:
            return Logged(state.frames, final)
        return Logged(state.frames, {**logged.metrics, **final}, logged.score)

    def count(
        self, batch: TensorDictBase, learned: dict[str, float], started: float
    ) -> dict[str, float]:
        """Count the batch (collected from time.perf_counter() = `started` on); its metrics.

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
        assert self.progress is not None  # opened before the first batch
        self.progress.update(batch.numel())
        return {
            **metrics,
            "frames": state.frames,
            "fps": batch.numel() / elapsed,
            "time/batch": elapsed,
            "train/episodes": state.episodes,
            "max_height": self.max_height(),
        }

    def max_height(self) -> float:
        """The training terrains' maximum height S now (the height schedule's point)."""
        return max_height_at(self.cfg.terrain, terrain_env(self.env).episodes)

    def evaluate(self) -> Logged:
        """Evaluate the actor (see the module docstring) and keep it as a candidate; the next
        evaluation is due `budget.eval_every` frames on."""
        if self.obs_stats is not None:  # the evaluation env normalises as the training env
            eval_norm, train_norm = obs_norm_of(self.eval_env), obs_norm_of(self.env)
            assert eval_norm is not None and train_norm is not None  # both envs normalise
            eval_norm.load_state_dict(train_norm.state_dict())
        state = self.state
        state.last_eval = evaluate(
            self.eval_env,
            self.actor,
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
        self.say(
            f"frames={state.frames} eval return={state.last_eval['return_mean']:.1f} "
            f"finish={state.last_eval['finish_rate']:.2f}"
        )
        metrics = {f"eval/{k}": v for k, v in state.last_eval.items()}
        return Logged(state.frames, metrics, state.last_eval["return_mean"])

    def add_cpu_time(self, seconds: float) -> None:
        self.state.cpu_time += seconds

    def snapshot_info(self) -> dict[str, float]:
        return {"max_height": self.max_height(), "frames": float(self.state.frames)}

    # --- checkpoints ------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """The counters, the learner, the normaliser and every random stream."""
        assert self.learner is not None  # given to `start`
        return {
            "loop": dataclasses.asdict(self.state),
            "learner": self.learner.state_dict(),
            "obs_norm": None if self.obs_stats is None else self.obs_stats.state_dict(),
            "rng": rng_state(self.env),
            "seeds": dataclasses.asdict(self.seeds),
        }

    def save_agents(self, folder: Path) -> None:
        """The policy beside the checkpoint, so the run's agent evaluates mid-training."""
        self.write_policy(folder / POLICY_FILE)

    def after_checkpoint(self) -> None:
        """Checkpoints end the running episode (module docstring)."""
        assert self.collector is not None  # given to `start`
        self.collector.reset()

    def artifacts(self, run_dir: Path) -> list[tuple[Path, str | None]]:
        """The exported policy and the learner's own files (SAC: its critics)."""
        assert self.learner is not None  # given to `start`
        paths = [run_dir / POLICY_FILE, *self.learner.artifacts(run_dir)]
        return [(path, None) for path in paths]

    # --- the exported policy ----------------------------------------------------------------

    def write_policy(self, path: Path) -> Path:
        """The actor as a policy file (epoet.rl.policy_file)."""
        return export_policy(path, self.actor, self.env, self.algo.hidden, self.algo.activation)

    def export(self, folder: Path) -> dict[str, Any]:
        """The policy the run exports into `folder` (`selection`: epoet.rl.candidates)."""
        self.write_policy(folder / POLICY_FILE)
        return self.candidates.export(folder)

    def say(self, line: str) -> None:
        """A line above the progress bar, prefixed with the algorithm's name."""
        assert self.progress is not None  # opened before the first batch
        self.progress.write(f"[{self.cfg.algo.name}] {line}")
