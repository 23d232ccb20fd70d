"""RK4 against implicitfast on the hexapod: physics speed, and stability on the roughest terrains.

Speed: bare `mj_step` steps/s of one MjData with random position targets, on the same model and
terrain, for each integrator, interleaved repeats, best of each (the machine is noisy: only the
ratio means something). Stability: episodes through the gymnasium env on CPPN terrains several
mutations deep at the height cap (S = terrain.max_height_limit), with uniform random actions,
random ES policies, and any trained policies given with --policy (`policies/env<N>.npz` of an
ePOET run); an episode is unstable if the state goes non-finite or MuJoCo raises a warning.
Self-collision: the same bare rate with the robot's geoms allowed to collide with each other
(every geom's conaffinity 1, the model before it followed the reference), for each integrator.
The last line is `implicitfast/rk4 = X`; `--speed-only` skips the stability episodes.
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from epoet.config import Config, compose, validate
from epoet.env_factory import action_to_targets
from epoet.envs.terrain_env import TerrainEnv
from epoet.rollout.policy import forward, init_params, policy_sizes
from epoet.terrain import Terrain, cppn_inputs, make_terrain, mutate_genome

INTEGRATORS = ("rk4", "implicitfast")


def rough_terrains(cfg: Config, n: int, generations: int) -> list[Terrain]:
    """n CPPN terrains `generations` mutations from their roots, at the height cap."""
    tc = cfg.terrain
    cap = int(np.ceil((tc.max_height_limit - tc.max_height) / max(tc.max_height_step, 1e-9)))
    terrains = []
    for i in range(n):
        genome = make_terrain(tc, seed=i).genome
        for g in range(generations):
            genome = mutate_genome(genome, tc.cppn, tc.mutation, seed=1000 * i + g,
                                   field=cppn_inputs(tc))
        terrains.append(make_terrain(tc, seed=i, iteration=cap, genome=genome,
                                     generation=generations))
    return terrains


def steps_per_second(cfg: Config, integrator: str, terrain: Terrain, steps: int,
                     self_collision: bool = False) -> float:
    """Bare mj_step rate on the env's model (terrain and spawn set by the env, not timed)."""
    cfg.agent.integrator = integrator
    env = TerrainEnv(cfg.agent, cfg.terrain)
    env.reset(seed=0, options={"terrain": terrain})
    model, data = env.model, env.data
    if self_collision:
        model.geom_conaffinity[:] = 1
    targets = action_to_targets(np.random.default_rng(0).uniform(-1, 1, (steps, 18)))
    start = time.perf_counter()
    for row in targets:
        np.copyto(data.ctrl, row)
        mujoco.mj_step(model, data)
    return steps / (time.perf_counter() - start)


Policy = Callable[[np.ndarray], np.ndarray]


def policies(cfg: Config, paths: list[Path], n_random: int) -> dict[str, Policy]:
    rng = np.random.default_rng(1)
    out: dict[str, Policy] = {"uniform random actions": lambda obs: rng.uniform(-1, 1, 18)}
    for i in range(n_random):
        sizes = policy_sizes(cfg.agent, cfg.algo.es.hidden)
        theta = init_params(i, sizes, std=0.5)
        out[f"random ES policy {i}"] = lambda obs, theta=theta, sizes=sizes: forward(theta, obs,
                                                                                      sizes)
    for path in paths:
        saved = np.load(path)
        theta, sizes = saved["theta"], tuple(int(s) for s in saved["layer_sizes"])
        out[f"trained {path}"] = lambda obs, theta=theta, sizes=sizes: forward(theta, obs, sizes)
    return out


def unstable_episodes(cfg: Config, integrator: str, terrains: list[Terrain],
                      policy: Policy, episodes: int) -> tuple[int, int, int]:
    """(episodes run, unstable episodes, control steps)."""
    cfg.agent.integrator = integrator
    env = TerrainEnv(cfg.agent, cfg.terrain)
    bad = steps = 0
    for e in range(episodes):
        obs, _ = env.reset(seed=e, options={"terrain": terrains[e % len(terrains)]})
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy(obs))
            steps += 1
            done = terminated or truncated or not np.isfinite(obs).all()
        warnings = sum(w.number for w in env.data.warning)
        bad += int(warnings > 0 or not (np.isfinite(env.data.qpos).all()
                                        and np.isfinite(env.data.qvel).all()))
    return episodes, bad, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=4000, help="physics steps per speed repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=10, help="per policy and integrator")
    parser.add_argument("--episode-steps", type=int, default=2000)
    parser.add_argument("--terrains", type=int, default=5)
    parser.add_argument("--generations", type=int, default=6)
    parser.add_argument("--random-policies", type=int, default=2)
    parser.add_argument("--policy", type=Path, action="append", default=[])
    parser.add_argument("--speed-only", action="store_true", help="skip the stability episodes")
    args = parser.parse_args()

    cfg: Config = validate(compose(["terrain=cppn",
                                    f"budget.episode_steps={args.episode_steps}"]))
    terrains = rough_terrains(cfg, args.terrains, args.generations)
    print(f"terrains: {len(terrains)} CPPN, {args.generations} mutations deep, "
          f"S = {terrains[0].max_height:.2f} m")
    for name, policy in ({} if args.speed_only else
                         policies(cfg, args.policy, args.random_policies)).items():
        for integrator in INTEGRATORS:
            n, bad, steps = unstable_episodes(cfg, integrator, terrains, policy, args.episodes)
            print(f"stability {integrator:12s} {name}: {bad}/{n} unstable episodes "
                  f"({steps} steps)")
    runs = [(integrator, collide) for integrator in INTEGRATORS for collide in (False, True)]
    best = dict.fromkeys(runs, 0.0)
    for _ in range(args.repeats):
        for integrator, collide in runs:
            rate = steps_per_second(cfg, integrator, terrains[0], args.steps, collide)
            best[integrator, collide] = max(best[integrator, collide], rate)
    for integrator in INTEGRATORS:
        plain, collide = best[integrator, False], best[integrator, True]
        print(f"{integrator}: {plain:,.0f} physics steps/s ({collide:,.0f} with robot "
              f"self-collision: no-self-collision/self-collision = {plain / collide:.2f})")
    print(f"implicitfast/rk4 = {best['implicitfast', False] / best['rk4', False]:.2f}")


if __name__ == "__main__":
    main()
