"""The ePOET loop (paper Algorithm 1; docs/reference.md).

`Epoet.run_iteration` is one iteration, as Enhanced POET's `optimize()` runs each of its own:
its `steps`, each run when it is due and timed under its name:
1. `reproduce`, every `reproduce_interval` iterations (reproduction.py): eligible parents
   propose mutated children, the minimal criterion filters them, and the most novel are
   admitted with the best agent;
2. `optimize`: every active pair takes one ES step on its environment (`es_step`) and is
   evaluated (`evaluate_pairs`);
3. `transfer`, every `transfer_interval` iterations (transfer.py): agents move between
   environments.
A loop that extends ePOET's (a subclass) adds steps to that list and overrides a step, the
lineage its pairs are counted in, or what its iterations report.

The pool (pairs.py) holds the pairs; the service (service.py) gives every step its keyed seeds,
terrains and episodes, one call to the workers per step. A run of iterations, with checkpoints
and the budget's end, is the driver's (epoet/driver.py; runner.py `EpoetRun` adapts the loop).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple, cast

import numpy as np

from epoet.core.clock import CpuMeter
from epoet.core.timing import PhaseTimer
from epoet.open_ended.config import EpoetConfig
from epoet.open_ended.keys import Key
from epoet.open_ended.pairs import Environment, Pair, Pool, Thresholds, annecs, best_by_lineage
from epoet.open_ended.reproduction import reproduce
from epoet.open_ended.service import Service
from epoet.open_ended.transfer import transfer
from epoet.rollout.agent_files import ES_POLICIES, write_es_policy
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.engine import Episodes
from epoet.rollout.policy import init_params
from epoet.terrain import max_height_at
from epoet.terrain.config import TerrainConfig

if TYPE_CHECKING:
    from epoet.config import Config, OpenEndedBudgetConfig


class Step(NamedTuple):
    """A step of an iteration: its name (its time is `time/<name>`), whether it is due at
    iteration t, and what it does at t (returning its metrics)."""

    name: str
    due: Callable[[int], bool]
    run: Callable[[int], dict[str, float]]


def every_iteration(t: int) -> bool:
    return True


class Epoet:
    """The pool of environment-agent pairs and the three steps that change it."""

    EVENTS: tuple[str, ...] = (
        "admitted",
        "transfers",
    )  # counts the progress line shows when an iteration has them

    def __init__(
        self,
        algo: EpoetConfig,
        terrain: TerrainConfig,
        evaluator: Evaluator,
        *,
        seed: int,
        n_pairs: int,
        eval_episodes: int,
        score_scale: float,
    ) -> None:
        self.cfg = algo
        self.service = Service(
            evaluator,
            terrain,
            algo.es,
            seed=seed,
            n_pairs=n_pairs,
            eval_episodes=eval_episodes,
        )
        self.pool = Pool(
            algo.max_num_envs,
            Thresholds(
                algo.mc_lower * score_scale,
                algo.mc_upper * score_scale,
                algo.repro_threshold * score_scale,
            ),
            self.service.policy,
        )
        every = algo.iterations_before_transfer
        self.transfer_interval = every
        self.reproduce_interval = algo.adjust_interval * every
        self.later_reproduce_interval = algo.later_adjust_interval * every
        self.iteration = 0
        self.transfers = 0
        self.elapsed = 0.0  # seconds of iterations, summed over resumes
        self.cpu_time = 0.0  # CPU seconds of the run's processes, summed over resumes
        self.cpu_meter = CpuMeter()
        self.score = -np.inf  # the last iteration's best active pair's evaluation: its `score`
        self.best_score = -np.inf  # the best `score` of any iteration so far
        service = self.service
        root = Environment(
            index=0,
            genome=service.root_genome(service.seed(Key.ROOT_GENOME, 0)),
            generation=0,
            parent=None,
            created_at=0,
        )
        self.pool.admit(
            root,
            service.optimizer_for(
                root, init_params(service.seed(Key.ROOT_AGENT, 0), service.layer_sizes)
            ),
        )

    @classmethod
    def from_config(cls, cfg: Config, evaluator: Evaluator) -> Epoet:
        """The `algo=epoet` loop of a run."""
        return cls(EpoetConfig.of(cfg), cfg.terrain, evaluator, **loop_settings(cfg))

    # --- one iteration ----------------------------------------------------------------------
    def run_iteration(self) -> dict[str, float]:
        """Run iteration `self.iteration` and return its metrics (`time/<step>`: where its wall
        time went); its `score` and the counters are the loop's attributes."""
        t, timer, start = self.iteration, PhaseTimer(), self.start_iteration()
        metrics: dict[str, float] = {}
        for step in self.steps():
            if step.due(t):
                with timer(step.name):
                    metrics.update(step.run(t))
        return self.end_iteration(metrics, timer, start)

    def steps(self) -> list[Step]:
        """The steps of an iteration, in order."""
        return [
            Step("reproduce", self.reproduce_due, self.reproduce_step),
            Step("optimize", every_iteration, self.optimize),
            Step("transfer", self.transfer_due, self.transfer_step),
        ]

    def reproduce_step(self, t: int) -> dict[str, float]:
        return {"admitted": float(self.reproduce(t))}

    def optimize(self, t: int) -> dict[str, float]:
        """Every active pair's ES step, then its evaluation."""
        metrics = self.es_step(t)[0]
        metrics.update(self.evaluate_pairs(t))
        return metrics

    def transfer_step(self, t: int) -> dict[str, float]:
        return {"transfers": float(self.transfer(t))}

    def reproduce_due(self, t: int) -> bool:
        """At the first interval, then every later interval (the reference: 75, then every 15;
        the paper: every 75)."""
        first = self.reproduce_interval
        return t > 0 and t % (first if t <= first else self.later_reproduce_interval) == 0

    def transfer_due(self, t: int) -> bool:
        return len(self.pool.active) > 1 and t % self.transfer_interval == 0

    def reproduce(self, t: int) -> int:
        """The reproduce step (reproduction.py); returns the children admitted."""
        return reproduce(self.pool, self.service, self.cfg, t)

    def es_step(self, t: int, record: int = 0) -> tuple[dict[str, float], list[Episodes]]:
        """One ES step of every active pair; the transitions of each pair's first `record`
        episodes come back with its episodes."""
        service, active = self.service, self.pool.active
        noise = [pair.es.sample_seeds() for pair in active]
        if service.obs_norm is not None:
            record = max(record, self.cfg.es.obs_norm_episodes)
        steps = [
            service.es_requests(pair.env, t, pair.theta, seeds, pair.es.sigma, record)
            for pair, seeds in zip(active, noise)
        ]
        metrics: dict[str, float] = {}
        flat = iter(service.run([request for step in steps for request in step]))
        results = [service.merge_variants([next(flat) for _ in step]) for step in steps]
        for pair, seeds, episodes in zip(active, noise, results):
            n = len(seeds)
            stats = pair.es.tell(seeds, episodes.returns[:n], episodes.returns[n:])
            prefix = f"pair{pair.env.index}"
            metrics.update(
                {
                    f"{prefix}/return_mean": float(episodes.returns.mean()),
                    f"{prefix}/return_max": float(episodes.returns.max()),
                    f"{prefix}/lr": stats["lr"],
                    f"{prefix}/sigma": stats["sigma"],
                }
            )
        if service.obs_norm is not None:  # the new statistics take effect from the evaluation on
            for episodes in results:
                assert episodes.transitions is not None  # recorded while obs_norm is on
                service.obs_norm.update(episodes.transitions["obs"])
            metrics["obs_norm/count"] = float(service.obs_norm.count)
        return metrics, results

    def evaluate_pairs(self, t: int) -> dict[str, float]:
        """Each active agent's score on its own environment this iteration."""
        service, active = self.service, self.pool.active
        requests = [
            service.eval_request(service.terrain(p.env, t), p.theta[None], Key.EVAL, p.env.index, t)
            for p in active
        ]
        scores = service.scores(requests)
        metrics: dict[str, float] = {}
        for pair, score in zip(active, scores):
            self.pool.record(pair, float(score[0]))
            metrics[f"pair{pair.env.index}/score"] = pair.score
        return metrics

    def transfer(self, t: int) -> int:
        """The transfer step (transfer.py); returns the agents replaced (`transfers`)."""
        return len(self.transfer_moves(t))

    def transfer_moves(self, t: int) -> dict[int, int]:
        """The transfer step; returns {target environment: source environment} of each
        replacement."""
        moves = transfer(self.pool, self.service, self.cfg, t)
        self.transfers += len(moves)
        return moves

    # --- what every iteration reports -------------------------------------------------------
    def start_iteration(self) -> tuple[float, int]:
        return time.perf_counter(), self.service.env_steps

    def end_iteration(
        self, metrics: dict[str, float], timer: PhaseTimer, start: tuple[float, int]
    ) -> dict[str, float]:
        """Close iteration `self.iteration`: add the run-level metrics to its own and move on."""
        elapsed = time.perf_counter() - start[0]
        self.elapsed += elapsed
        self.cpu_time += self.cpu_meter.lap()  # since the last iteration: its checkpoint too
        score = max(p.score for p in self.pool.active)
        if self.best_score < self.pool.thresholds.repro <= score:
            # The run's first walker (on 2000-step episodes the paper's "solved"): its cost.
            metrics.update(
                {
                    "walker/cpu_time": self.cpu_time,
                    "walker/elapsed": self.elapsed,
                    "walker/env_steps": float(self.service.env_steps),
                }
            )
        self.best_score = max(self.best_score, score)
        metrics.update(timer.metrics())
        metrics.update(best_by_lineage(self.pool.active, self.lineage))
        self.score = score
        metrics.update(
            {
                "active_envs": float(len(self.pool.active)),
                "archived_envs": float(len(self.pool.archived)),
                "annecs": float(annecs(self.novel_pairs())),
                "steps_per_second": (self.service.env_steps - start[1]) / elapsed,
                "time/iteration": elapsed,
                "max_height": max_height_at(self.service.terrain_cfg, self.iteration),
            }
        )
        self.iteration += 1
        return metrics

    def lineage(self, pair: Pair) -> int:
        """The lineage `gen<g>/score` counts the pair in: its environment's generation."""
        return pair.env.generation

    def novel_pairs(self) -> list[Pair]:
        """The pairs whose environments ANNECS may count: all of them."""
        return self.pool.pairs

    def progress(self, metrics: dict[str, float]) -> str:
        """What the runner's progress line adds for an iteration: its events."""
        return "".join(f" {k}={int(metrics[k])}" for k in self.EVENTS if k in metrics)

    # --- artifacts and checkpoints ----------------------------------------------------------
    def save_agents(self, folder: Path, choice: str = "best") -> Path:
        """Every pair's agent into `folder`/policies/env<N>.npz (`theta` and `score` are the
        `choice`, its best evaluated or its final; both are kept), each file written
        atomically: the run's agents at a checkpoint, a CPU-time snapshot or the end."""
        for status, pairs in (("active", self.pool.active), ("archived", self.pool.archived)):
            for pair in pairs:
                final = self.service.policy(pair.theta)
                best = pair.best_theta if pair.best_theta is not None else final
                chosen = (best, pair.best_score) if choice == "best" else (final, pair.score)
                write_es_policy(
                    folder / ES_POLICIES / f"env{pair.env.index}.npz",
                    *chosen,
                    self.service.layer_sizes,
                    self.service.evaluator.agent,
                    choice=choice,
                    best_theta=best,
                    best_score=pair.best_score,
                    final_theta=final,
                    final_score=pair.score,
                    status=status,
                    generation=pair.env.generation,
                    parent=-1 if pair.env.parent is None else pair.env.parent,
                )
        return folder

    def artifacts(self, run_dir: Path, choice: str = "best") -> list[tuple[Path, str | None]]:
        """The run's final agents (`save_agents`) and each environment's last terrain (npz and
        PNG), written into `run_dir`: (folder, its artifact folder) for the store."""
        terrains = run_dir / "terrains"
        terrains.mkdir(exist_ok=True)
        for pair in self.pool.pairs:
            terrain = self.service.terrain(pair.env, self.iteration - 1)  # the last trained on
            terrain.save(terrains / f"env{pair.env.index}.npz")
            terrain.to_png(terrains / f"env{pair.env.index}.png")
        self.save_agents(run_dir, choice)
        return [(terrains, "terrains"), (run_dir / ES_POLICIES, ES_POLICIES)]

    def state_dict(self) -> dict[str, Any]:
        def pair_state(p: Pair) -> dict[str, Any]:
            return {
                "env": p.env,
                "es": p.es.state_dict(),
                "scores": list(p.scores),
                "best_score": p.best_score,
                "best_theta": p.best_theta,
            }

        return {
            "iteration": self.iteration,
            "next_index": self.pool.next_index,
            "transfers": self.transfers,
            "elapsed": self.elapsed,
            "cpu_time": self.cpu_time,
            "best_score": self.best_score,
            **self.service.state_dict(),  # env_steps, obs_norm
            "active": [pair_state(p) for p in self.pool.active],
            "archived": [pair_state(p) for p in self.pool.archived],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        def restore(s: dict[str, Any]) -> Pair:
            es = self.service.new_es(s["es"]["theta"], 0)
            es.load_state_dict(s["es"])
            return Pair(
                env=s["env"],
                es=es,
                scores=list(s["scores"]),
                best_score=s["best_score"],
                best_theta=s["best_theta"],
            )

        self.iteration, self.transfers = state["iteration"], state["transfers"]
        self.elapsed = state["elapsed"]
        self.cpu_time = state.get("cpu_time", 0.0)  # checkpoints before the CPU clock: none
        self.service.load_state_dict(state)
        # checkpoints older than the run-level best: the pairs' bests are the closest record
        self.best_score = state.get(
            "best_score", max(s["best_score"] for s in state["active"] + state["archived"])
        )
        self.pool.next_index = state["next_index"]
        self.pool.active = [restore(s) for s in state["active"]]
        self.pool.archived = [restore(s) for s in state["archived"]]


def loop_settings(cfg: Config) -> dict[str, Any]:
    """What a loop takes of a run's config besides its algorithm, terrain and evaluator (whose
    policy sizes it runs): the seed, and the budget's population, evaluations and score scale."""
    budget = cast("OpenEndedBudgetConfig", cfg.budget)  # the ePOET family's YAML picks its budget
    return {
        "seed": cfg.seed,
        "n_pairs": budget.n_pairs,
        "eval_episodes": budget.eval_episodes,
        "score_scale": budget.score_scale,
    }
