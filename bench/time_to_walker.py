"""Time to a walker: how long the workstation budget's root pair takes to first reach an
evaluation score of 2000 (the reproduction threshold on 2000-step episodes), per seed.

The root pair trains alone (no reproduction, hence no transfers), exactly as in a
`budget=workstation` run until its first reproduction, on every core. Per seed it prints the
wall-clock minutes and iterations until the score first reaches the threshold, or "not reached"
after the budget's iterations; the last line is the median minutes over the seeds (a seed that
never reached counts as its full time, so the median is a lower bound then):

    python bench/time_to_walker.py --seeds 1,2,3 [override ...]

Overrides are `python -m epoet` config overrides (e.g. `algo.es.lr=0.02`), so a candidate
change is measured the same way as the default. Time it on a quiet machine.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from epoet.config import Config, load
from epoet.es.workers import evaluator_for
from epoet.poet.runner import layer_sizes, make_loop


def time_to_walker(cfg: Config, threshold: float) -> tuple[float, int, bool, float, float]:
    """(minutes, iterations, reached, last score, best score) of the root pair until its score
    first reaches `threshold` or the budget's iterations run out; the scores are the proxy
    a shorter budget (`budget.iterations=100`) screens candidates on."""
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator:
        poet = make_loop(cfg, evaluator)
        start = time.perf_counter()
        try:
            while poet.iteration < cfg.budget.iterations:
                poet.iterate()
                root = poet.active[0]
                if poet.iteration % 10 == 0:
                    print(f"  seed {cfg.seed} it {poet.iteration} score {root.score:.1f} "
                          f"({(time.perf_counter() - start) / 60:.1f} min)", flush=True)
                if root.score >= threshold:
                    break
        finally:
            poet.close()
    return ((time.perf_counter() - start) / 60, poet.iteration, root.score >= threshold,
            root.score, root.best_score)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("overrides", nargs="*", help="python -m epoet config overrides")
    args = parser.parse_args()
    minutes = []
    for seed in (int(s) for s in args.seeds.split(",")):
        # No reproduction: the root pair alone, as a workstation run before its first round.
        cfg = load(["budget=workstation", "budget.reproduce_interval=1000000", f"seed={seed}",
                    *args.overrides])
        threshold = cfg.algo.repro_threshold * cfg.budget.score_scale
        took, iterations, reached, score, best = time_to_walker(cfg, threshold)
        minutes.append(took)
        result = (f"reached {threshold:.0f} after {iterations} iterations" if reached
                  else f"not reached in {iterations} iterations")
        print(f"seed {seed}: {result}, {took:.1f} min (score {score:.1f}, best {best:.1f})",
              flush=True)
    print(f"median minutes to walker = {np.median(minutes):.1f}")


if __name__ == "__main__":
    main()
