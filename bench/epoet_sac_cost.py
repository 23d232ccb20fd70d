"""Where ePOET-SAC's time goes on CPU, and what the cheap wins are worth (issue 30).

1. `iteration`: a few ePOET-SAC iterations at tiny scale (the workstation budget's learner and
   Train_SAC frames, a smaller pool and shorter episodes: `TINY` below), their wall time split
   into ES rollouts (ES steps and evaluations, in the workers), SAC's environment steps, SAC's
   gradient updates, transfers (with the actor's update from the pool) and joins.
2. `update`: one SAC update of the workstation learner (batch 256, [256, 256] ReLU, twin Q),
   its wall time split into replay sampling, the losses' forward, backward, the optimiser step
   and the target update.
3. Candidates, each against the code as it is, in this one process: the two sides alternate
   (which goes first alternates too) for `--rounds` rounds, and the median of the per-round
   ratios is printed, so load from other processes weighs on both alike:
   - `threads`: SAC updates with one torch thread over `workers.num` threads (the cores);
   - `collect`: SAC's frames stepped on the gym env directly (the loop's `collect`) over
     TorchRL's `env.rollout` (what the loop did before);
   - `compile` (with --compile; ~90 s to compile): the losses under torch.compile over eager.
4. `before/after`: Train_SAC frames/s (collection + updates, the workstation's 1 update per
   frame; `--frames` of them per round) of the loop as it is over the loop as it was (TorchRL's rollout, `workers.num`
   torch threads), and the ES steps/s of whole ePOET-SAC iterations over ePOET's on the same
   configuration, alternating iterations of the two loops.

    .venv/bin/python bench/epoet_sac_cost.py [--rounds 7] [--compile] [override ...]

The machine this ran on was shared with other runs: read the ratios, not the seconds.
"""
from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import torch
from torchrl.envs import ExplorationType
from torchrl.envs.utils import set_exploration_type

from epoet.config import Config, load
from epoet.core.cores import default_workers
from epoet.epoet_sac.loop import EpoetSac
from epoet.epoet_sac.runner import warm_start_of
from epoet.open_ended.loop import Epoet
from epoet.open_ended.runner import layer_sizes
from epoet.rl.env import terrain_env
from epoet.rollout.evaluators import make_evaluator

TINY = ["algo=epoet_sac", "budget=workstation", "budget.n_pairs=8", "budget.episode_steps=400",
        "budget.eval_episodes=1", "algo.iterations_before_transfer=2", "algo.adjust_interval=100",
        "algo.distill.states=1024", "algo.distill.epochs=2"]


def timed(totals: dict[str, float], name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[name] += time.perf_counter() - start
    return wrapper


def iteration_split(cfg: Config, iterations: int) -> None:
    """Section 1: the wall time of `iterations` ePOET-SAC iterations, by part."""
    totals: dict[str, float] = defaultdict(float)
    with make_evaluator(cfg.agent, cfg.terrain, cfg.workers.num or default_workers(),
                        cfg.workers.batch, layer_sizes(cfg)) as evaluator:
        loop = EpoetSac.from_config(cfg, evaluator, warm_start_of(cfg))
        loop.es_step = timed(totals, "ES rollouts", loop.es_step)
        loop.evaluate_pairs = timed(totals, "ES rollouts", loop.evaluate_pairs)
        loop.collect = timed(totals, "SAC env steps", loop.collect)
        loop.learner.learn = timed(totals, "SAC updates", loop.learner.learn)
        loop.transfer_moves = timed(totals, "transfers", loop.transfer_moves)
        exchange = loop.exchange
        exchange.update_actor_from_pool = timed(totals, "transfers", exchange.update_actor_from_pool)
        loop.join = timed(totals, "joins", loop.join)
        start = time.perf_counter()
        for _ in range(iterations):
            loop.run_iteration()
        wall = time.perf_counter() - start
        loop.close()
    totals["other (reproduction, bookkeeping)"] = wall - sum(totals.values())
    print(f"[iteration] {iterations} iterations, {len(loop.pool.active)} active pairs at the "
          f"end, {wall:.1f} s, torch threads {torch.get_num_threads()}:")
    for name, seconds in totals.items():
        print(f"  {name:34s} {100 * seconds / wall:5.1f} %  ({seconds:.2f} s)")


def update_split(loop: EpoetSac, updates: int) -> dict[str, float]:
    """Section 2: milliseconds per update, by part (the learner's `update`, written out)."""
    learner, parts = loop.learner, defaultdict(float)
    for _ in range(updates):
        t0 = time.perf_counter()
        sample = learner.buffer.sample(learner.batch_size)
        t1 = time.perf_counter()
        out = learner.loss(sample)
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        t2 = time.perf_counter()
        learner.optimizer.zero_grad(set_to_none=True)
        total.backward()
        t3 = time.perf_counter()
        learner.optimizer.step()
        t4 = time.perf_counter()
        learner.loss.update_targets(learner.tau)
        t5 = time.perf_counter()
        for name, (a, b) in {"sample": (t0, t1), "forward": (t1, t2), "backward": (t2, t3),
                             "optimiser": (t3, t4), "target update": (t4, t5)}.items():
            parts[name] += 1000 * (b - a) / updates
    return parts


COSTS: dict[str, list[float]] = defaultdict(list)  # every side's cost per round, by name


def alternate(name: str, a: Callable[[], float], b: Callable[[], float], rounds: int,
              sides: tuple[str, str] = ("a", "b")) -> float:
    """Median over rounds of cost(b) / cost(a) (> 1: a is faster), a and b in turns (who goes
    first alternates too); each side's costs are kept in COSTS[sides[i]]."""
    ratios = []
    for r in range(rounds):
        first, second = (a, b) if r % 2 == 0 else (b, a)
        x, y = first(), second()
        ca, cb = (x, y) if r % 2 == 0 else (y, x)
        COSTS[sides[0]].append(ca)
        COSTS[sides[1]].append(cb)
        ratios.append(cb / ca)
    median = statistics.median(ratios)
    print(f"[{name}] per round: {', '.join(f'{r:.2f}' for r in ratios)}; median {median:.2f}",
          flush=True)
    return median


def seconds(fn: Callable[[], Any]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def rollout_before(loop: EpoetSac, frames: int) -> Any:
    """SAC's frames as the loop collected them before: TorchRL's env.rollout."""
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        return loop.sac_env.rollout(frames, policy=loop.learner.actor, break_when_any_done=False)


def prepared_loop(cfg: Config, evaluator: Any) -> EpoetSac:
    """A loop whose replay holds a batch and whose SAC env has a terrain."""
    loop = EpoetSac.from_config(cfg, evaluator, warm_start_of(cfg))
    _, episodes = loop.es_step(0, record=cfg.algo.es_episodes_per_pair)
    loop.sync_obs_statistics()
    loop.add_to_replay(episodes)
    terrain_env(loop.sac_env).set_terrain(loop.service.terrain(loop.pool.active[0].env, 0))
    while len(loop.learner.buffer) < 4 * loop.learner.batch_size:
        loop.learner.add(loop.collect(loop.frames_per_iteration, 0, explore=True))
    return loop


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--iterations", type=int, default=7)
    parser.add_argument("--updates", type=int, default=20, help="updates per side and round")
    parser.add_argument("--frames", type=int, default=60,
                        help="SAC frames (and updates) per side and round in sections 3 and 4")
    parser.add_argument("--compile", action="store_true", help="also time torch.compile")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    cfg = load([*TINY, *args.overrides])
    cores = cfg.workers.num or default_workers()
    print(f"config: {' '.join([*TINY, *args.overrides])}; {cores} cores; SAC: batch "
          f"{cfg.algo.sac.batch_size}, {cfg.algo.sac.hidden} {cfg.algo.sac.activation}, "
          f"{cfg.algo.frames_per_iteration} frames x {cfg.algo.updates_per_frame} updates per "
          f"iteration; SAC torch threads {cfg.algo.sac_threads or cores} "
          f"(algo.sac_threads)", flush=True)
    iteration_split(cfg, args.iterations)
    frames = args.frames
    with make_evaluator(cfg.agent, cfg.terrain, cores, cfg.workers.batch,
                        layer_sizes(cfg)) as evaluator:
        loop = prepared_loop(cfg, evaluator)
        learner = loop.learner
        for threads in sorted({1, cores}):
            torch.set_num_threads(threads)
            update_split(loop, 3)
            parts = update_split(loop, args.updates)
            print(f"[update] {threads} torch thread(s): "
                  + ", ".join(f"{k} {v:.1f} ms" for k, v in parts.items())
                  + f"; total {sum(parts.values()):.1f} ms", flush=True)

        def updates_with(threads: int) -> Callable[[], float]:
            def run() -> float:
                torch.set_num_threads(threads)
                return seconds(lambda: learner.gradient_steps(args.updates))
            return run

        threads = alternate(f"threads: {cores} over 1 (time per update)", updates_with(1),
                            updates_with(cores), args.rounds)
        torch.set_num_threads(loop.sac_threads)
        collect = alternate("collect: TorchRL rollout over the loop's collect (time per frame)",
                            lambda: seconds(lambda: loop.collect(frames, 0, explore=True)),
                            lambda: seconds(lambda: rollout_before(loop, frames)), args.rounds)
        if args.compile:
            compiled_ratio(loop, args)

        def train_sac_now() -> float:  # Train_SAC as the loop runs it
            torch.set_num_threads(loop.sac_threads)
            return seconds(lambda: learner.learn(loop.collect(frames, 0, explore=True), frames))

        def train_sac_before() -> float:  # as it ran before: workers.num threads, env.rollout
            torch.set_num_threads(cores)
            return seconds(lambda: learner.learn(rollout_before(loop, frames), frames))

        sac = alternate("Train_SAC frames/s: now over before", train_sac_now, train_sac_before,
                        args.rounds, ("sac now", "sac before"))
        loop.close()
    es = es_steps_ratio(cfg, args.rounds, cores)
    projection(cfg, frames)
    print(f"threads/1 = {threads:.2f}  rollout/collect = {collect:.2f}  "
          f"sac_now/before = {sac:.2f}  epoet_sac_es/epoet_es = {es:.2f} (this configuration)")


def projection(cfg: Config, frames: int) -> None:
    """ePOET-SAC's ES steps/s over ePOET's on the workstation budget, from the unit costs of
    this run (median seconds per worker step and per Train_SAC frame with its update): an
    iteration of P pairs with mean episode length L takes P (2 n_pairs + eval_episodes) L
    worker steps besides Train_SAC's frames (by turns, so the ratio is ES / (ES + SAC))."""
    work = load(["algo=epoet_sac", "budget=workstation"])
    per_pair = 2 * work.budget.n_pairs + work.budget.eval_episodes
    step = statistics.median(COSTS["es"])
    sac_frames = work.algo.frames_per_iteration * work.algo.updates_per_frame
    for side in ("sac before", "sac now"):
        per_frame = statistics.median(COSTS[side]) / frames
        cells = []
        for pairs, length in ((1, 500), (1, 2000), (3, 2000)):
            es = pairs * per_pair * length * step
            cells.append(f"{pairs} pair(s), episodes of {length}: "
                         f"{es / (es + sac_frames * per_frame):.2f}")
        print(f"[projection, workstation, SAC {side.split()[1]}] ES steps/s of ePOET-SAC over "
              f"ePOET's: {'; '.join(cells)}")


def compiled_ratio(loop: EpoetSac, args: argparse.Namespace) -> None:
    """torch.compile of the losses (SacLoss.losses, on plain tensors), then eager over compiled
    time per update."""
    loss = loop.learner.loss
    eager = loss.losses
    compiled = torch.compile(eager)
    start = time.perf_counter()
    loss.losses = compiled
    loop.learner.gradient_steps(3)
    print(f"[compile] compiled in {time.perf_counter() - start:.0f} s", flush=True)

    def with_losses(fn: Callable[..., Any]) -> Callable[[], float]:
        def run() -> float:
            loss.losses = fn
            return seconds(lambda: loop.learner.gradient_steps(args.updates))
        return run

    alternate("compile: eager over compiled (time per update)", with_losses(compiled),
              with_losses(eager), args.rounds)
    loss.losses = eager


def es_steps_ratio(cfg: Config, rounds: int, cores: int) -> float:
    """The workers' environment steps per second of whole iterations: ePOET-SAC's over ePOET's,
    the two loops' iterations alternating (same pool size, terrains, seeds)."""
    with make_evaluator(cfg.agent, cfg.terrain, cores, cfg.workers.batch,
                        layer_sizes(cfg)) as evaluator:
        sac = EpoetSac.from_config(cfg, evaluator, warm_start_of(cfg))
        budget = cfg.budget
        epoet = Epoet(cfg.algo, cfg.terrain, evaluator, seed=cfg.seed, n_pairs=budget.n_pairs,
                      eval_episodes=budget.eval_episodes, score_scale=budget.score_scale)
        steps: dict[Any, int] = {epoet: 0, sac: 0}  # worker steps per loop
        for loop in steps:
            run = loop.service.run

            def counted(requests: Any, run: Any = run, loop: Any = loop) -> Any:
                episodes = run(requests)
                steps[loop] += sum(int(e.lengths.sum()) for e in episodes)
                return episodes
            loop.service.run = counted

        def per_step(loop: Any) -> Callable[[], float]:
            def run() -> float:  # seconds per worker step (the inverse rate)
                before = steps[loop]
                wall = seconds(loop.run_iteration)
                return wall / (steps[loop] - before)
            return run

        ratio = alternate("ES steps/s: ePOET-SAC over ePOET (whole iterations)",
                          per_step(epoet), per_step(sac), rounds, ("es", "es in epoet_sac"))
        sac.close()
    return 1.0 / ratio


if __name__ == "__main__":
    main()
