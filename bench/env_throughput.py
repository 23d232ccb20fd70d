"""Steps/s of raw `mj_step` on the hexapod model vs `env.step` with random actions.

Both are measured in this one run on the same terrain (machines here are noisy, so only the
ratio means something). The last line is `env/raw = X`.
"""
from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from epoet.env_factory import make_terrain_env


def steps_per_second(step, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        step()
    return n / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--terrain", default="cppn", help="a conf/terrain/ kind")
    args = parser.parse_args()

    env = make_terrain_env(terrain=args.terrain)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(args.steps, 18))
    index = iter(range(args.steps))

    def env_step() -> None:
        _, _, terminated, truncated, _ = env.step(actions[next(index)])
        if terminated or truncated:
            env.reset()

    # Raw physics on a copy of the env's data, with the same kind of (random) targets applied.
    model, data = env.model, mujoco.MjData(env.model)
    data.qpos[:] = env.data.qpos
    data.ctrl[:] = env.data.ctrl

    def raw_step() -> None:
        mujoco.mj_step(model, data)

    raw = steps_per_second(raw_step, args.steps)
    wrapped = steps_per_second(env_step, args.steps)
    print(f"raw mj_step: {raw:,.0f} steps/s")
    print(f"env.step:    {wrapped:,.0f} steps/s")
    print(f"env/raw = {wrapped / raw:.2f}")


if __name__ == "__main__":
    main()
