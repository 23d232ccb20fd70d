"""Steps/s of the batched rollout engine over raw `mj_step` on the same model, terrain and states.

The engine runs a mirrored ES population (policy, observation, reward, spawning and early stopping
included) and is timed end to end. The raw baseline then replays exactly the same episodes in one
MjData: the same spawn (reset + settling steps) and each episode's recorded actions as position
targets, timing only the spawn and the `ctrl` write + `mj_step` loop. Both sides thus simulate the
same physics steps, the steps actually simulated (settling included; idle slots are not stepped),
and the ratio is the engine's whole overhead. Both are measured in this one run, interleaved, best
of `repeats` (the machine is noisy, only the ratio means something). The last line is
`rollout/raw = X`.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import mujoco
import numpy as np

from epoet.config import load
from epoet.envs.config import AgentConfig
from epoet.terrain.config import TerrainConfig
from epoet.envs.model import Ground, action_to_ctrl, build_model, layout
from epoet.envs.spawn import spawn
from epoet.rollout.populations import mirrored_population
from epoet.rollout.policy import init_params, policy_sizes
from epoet.rollout.engine import RolloutEngine, TerrainLike
from epoet.terrain import make_terrain


def raw_seconds(agent: AgentConfig, terrain_cfg: TerrainConfig, terrain: TerrainLike,
                seeds: np.ndarray, actions: np.ndarray, episode: np.ndarray) -> float:
    """Time of spawning each episode and replaying its recorded actions with bare mj_step."""
    model = build_model(agent, terrain_cfg)
    ground = Ground(model)
    ground.set(model, np.asarray(terrain.heightmap), terrain.max_height, terrain.size)
    data = mujoco.MjData(model)
    lay = layout(model)
    targets = action_to_ctrl(lay, actions)
    total = 0.0
    for e, seed in enumerate(seeds):
        rows = list(targets[episode == e])
        start = time.perf_counter()
        spawn(model, data, ground, agent, lay, np.random.default_rng(int(seed)))
        for row in rows:
            np.copyto(data.ctrl, row)
            mujoco.mj_step(model, data)
        total += time.perf_counter() - start
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--pairs", type=int, default=32, help="mirrored pairs (2x episodes)")
    parser.add_argument("--batch", type=int, default=None,
                        help="robots stepped together (default: workers.batch)")
    parser.add_argument("--max-steps", type=int, default=400)
    parser.add_argument("--terrain", default="cppn", help="a conf/terrain/ kind")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("overrides", nargs="*", help="config overrides on the paper budget, "
                                                      "e.g. agent.integrator=implicitfast")
    args = parser.parse_args()

    paper = load(["budget=paper", f"terrain={args.terrain}", *args.overrides])
    agent = replace(paper.agent, max_episode_steps=args.max_steps)
    terrain_cfg = paper.terrain
    terrain = make_terrain(terrain_cfg, seed=0, iteration=20)
    sizes = policy_sizes(paper.agent, paper.algo.es.hidden)
    engine = RolloutEngine(agent, terrain_cfg, args.batch or paper.workers.batch, sizes)
    rng = np.random.default_rng(0)
    params = mirrored_population(init_params(0, sizes), rng.integers(0, 2**62, args.pairs), 0.02)
    seeds = np.tile(rng.integers(0, 2**62, args.pairs), 2)

    # Same episodes with recording (untimed), for the actions the raw replay needs.
    recorded = engine.run(terrain, params, seeds, record=True)
    actions, episode = recorded.transitions["action"], recorded.transitions["episode"]
    steps = int(recorded.lengths.sum()) + len(seeds) * agent.settle_steps
    # Interleaved repeats, best of each: load from other processes only ever slows a side down.
    rollout = raw = np.inf
    for _ in range(args.repeats):
        start = time.perf_counter()
        episodes = engine.run(terrain, params, seeds)
        rollout = min(rollout, time.perf_counter() - start)
        assert np.array_equal(episodes.returns, recorded.returns), "rollouts are not deterministic"
        raw = min(raw, raw_seconds(agent, terrain_cfg, terrain, seeds, actions, episode))

    print(f"episodes: {len(seeds)}, physics steps: {steps}, lengths {recorded.lengths.min()}.."
          f"{recorded.lengths.max()}")
    print(f"raw mj_step: {steps / raw:,.0f} steps/s")
    print(f"rollout:     {steps / rollout:,.0f} steps/s")
    print(f"rollout/raw = {raw / rollout:.2f}")


if __name__ == "__main__":
    main()
