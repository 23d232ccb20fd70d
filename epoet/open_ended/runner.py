"""`algo=epoet`: the loop's iterations for the budget, tracked and resumable (`train_loop` runs
them for any loop that extends ePOET's)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, cast

from epoet.config import Config, OpenEndedBudgetConfig
from epoet.core.lifecycle import raise_if_stopped, stop_requested
from epoet.open_ended.config import EpoetConfig
from epoet.open_ended.exported_agent import export_agent
from epoet.open_ended.loop import Epoet
from epoet.rollout.evaluators import evaluator_for
from epoet.rollout.policy import policy_sizes
from epoet.run_state import report_stop, save_run_state, take_snapshots
from epoet.tracking import Tracker


def layer_sizes(cfg: Config) -> tuple[int, ...]:
    """The ES policy's sizes, derived here only: the evaluator takes them, the loop (its
    service) reads them from it."""
    return policy_sizes(cfg.agent, EpoetConfig.of(cfg).es.hidden)


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None) -> Epoet:
    """Train ePOET for the budget's iterations (or hours)."""
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator:
        loop = Epoet.from_config(cfg, evaluator)
        train_loop(loop, cfg, tracker, run_dir, resume)
    return loop


def train_loop(
    loop: Epoet, cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
) -> None:
    """Run `loop`'s iterations until `budget.iterations` (or `budget.hours`, `budget.cpu_hours`),
    logging each one's metrics, saving the pool's agents at each CPU-time mark of
    `snapshot_cpu_minutes`, and checkpointing (with the pool's agents, so a run evaluates
    mid-training) every `checkpoint_every` iterations, at the end and on a stop signal; then tag
    why it stopped and log the pool's artifacts."""
    budget = cast(OpenEndedBudgetConfig, cfg.budget)  # ePOET's YAML picks the ePOET family's
    if resume is not None:
        loop.load_state_dict(resume["open_ended"])
        print(f"[{cfg.algo.name}] resumed at iteration {loop.iteration}", flush=True)
    started = time.perf_counter()
    evaluator = loop.service.evaluator
    restarts = evaluator.restarts

    def done() -> bool:
        return loop.iteration >= budget.iterations or out_of_time() is not None

    def out_of_time() -> str | None:
        return budget.time_is_up(loop.elapsed, loop.cpu_time)

    def save_agents(folder: Path) -> Path:
        return loop.save_agents(folder, cfg.agent_choice)

    def export(folder: Path) -> None:
        """The pool's agents and the one the run exports (`selection`)."""
        save_agents(folder)
        record = export_agent(loop, folder, cfg)
        print(
            f"[{cfg.algo.name}] exports {record['exported']} (held-out choice: "
            f"{record.get('validation', 'none')}, own-terrain choice: {record['own']}; "
            f"{record['cpu_s']:.0f} CPU s)",
            flush=True,
        )

    while not done():
        metrics = loop.run_iteration()
        if evaluator.restarts > restarts:  # a worker died; the iteration ran unchanged
            metrics["workers/restarts"] = evaluator.restarts - restarts
            restarts = evaluator.restarts
        tracker.log_metrics(loop.iteration - 1, metrics)
        _progress(cfg, loop, metrics, time.perf_counter() - started)
        info = {k: metrics[k] for k in ("cpu_time", "elapsed", "env_steps", "max_height")}
        saved, spent = take_snapshots(
            run_dir,
            cfg.snapshot_cpu_minutes,
            loop.cpu_time,
            export,
            {**info, "iteration": loop.iteration},
            loop.cpu_meter,
        )
        loop.cpu_time += spent  # the choice's CPU, before the checkpoint that may end the run
        for minutes in saved:
            print(f"[{cfg.algo.name}] snapshot of the pool at {minutes} CPU minutes", flush=True)
        if loop.iteration % cfg.checkpoint_every == 0 or done() or stop_requested():
            save_run_state(run_dir, tracker, cfg, {"open_ended": loop.state_dict()})
            save_agents(run_dir)
            raise_if_stopped(f"after iteration {loop.iteration}")
    report_stop(
        tracker,
        cfg.algo.name,
        budget,
        out_of_time() if loop.iteration < budget.iterations else None,
        loop.iteration,
        "iterations",
        loop.elapsed,
        loop.cpu_time,
    )
    export(run_dir)
    loop.log_artifacts(run_dir, tracker, cfg.agent_choice)


def _progress(cfg: Config, loop: Epoet, metrics: dict[str, float], elapsed: float) -> None:
    iterations = cast(OpenEndedBudgetConfig, cfg.budget).iterations
    print(
        f"[{cfg.algo.name}] it {loop.iteration}/{iterations} "
        f"pairs={int(metrics['active_envs'])} archived={int(metrics['archived_envs'])} "
        f"score={metrics['score']:.1f} best={metrics['best_score']:.1f} "
        f"annecs={int(metrics['annecs'])} S={metrics['max_height']:.2f} "
        f"steps/s={metrics['steps_per_second']:,.0f} elapsed={elapsed:.0f}s "
        f"cpu={metrics['cpu_time'] / 60:.1f}min{loop.progress(metrics)}",
        flush=True,
    )
