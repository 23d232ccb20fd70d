"""Whole ePOET iterations, as `make train` runs them, against bare MuJoCo on every core.

The laptop configuration (budget=laptop, every core as a worker) first grows its pool to
--pairs environments (open thresholds, one reproduction per iteration, untimed), then runs
--iterations ordinary iterations, transfers included, timed end to end: ES episodes,
evaluations, optimiser updates, terrain generation, everything the main process does. Physics
steps are the control steps of every episode plus its settling steps. The baseline replays
episodes of the same agents on the same terrain with bare `mj_step` in one process (spawn
included, as bench/rollout_throughput.py does) and is multiplied by the number of cores; both are
measured in this one run (the machine is noisy: only the ratio means something).
The last line is `iteration/raw = X` (target >= 0.85).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from epoet.config import Config, compose, validate
from epoet.es.rollout import RolloutEngine
from epoet.es.workers import Evaluator, Request, default_workers, make_evaluator
from epoet.poet.loop import EPOET
from epoet.poet.runner import layer_sizes
from rollout_throughput import raw_seconds


class Counting:
    """The evaluator, counting the physics steps of everything it runs."""

    def __init__(self, evaluator: Evaluator, settle_steps: int) -> None:
        self.evaluator, self.settle_steps, self.physics_steps = evaluator, settle_steps, 0

    def run(self, requests: list[Request], *, record: bool = False):
        episodes = self.evaluator.run(requests, record=record)
        self.physics_steps += sum(int(e.lengths.sum()) + e.lengths.size * self.settle_steps
                                  for e in episodes)
        return episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--pairs", type=int, default=4, help="active pairs while timed")
    parser.add_argument("--iterations", type=int, default=10, help="timed iterations")
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. budget=laptop")
    args = parser.parse_args()

    cfg: Config = validate(compose(["budget=laptop", "algo.repro_threshold=-1e9",
                                    "algo.mc_lower=-1e9", "algo.mc_upper=1e9",
                                    *args.overrides]))
    budget, sizes = cfg.budget, layer_sizes(cfg)
    cores = cfg.workers.num or default_workers()
    with make_evaluator(cfg.agent, cfg.terrain, cores, cfg.workers.batch, sizes) as pool:
        evaluator = Counting(pool, cfg.agent.settle_steps)
        poet = EPOET(cfg.algo, cfg.terrain, evaluator, seed=cfg.seed, n_pairs=budget.n_pairs,
                     eval_episodes=budget.eval_episodes, score_scale=budget.score_scale,
                     layer_sizes=sizes, transfer_interval=budget.transfer_interval,
                     reproduce_interval=1)
        while len(poet.active) < args.pairs:
            poet.iterate()
        poet.reproduce_interval = 10**9  # the pool stays as it is while timed
        evaluator.physics_steps = 0
        start = time.perf_counter()
        transfers = 0
        for _ in range(args.iterations):
            transfers += "transfers" in poet.iterate()
        seconds = time.perf_counter() - start
    rate = evaluator.physics_steps / seconds

    # Bare MuJoCo: the pool's agents, one episode each on each terrain, replayed.
    engine = RolloutEngine(cfg.agent, cfg.terrain, batch=budget.eval_episodes)
    raw_steps, raw_time = 0, 0.0
    for pair in poet.active:
        terrain = poet.terrain(pair.env)
        seeds = np.arange(budget.eval_episodes)
        recorded = engine.run(terrain, np.repeat(pair.theta[None], len(seeds), 0), seeds,
                              record=True)
        t = recorded.transitions
        raw_time += raw_seconds(engine, seeds, t["action"], t["episode"])
        raw_steps += int(recorded.lengths.sum()) + len(seeds) * cfg.agent.settle_steps
    raw = raw_steps / raw_time

    print(f"pairs: {len(poet.active)}, timed iterations: {args.iterations} "
          f"({transfers} with transfers), workers: {cores}, integrator: {cfg.agent.integrator}")
    print(f"iterations: {rate:,.0f} physics steps/s ({evaluator.physics_steps:,} steps in "
          f"{seconds:.1f} s)")
    print(f"bare mj_step: {raw:,.0f} steps/s on one core, x {cores} cores = {raw * cores:,.0f}")
    print(f"iteration/raw = {rate / (raw * cores):.2f}")


if __name__ == "__main__":
    main()
