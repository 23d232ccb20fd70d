"""`algo=epoet` (and, with its loop, `algo=epoet_sac`): run the loop for the budget's iterations,
tracked and resumable."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

from epoet.config import Config
from epoet.rollout.policy import policy_sizes
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.evaluators import evaluator_for
from epoet.core.lifecycle import raise_if_stopped, stop_requested
from epoet.run_state import report_stop, save_run_state
from epoet.poet.loop import EPOET
from epoet.tracking import Tracker


def layer_sizes(cfg: Config) -> tuple[int, ...]:
    return policy_sizes(cfg.algo.es.hidden)


LoopFactory = Callable[..., EPOET]


def make_epoet(cfg: Config, evaluator: Evaluator, **poet: Any) -> EPOET:
    """The `algo=epoet` loop."""
    return EPOET(cfg.algo, cfg.terrain, evaluator, **poet)


def make_loop(cfg: Config, evaluator: Evaluator, factory: LoopFactory = make_epoet) -> EPOET:
    """`factory`'s loop over the pool, with the budget's sizes and schedule."""
    budget = cfg.budget
    return factory(cfg, evaluator, seed=cfg.seed, n_pairs=budget.n_pairs,
                   eval_episodes=budget.eval_episodes, score_scale=budget.score_scale,
                   layer_sizes=layer_sizes(cfg))


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None,
          factory: LoopFactory = make_epoet) -> EPOET:
    """Iterate until `budget.iterations`, checkpointing every `checkpoint_every` iterations
    (epoet.epoet_sac.runner passes its loop as `factory`)."""
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator:
        poet = make_loop(cfg, evaluator, factory)
        try:
            _iterate(poet, cfg, tracker, run_dir, resume)
        finally:
            poet.close()
    return poet


def _iterate(poet: EPOET, cfg: Config, tracker: Tracker, run_dir: Path,
             resume: dict[str, Any] | None) -> None:
    budget = cfg.budget
    if resume is not None:
        poet.load_state_dict(resume["poet"])
        print(f"[{cfg.algo.name}] resumed at iteration {poet.iteration}", flush=True)
    started = time.perf_counter()
    restarts = poet.evaluator.restarts

    def done() -> bool:
        return poet.iteration >= budget.iterations or budget.time_is_up(poet.elapsed)

    while not done():
        metrics = poet.iterate()
        if poet.evaluator.restarts > restarts:  # a worker died; the iteration ran unchanged
            metrics["workers/restarts"] = poet.evaluator.restarts - restarts
            restarts = poet.evaluator.restarts
        tracker.log_metrics(poet.iteration - 1, metrics)
        _progress(cfg.algo.name, poet, metrics, budget.iterations, time.perf_counter() - started)
        if poet.iteration % cfg.checkpoint_every == 0 or done() or stop_requested():
            save_run_state(run_dir, tracker, cfg, {"poet": poet.state_dict()})
            raise_if_stopped(f"after iteration {poet.iteration}")
    report_stop(tracker, cfg.algo.name, budget, poet.iteration < budget.iterations,
                poet.iteration, "iterations", poet.elapsed)
    poet.log_artifacts(run_dir, tracker, cfg.agent_choice)


EVENTS = ("admitted", "transfers", "joined", "replaced")  # shown when an iteration has them


def _progress(name: str, poet: EPOET, metrics: dict[str, float], total: int,
              elapsed: float) -> None:
    extra = "".join(f" {k}={int(metrics[k])}" for k in EVENTS if k in metrics)
    if "sac/score" in metrics:
        extra += f" sac_score={metrics['sac/score']:.1f}"
    if "join/mapped_score" in metrics:
        extra += (f" join: {poet.cfg.mapping} mapping scored {metrics['join/mapped_score']:.1f}"
                  f" vs the SAC actor's {metrics['join/sac_score']:.1f}")
    print(f"[{name}] it {poet.iteration}/{total} pairs={len(poet.active)} "
          f"archived={len(poet.archived)} score={metrics['score']:.1f} "
          f"best={metrics['best_score']:.1f} "
          f"annecs={poet.annecs} steps/s={metrics['steps_per_second']:,.0f} "
          f"elapsed={elapsed:.0f}s{extra}", flush=True)
