"""Episode start: place the robot above the local ground, randomise, and let it settle."""

from __future__ import annotations

import mujoco
import numpy as np

from epoet.envs.config import AgentConfig
from epoet.envs.model import Ground, Layout, action_to_ctrl, begin, stepper


def spawn(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ground: Ground,
    agent: AgentConfig,
    layout: Layout,
    rng: np.random.Generator,
) -> None:
    """Reset `data` to a random start pose and run the settling steps with the neutral action
    (zero: the middle of every ctrlrange).

    The torso starts `spawn_clearance` above the highest ground within `spawn_footprint`, so it
    never starts inside raised terrain (the reference used a fixed 0.18 m above zero: defect 3).
    The joints start at the MJCF's reference angles, clipped into their ranges where limited
    (the hexapod's are inside; the ant's ankles are not).
    """
    mujoco.mj_resetData(model, data)
    x = agent.start_x + rng.normal(0.0, agent.spawn_xy_std)
    y = rng.normal(0.0, agent.spawn_xy_std)
    yaw = rng.uniform(-agent.spawn_yaw, agent.spawn_yaw)
    z = ground.max_around(x, y, agent.spawn_footprint) + agent.spawn_clearance
    data.qpos[0:3] = x, y, z
    data.qpos[3:7] = np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)
    joints, low, high = layout.joint_qpos, model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    reference = model.qpos0[joints]
    data.qpos[joints] = np.where(model.jnt_limited[1:], np.clip(reference, low, high), reference)
    data.qvel[:] = rng.normal(0.0, agent.spawn_vel_std, size=model.nv)
    action_to_ctrl(layout, np.zeros(layout.joints), out=data.ctrl)
    begin(model, data)
    step = stepper(model)
    for _ in range(agent.settle_steps):
        step(model, data)
