"""Time to a walker: how long the workstation budget's root pair takes to first reach an
evaluation score of 2000 (the reproduction threshold on 2000-step episodes), per seed.

The root pair trains alone (no reproduction, hence no transfers), exactly as in a
`budget=workstation` run until its first reproduction, on every core. Per seed it prints the
wall-clock minutes, iterations and environment steps until the score first reaches the
threshold, or "not reached" after the budget's iterations; the last line is the median minutes
over the seeds (a seed that never reached counts as its full time, so the median is a lower
bound then):

    python bench/time_to_walker.py --seeds 1,2,3 [override ...]

Overrides are `python -m epoet` config overrides (e.g. `algo.es.lr=0.02`), so a candidate
change is measured the same way as the default (bench/screen_walkers.py screens a list of them).
Minutes need a quiet machine; iterations, steps and scores are a function of the config and
seed, whatever the load.
"""
from __future__ import annotations

import argparse
import time
from typing import NamedTuple

import numpy as np

from epoet.config import Config, load
from epoet.rollout.evaluators import evaluator_for
from epoet.open_ended.loop import Epoet
from epoet.open_ended.runner import layer_sizes


class Walk(NamedTuple):
    """One seed's root pair: how far it got, at what cost."""
    minutes: float
    iterations: int
    env_steps: int
    reached: bool
    score: float        # the last evaluation score (the proxy a short budget screens on)
    best_score: float
    curve: list[float]  # the score every 10 iterations (the proxy of a longer run)


def root_pair_config(seed: int, overrides: list[str]) -> Config:
    """The workstation budget without reproduction: the root pair alone, as a workstation run
    before its first round."""
    return load(["budget=workstation", "algo.adjust_interval=100000", f"seed={seed}",
                 *overrides])


def time_to_walker(cfg: Config, threshold: float) -> Walk:
    """Train the root pair until its score first reaches `threshold` or the budget's iterations
    run out."""
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator:
        loop = Epoet.from_config(cfg, evaluator)
        start, curve = time.perf_counter(), []
        while loop.iteration < cfg.budget.iterations:
            loop.run_iteration()
            root = loop.pool.active[0]
            if loop.iteration % 10 == 0:
                curve.append(round(root.score, 1))
                print(f"  seed {cfg.seed} it {loop.iteration} score {root.score:.1f} "
                      f"({(time.perf_counter() - start) / 60:.1f} min)", flush=True)
            if root.score >= threshold:
                break
    return Walk((time.perf_counter() - start) / 60, loop.iteration, loop.service.env_steps,
                root.score >= threshold, root.score, root.best_score, curve)


def describe(seed: int, threshold: float, walk: Walk) -> str:
    result = (f"reached {threshold:.0f} after {walk.iterations} iterations" if walk.reached
              else f"not reached in {walk.iterations} iterations")
    return (f"seed {seed}: {result}, {walk.minutes:.1f} min, {walk.env_steps / 1e6:.2f}M steps "
            f"(score {walk.score:.1f}, best {walk.best_score:.1f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("overrides", nargs="*", help="python -m epoet config overrides")
    args = parser.parse_args()
    minutes = []
    for seed in (int(s) for s in args.seeds.split(",")):
        cfg = root_pair_config(seed, args.overrides)
        threshold = cfg.algo.repro_threshold * cfg.budget.score_scale
        walk = time_to_walker(cfg, threshold)
        minutes.append(walk.minutes)
        print(describe(seed, threshold, walk), flush=True)
    print(f"median minutes to walker = {np.median(minutes):.1f}")


if __name__ == "__main__":
    main()
