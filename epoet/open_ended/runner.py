"""`algo=epoet`: the loop's iterations for the budget, run by the driver (epoet/driver.py) as
every algorithm's run is; `EpoetRun` adapts any loop that extends ePOET's."""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

from epoet.config import Config, OpenEndedBudgetConfig
from epoet.core.algorithm import Family
from epoet.driver import Counters, Logged, drive
from epoet.open_ended.config import EpoetConfig
from epoet.open_ended.exported_agent import export_agent
from epoet.open_ended.loop import Epoet
from epoet.rollout.evaluators import evaluator_for
from epoet.rollout.policy import policy_sizes
from epoet.terrain import max_height_at
from epoet.tracking import Tracker


def layer_sizes(cfg: Config) -> tuple[int, ...]:
    """The ES policy's sizes, derived here only: the evaluator takes them, the loop (its
    service) reads them from it."""
    return policy_sizes(cfg.agent, EpoetConfig.of(cfg).es.hidden)


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None) -> Epoet:
    """Train ePOET for the budget's iterations (or hours)."""
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator:
        loop = Epoet.from_config(cfg, evaluator)
        drive(EpoetRun(loop, cfg, resume), cfg, tracker, run_dir, resumed=resume is not None)
    return loop


class EpoetRun:
    """An open-ended loop as the driver's `Trainable`: a step is an iteration; the agents are
    the pool's, and the run exports the one `selection` picks among them."""

    unit = Family.OPEN_ENDED.counts

    def __init__(self, loop: Epoet, cfg: Config, resume: dict[str, Any] | None) -> None:
        self.loop, self.cfg = loop, cfg
        self.name = cfg.algo.name
        self.total = cast(OpenEndedBudgetConfig, cfg.budget).iterations  # the family's
        self.cpu_meter = loop.cpu_meter
        self.evaluator = loop.service.evaluator
        self.restarts = self.evaluator.restarts
        if resume is not None:
            loop.load_state_dict(resume["open_ended"])

    def counters(self) -> Counters:
        loop = self.loop
        return Counters(
            loop.iteration,
            loop.iteration,
            loop.service.env_steps,
            loop.elapsed,
            loop.cpu_time,
            loop.best_score,
        )

    def begin(self) -> Logged | None:
        return None  # the pool is scored by its first iteration

    def step(self) -> Logged:
        """One iteration of the loop, and a line of progress."""
        metrics = self.loop.run_iteration()
        if self.evaluator.restarts > self.restarts:  # a worker died; the iteration ran unchanged
            metrics["workers/restarts"] = self.evaluator.restarts - self.restarts
            self.restarts = self.evaluator.restarts
        self.progress(metrics)
        return Logged(self.loop.iteration - 1, metrics, self.loop.score)

    def end(self) -> Logged | None:
        return None

    def add_cpu_time(self, seconds: float) -> None:
        self.loop.cpu_time += seconds

    def snapshot_info(self) -> dict[str, float]:
        """The iteration (pipeline/choose.py reads it) and the terrains' height it trained at."""
        last = self.loop.iteration - 1
        return {
            "max_height": max_height_at(self.cfg.terrain, last),
            "iteration": self.loop.iteration,
        }

    def state_dict(self) -> dict[str, Any]:
        return {"open_ended": self.loop.state_dict()}

    def save_agents(self, folder: Path) -> None:
        self.loop.save_agents(folder, self.cfg.agent_choice)

    def export(self, folder: Path) -> dict[str, Any]:
        """The pool's agents and the one the run exports (`selection`)."""
        self.save_agents(folder)
        return export_agent(self.loop, folder, self.cfg)

    def after_checkpoint(self) -> None:
        pass  # an iteration ends with no episode running

    def artifacts(self, run_dir: Path) -> list[tuple[Path, str | None]]:
        return self.loop.artifacts(run_dir, self.cfg.agent_choice)

    def say(self, line: str) -> None:
        print(f"[{self.name}] {line}", flush=True)

    def progress(self, metrics: dict[str, float]) -> None:
        loop = self.loop
        self.say(
            f"it {loop.iteration}/{self.total} "
            f"pairs={int(metrics['active_envs'])} archived={int(metrics['archived_envs'])} "
            f"score={loop.score:.1f} best={loop.best_score:.1f} "
            f"annecs={int(metrics['annecs'])} S={metrics['max_height']:.2f} "
            f"steps/s={metrics['steps_per_second']:,.0f} elapsed={loop.elapsed:.0f}s "
            f"cpu={loop.cpu_time / 60:.1f}min{loop.progress(metrics)}"
        )
