"""The observation and action layout of a robot's task, by the one rule every robot shares:
the joints' angles, then their velocities, the torso's linear and angular velocity, its
quaternion (w, x, y, z) and its lateral position y, then a contact flag per foot; the action
drives the joints in the same order (epoet.envs.task builds the vectors).

Read from the robot's config alone, without MuJoCo: agent files are checked against it before
rendering lets MuJoCo pick its OpenGL backend (epoet.eval.render.open_gl). An agent file records
the layout it was trained with (`layout_of`); a file from before robots were parts records none
and is the hexapod's (epoet.envs.config.HEXAPOD).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from epoet.envs.config import AgentConfig

TORSO = ("vx", "vy", "vz", "wx", "wy", "wz", "qw", "qx", "qy", "qz", "y")


def observation_names(joints: Sequence[str], feet: Sequence[str]) -> list[str]:
    """One name per observation entry, in order."""
    return [
        *(f"{joint}.angle" for joint in joints),
        *(f"{joint}.velocity" for joint in joints),
        *(f"torso.{entry}" for entry in TORSO),
        *(f"{foot}.contact" for foot in feet),
    ]


def observation_size(n_joints: int, n_feet: int) -> int:
    return 2 * n_joints + len(TORSO) + n_feet


def robot_sizes(agent: AgentConfig) -> tuple[int, int]:
    """The robot's observation and action sizes."""
    return observation_size(len(agent.joints), len(agent.feet)), len(agent.joints)


def layout_of(agent: AgentConfig) -> dict[str, Any]:
    """What an agent file records of the robot it was trained on."""
    return {
        "robot": agent.name,
        "observation": observation_names(agent.joints, agent.feet),
        "action": list(agent.joints),
    }
