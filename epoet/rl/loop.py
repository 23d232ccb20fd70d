"""The baselines' training loop: PPO, SAC and VMPO each give it a learner (ppo.py, sac.py,
vmpo.py) and it does the rest, read top to bottom in `train`:

    set up      threads, seeds, the training and evaluation envs, the counters (a resume's)
    collect     a batch of `frames_per_batch` frames from the stochastic actor
    learn       the algorithm's update on the batch
    normalise   the observation statistics, after learning: one update per batch
    log         counters and metrics; the policy at each `snapshot_cpu_minutes` mark
    evaluate    every `budget.eval_every` frames (and at frame 0 and the end)
    checkpoint  every `checkpoint_every` batches; a stop signal ends the run there
    stop        when the budget's frames are collected or its hours or CPU hours are used
    finish      the last evaluation, checkpoint and exported policy; why the run stopped

Checkpoints: every `cfg.checkpoint_every` collector batches and at the end. To make a resumed run
continue exactly like an uninterrupted one, a checkpoint ends the running episode: the collector
resets its env right after saving (and a resumed run resets right after loading), so no
mid-episode simulator state needs saving. The cut episode is not counted in the training episode
statistics; its transitions are still learned from.

Evaluation (the paper's tables do not fix it): `budget.eval_episodes` episodes of the
deterministic policy on a separate env whose terrains come from a fixed seed, at the training
env's current point of the height schedule. It runs under `fork_rng`, so it never changes the
training's random streams. Each evaluation point's policy is kept (candidates.py), and the
exported policy is chosen among them at snapshots and at the end (`selection`).

Metrics go to the tracker at step = frames: `train/*` (episode return and length, the learner's
losses and diagnostics), `eval/*` (return_mean, return_std, length_mean, finish_rate), `score`
(eval/return_mean) and `best_score` (its best so far), the axes `env_steps`, `elapsed` and
`cpu_time` (the baselines family's metrics: epoet/core/algorithm.py), `frames`, `fps`,
`time/batch`, and `final/*` (the last evaluation) at the end.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
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
from epoet.core.lifecycle import raise_if_stopped, stop_requested
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
from epoet.run_state import report_stop, save_run_state, take_snapshots
from epoet.terrain import max_height_at

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


class Learner(Protocol):
    """What an algorithm gives the loop: its policy, its update on a collector batch, and its
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
    """A baseline's run: `make_learner(env, plan)` builds the algorithm on the training env."""
    with closing(BaselineRun(cfg, tracker, run_dir, resume)) as run:  # seeds, envs, counters
        learner = make_learner(run.env, run.plan)  # after the envs: both draw seeded numbers
        state = run.state
        random_frames = max(0, learner.random_frames - state.frames)  # none left past them
        collector = make_collector(run.env, learner.actor, run.plan, random_frames)
        run.start(collector, learner)  # a resumed run continues from its checkpoint

        if state.frames >= state.next_eval:  # frame 0
            run.evaluate()
        batches = iter(collector)
        while not run.budget_spent():  # budget.frames, budget.hours or budget.cpu_hours
            started = time.perf_counter()
            batch = next(batches)  # collect
            learned = learner.learn(batch)  # learn
            if run.obs_stats is not None:  # normalise: after learning, one update per batch
                run.obs_stats.update(batch[OBS])
            run.log(batch, learned, started)  # log
            run.snapshot()  # the exported policy at each CPU-time mark
            if state.frames >= state.next_eval:  # evaluate
                run.evaluate()
            if run.checkpoint_due():  # checkpoint
                run.checkpoint()
                raise_if_stopped(f"at frame {state.frames}")  # a stop signal ends the run here
                collector.reset()  # checkpoints end the running episode (module docstring)
        if state.last_eval_frames != state.frames:  # the final policy, unless just evaluated
            run.evaluate()
        for path in learner.artifacts(run_dir):
            tracker.log_artifact(path)
        return run.finish()


class BaselineRun:
    """One baseline run's seeds, envs, counters, tracking, checkpoints and progress: the steps
    `train` calls, in the order it calls them."""

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
        metrics.update(
            {
                "frames": state.frames,
                "fps": batch.numel() / elapsed,
                "time/batch": elapsed,
                "train/episodes": state.episodes,
                **self.axes(),
                "max_height": self.max_height(),
            }
        )
        self.tracker.log_metrics(state.frames, metrics)
        assert self.progress is not None  # opened before the first batch
        self.progress.update(batch.numel())

    def axes(self) -> dict[str, float]:
        """The x-axes every algorithm logs (ePOET too), so figures and MLflow can chart all
        algorithms against environment steps, training time or CPU time."""
        state = self.state
        return {"env_steps": state.frames, "elapsed": state.wall_time, "cpu_time": state.cpu_time}

    def max_height(self) -> float:
        """The training terrains' maximum height S now (the height schedule's point)."""
        return max_height_at(self.cfg.terrain, terrain_env(self.env).episodes)

    def snapshot(self) -> None:
        """Export the policy once for each `snapshot_cpu_minutes` mark the run has passed."""
        info = {**self.axes(), "max_height": self.max_height(), "frames": self.state.frames}
        saved, spent = take_snapshots(
            self.run_dir,
            self.cfg.snapshot_cpu_minutes,
            self.state.cpu_time,
            self.export_agent,
            {k: float(v) for k, v in info.items()},
            self.cpu_meter,
        )
        self.state.cpu_time += spent  # the choice's CPU, before the checkpoint that may end the run
        for minutes in saved:
            self.write(f"snapshot at {minutes} CPU minutes")

    def evaluate(self) -> None:
        """Evaluate the actor (see the module docstring), keep it as a candidate and log it;
        the next evaluation is due `budget.eval_every` frames on."""
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
        metrics = {
            **{f"eval/{k}": v for k, v in state.last_eval.items()},
            "score": state.last_eval["return_mean"],
            "best_score": state.best_score,
        }
        if state.batches == 0:  # later evaluations follow a batch that logged the axes already
            metrics.update(self.axes())
        self.tracker.log_metrics(state.frames, metrics)
        self.write(
            f"frames={state.frames} eval return={state.last_eval['return_mean']:.1f} "
            f"finish={state.last_eval['finish_rate']:.2f}"
        )

    def checkpoint_due(self) -> bool:
        """Every `checkpoint_every` batches but the last (`finish` writes that one), and when a
        signal asked the run to stop."""
        return (
            self.state.batches % self.cfg.checkpoint_every == 0 or stop_requested()
        ) and not self.budget_spent()

    def checkpoint(self) -> None:
        """Save the counters, the learner, the normaliser and every random stream, and the
        policy beside them, so the run's agent evaluates mid-training."""
        assert self.learner is not None  # given to `start`
        save_run_state(
            self.run_dir,
            self.tracker,
            self.cfg,
            {
                "loop": dataclasses.asdict(self.state),
                "learner": self.learner.state_dict(),
                "obs_norm": None if self.obs_stats is None else self.obs_stats.state_dict(),
                "rng": rng_state(self.env),
                "seeds": dataclasses.asdict(self.seeds),
            },
        )
        self.write_policy(self.run_dir / POLICY_FILE)

    def finish(self) -> TrainResult:
        """Log the last evaluation as `final/*`, checkpoint, export the policy, say why the run
        stopped."""
        self.tracker.log_metrics(
            self.state.frames, {f"final/{k}": v for k, v in self.state.last_eval.items()}
        )
        self.checkpoint()
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
        state = self.state
        return TrainResult(
            state.frames, state.batches, dict(state.last_eval), policy_path, self.learner
        )

    # --- the exported policy ----------------------------------------------------------------

    def write_policy(self, path: Path) -> Path:
        """The actor as a policy file (epoet.rl.policy_file)."""
        return export_policy(path, self.actor, self.env, self.algo.hidden, self.algo.activation)

    def export_agent(self, folder: Path) -> None:
        """The policy the run exports into `folder` (`selection`: epoet.rl.candidates)."""
        self.write_policy(folder / POLICY_FILE)
        record = self.candidates.export(folder)
        self.write(
            f"exports the policy of {record['exported']} (held-out choice: "
            f"{record.get('validation', 'none')}; {record['cpu_s']:.0f} CPU s)"
        )

    def write(self, line: str) -> None:
        """A line above the progress bar, prefixed with the algorithm's name."""
        assert self.progress is not None  # opened before the first batch
        self.progress.write(f"[{self.cfg.algo.name}] {line}")
