"""ES-step throughput with a 2-worker process pool over the in-process (1-worker) backend, and
with 2 Ray actors (workers=ray, a local Ray) over the 2-worker pool.

One ES step = the episodes of a mirrored population (theta +- sigma * eps) on one terrain, as the
ePOET loop runs it. Both backends evaluate the same population with the same seeds (the returns
must match exactly); the three are timed in turn `repeats` times (at least 5), so a burst of
load from other processes weighs on all alike, and each ratio is taken within a repeat. Start-up
is reported separately (paid once per run). Prints `scaling_2w = X` (2 cores: 2.0 is the
ceiling), then `ray/local = X` (target >= 0.9; Ray's own processes share the two cores with its
actors): each the median over the repeats, with the interquartile range beside it (a reading
decides a target when its IQR is smaller than its margin).
"""
from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np

from epoet.config import load
from epoet.rollout.policy import init_params, policy_sizes
from epoet.rollout.backends.ray_host import RayEvaluator
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.evaluators import make_evaluator
from epoet.rollout.populations import Mirrored, Request
from epoet.terrain import make_terrain


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--pairs", type=int, default=32)
    parser.add_argument("--max-steps", type=int, default=600)  # ES steps of seconds: a steady ratio
    parser.add_argument("--batch", type=int, default=None,
                        help="robots per process (default: workers.batch)")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    paper = load(["budget=paper"])  # RK4, the CPPN terrain
    agent = replace(paper.agent, max_episode_steps=args.max_steps)
    terrain_cfg = paper.terrain
    terrain = make_terrain(terrain_cfg, seed=0, iteration=20)
    rng = np.random.default_rng(0)
    sizes = policy_sizes(paper.agent, paper.algo.es.hidden)
    batch = args.batch or paper.workers.batch
    theta = init_params(0, sizes)
    es = Request(terrain, Mirrored.of(theta, rng.integers(0, 2**62, args.pairs),
                                      paper.algo.es.sigma, rng.integers(0, 2**62, args.pairs)))

    def es_step(evaluator: Evaluator) -> tuple[float, np.ndarray]:
        start = time.perf_counter()
        (episodes,) = evaluator.run([es])
        return time.perf_counter() - start, episodes.returns

    start = time.perf_counter()
    pool = make_evaluator(agent, terrain_cfg, 2, batch, sizes)
    startup = time.perf_counter() - start
    start = time.perf_counter()
    ray = RayEvaluator(agent, terrain_cfg, 2, batch, sizes)
    ray_startup = time.perf_counter() - start
    serial = make_evaluator(agent, terrain_cfg, 1, batch, sizes)
    if args.repeats < 5:
        parser.error("--repeats must be at least 5: a median and a spread need them")
    times = []  # per repeat: (1 worker, 2 workers, 2 Ray actors) seconds
    with pool, serial, ray:
        for _ in range(args.repeats):
            one, returns_1 = es_step(serial)
            two, returns_2 = es_step(pool)
            on_ray, returns_ray = es_step(ray)
            times.append((one, two, on_ray))
            assert np.array_equal(returns_1, returns_2), "1 and 2 workers disagree"
            assert np.array_equal(returns_2, returns_ray), "Ray and the local pool disagree"
    one, two, on_ray = np.median(np.array(times), axis=0)
    scaling = [t[0] / t[1] for t in times]
    ray_local = [t[1] / t[2] for t in times]

    episodes = 2 * args.pairs
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())} "
          f"on {os.cpu_count()} cores")
    print(f"start-up: pool {startup:.2f} s, Ray {ray_startup:.2f} s")
    print(f"1 worker:  {episodes / one:.1f} episodes/s ({one:.2f} s per ES step)")
    print(f"2 workers: {episodes / two:.1f} episodes/s ({two:.2f} s per ES step)")
    print(f"2 Ray actors: {episodes / on_ray:.1f} episodes/s ({on_ray:.2f} s per ES step)")
    print(f"scaling_2w = {np.median(scaling):.2f} (IQR {iqr(scaling):.3f}, {args.repeats} repeats)")
    print(f"ray/local = {np.median(ray_local):.2f} (IQR {iqr(ray_local):.3f}, {args.repeats} repeats)")


def iqr(values: list[float]) -> float:
    low, high = np.percentile(values, [25, 75])
    return float(high - low)


if __name__ == "__main__":
    main()
