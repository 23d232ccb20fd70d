"""Episode start: place the robot above the local ground, randomise, and let it settle."""

from __future__ import annotations

import mujoco
import numpy as np

from epoet.envs.config import AgentConfig
from epoet.envs.model import Ground, action_to_targets, begin, stepper

FOOTPRINT = 0.35
"""Half-width (m) of the square searched for the highest ground: the legs reach ~0.25 m."""

_NEUTRAL = action_to_targets(np.zeros(18))


def spawn(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ground: Ground,
    agent: AgentConfig,
    rng: np.random.Generator,
) -> None:
    """Reset `data` to a random start pose and run the settling steps.

    The torso starts `spawn_clearance` above the highest ground under its footprint, so it never
    starts inside raised terrain (the reference used a fixed 0.18 m above zero: defect 3).
    """
    mujoco.mj_resetData(model, data)
    x = agent.start_x + rng.normal(0.0, agent.spawn_xy_std)
    y = rng.normal(0.0, agent.spawn_xy_std)
    yaw = rng.uniform(-agent.spawn_yaw, agent.spawn_yaw)
    data.qpos[0:3] = x, y, ground.max_around(x, y, FOOTPRINT) + agent.spawn_clearance
    data.qpos[3:7] = np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)
    data.qvel[:] = rng.normal(0.0, agent.spawn_vel_std, size=model.nv)
    data.ctrl[:] = _NEUTRAL
    begin(model, data)
    step = stepper(model)
    for _ in range(agent.settle_steps):
        step(model, data)
