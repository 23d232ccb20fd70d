"""Whole ePOET iterations, as `make train` runs them, against bare MuJoCo on every core.

The laptop configuration (budget=laptop, every core as a worker) first grows its pool to
--pairs environments (open thresholds, one reproduction per iteration, untimed), then runs
--iterations ordinary iterations, transfers included, timed end to end: ES episodes,
evaluations, optimiser updates, terrain generation, everything the main process does. Physics
steps are the control steps of every episode plus its settling steps. The baseline replays
ES episodes of the same agents (mirrored samples around each, with its sigma) on the same terrains
with bare `mj_step` in one process (spawn included, as bench/rollout_throughput.py does), best of
two passes, and is multiplied by the number of cores; both are measured in this one run (the
machine is noisy: only the ratio means something).
The last line is `iteration/raw = X (IQR Y, N interleaved repeats)` (target >= 0.85): the median
of the per-iteration ratios and their interquartile range.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from epoet.config import Config, compose, validate
from epoet.rollout.populations import mirrored_population
from epoet.rollout.engine import RolloutEngine
from epoet.core.cores import default_workers
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.evaluators import make_evaluator
from epoet.rollout.populations import Request
from epoet.open_ended.loop import Epoet
from epoet.open_ended.runner import layer_sizes
from rollout_throughput import raw_seconds


class Counting:
    """The evaluator, counting the physics steps of everything it runs."""

    def __init__(self, evaluator: Evaluator, settle_steps: int) -> None:
        self.evaluator, self.settle_steps, self.physics_steps = evaluator, settle_steps, 0
        self.layer_sizes = evaluator.layer_sizes  # the loop's policy sizes are its evaluator's

    def run(self, requests: list[Request]):
        episodes = self.evaluator.run(requests)
        self.physics_steps += sum(int(e.lengths.sum()) + e.lengths.size * self.settle_steps
                                  for e in episodes)
        return episodes


def bare_rate(loop: Epoet, cfg: Config, samples: int) -> float:
    """One core's bare mj_step steps/s replaying ES episodes like the timed ones: `samples`
    mirrored pairs around each pool agent with its current sigma, on its current terrain."""
    engine = RolloutEngine(cfg.agent, cfg.terrain, cfg.workers.batch, layer_sizes(cfg))
    steps, seconds = 0, 0.0
    for pair in loop.pool.active:
        terrain = loop.service.terrain(pair.env, loop.iteration)
        noise = np.arange(samples) + 1000 * pair.env.index
        params = mirrored_population(pair.theta, noise, pair.es.sigma)
        seeds = np.tile(noise, 2)
        recorded = engine.run(terrain, params, seeds, record=True)
        t = recorded.transitions
        seconds += raw_seconds(cfg.agent, cfg.terrain, terrain, seeds,
                               t["action"], t["episode"])
        steps += int(recorded.lengths.sum()) + len(seeds) * cfg.agent.settle_steps
    return steps / seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--pairs", type=int, default=4, help="active pairs while timed")
    parser.add_argument("--iterations", type=int, default=10,
                        help="timed iterations, each beside a bare pass (at least 5)")
    parser.add_argument("--samples", type=int, default=4,
                        help="mirrored pairs per agent replayed for the bare baseline")
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. budget=laptop")
    args = parser.parse_args()
    if args.iterations < 5:
        parser.error("--iterations must be at least 5: a median and a spread need them")

    cfg: Config = validate(compose(["budget=laptop", "algo.repro_threshold=-1e9",
                                    "algo.mc_lower=-1e9", "algo.mc_upper=1e9",
                                    *args.overrides]))
    budget, sizes = cfg.budget, layer_sizes(cfg)
    cores = cfg.workers.num or default_workers()
    with make_evaluator(cfg.agent, cfg.terrain, cores, cfg.workers.batch, sizes) as pool:
        evaluator = Counting(pool, cfg.agent.settle_steps)
        loop = Epoet(cfg.algo, cfg.terrain, evaluator, seed=cfg.seed, n_pairs=budget.n_pairs,
                     eval_episodes=budget.eval_episodes, score_scale=budget.score_scale)
        loop.reproduce_interval = loop.later_reproduce_interval = 1  # until the pool is full
        while len(loop.pool.active) < args.pairs:
            loop.run_iteration()
        loop.reproduce_interval = 10**9  # the pool stays as it is while timed
        # Interleaved: each timed iteration is followed by a bare pass, so load from elsewhere
        # on this noisy machine weighs on both sides alike.
        ratios, rates, raws, transfers = [], [], [], 0
        for _ in range(args.iterations):
            evaluator.physics_steps = 0
            start = time.perf_counter()
            transfers += "transfers" in loop.run_iteration()
            rates.append(evaluator.physics_steps / (time.perf_counter() - start))
            raws.append(bare_rate(loop, cfg, args.samples))
            ratios.append(rates[-1] / (raws[-1] * cores))
    print(f"pairs: {len(loop.pool.active)}, timed iterations: {args.iterations} "
          f"({transfers} with transfers), workers: {cores}, integrator: {cfg.agent.integrator}")
    print(f"iterations: {np.median(rates):,.0f} physics steps/s (median; "
          f"{min(rates):,.0f}..{max(rates):,.0f})")
    print(f"bare mj_step: {np.median(raws):,.0f} steps/s on one core (median), x {cores} cores")
    low, high = np.percentile(ratios, [25, 75])
    print(f"iteration/raw = {np.median(ratios):.2f} (IQR {high - low:.3f}, {args.iterations} "
          "interleaved repeats)")


if __name__ == "__main__":
    main()
