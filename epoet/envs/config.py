"""A robot's and its episode's settings (conf/agent/<robot>.yaml); the integrators are those
`epoet.envs.model` implements, the MJCF file is found by `mjcf_file`."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Optional

from epoet.core.schema import check, non_negative, positive


@dataclass
class RewardConfig:
    """Weights of the paper's Eq. 1 as implemented by the reference (docs/reference.md)."""

    KEY: ClassVar[str] = "agent.reward"

    target_speed: float
    lateral_speed_penalty: float
    w_velocity: float
    w_heading: float
    w_lateral: float
    c_lateral: float
    c_heading: float
    c_pitch: float
    c_roll: float
    c_actuator: float
    c_vertical: float
    finish_bonus: float

    def __post_init__(self) -> None:
        positive(self, "target_speed")
        non_negative(
            self,
            "lateral_speed_penalty",
            "w_velocity",
            "w_heading",
            "w_lateral",
            "c_lateral",
            "c_heading",
            "c_pitch",
            "c_roll",
            "c_actuator",
            "c_vertical",
            "finish_bonus",
        )


# rk4: the reference's; implicitfast: faster and stable here (docs/configs.md); epoet.envs.model
# maps each name to MuJoCo's integrator.
INTEGRATORS = ("rk4", "implicitfast")


def mjcf_file(spec: str) -> Path | None:
    """The file `agent.mjcf` names: `<package>:<path inside it>` (an installed package's file,
    found without importing the package) or a file path; None if there is no such file."""
    package, _, inside = spec.partition(":")
    if inside and all(part.isidentifier() for part in package.split(".")):
        try:
            found = importlib.util.find_spec(package)
        except ModuleNotFoundError:  # a parent package is missing
            found = None
        if found is None or not found.submodule_search_locations:
            return None
        path = Path(next(iter(found.submodule_search_locations))) / inside
    else:
        path = Path(spec)
    return path if path.is_file() else None


HEXAPOD = "hexapod"  # the robot of agent files and configs from before robots were parts
# What such a config lacks: the robot's body (conf/agent/<robot>.yaml; epoet.config.saved_agent).
BODY_KEYS = ("mjcf", "joints", "feet", "spawn_footprint", "published_sac")


@dataclass
class AgentConfig:
    """The robot and its episode rules (docs/reference.md "Robot, reward, episode end"; a robot's
    body: docs/architecture.md "Adding a robot")."""

    KEY: ClassVar[str] = "agent"

    name: str  # the robot's name, recorded in the agent files trained on it
    mjcf: str  # its MuJoCo model: <package>:<path inside it>, or a file
    joints: list[str]  # the joints observed and driven, in the MJCF's order
    feet: list[str]  # the geoms whose contact with the ground are the foot flags
    timestep: float  # one physics step per control step: 50 Hz, as the reference
    integrator: str  # rk4 (the reference) | implicitfast (faster; docs/configs.md)
    max_episode_steps: int
    start_x: float  # spawn x; the finish line is `finish_x` (docs/evaluation.md)
    finish_x: float
    no_progress_steps: int  # end after this many steps without a new best x
    progress_margin: float  # metres beyond the best x that count as progress
    settle_steps: int
    spawn_xy_std: float
    spawn_yaw: float  # yaw ~ U(-spawn_yaw, spawn_yaw)
    spawn_vel_std: float
    spawn_clearance: float  # torso height above the highest ground under the robot
    spawn_footprint: float  # half-width of the square searched for that ground, metres
    published_sac: Optional[str]  # the authors' SAC agent of this robot (reference:<name>)
    reward: RewardConfig

    def __post_init__(self) -> None:
        check(
            mjcf_file(self.mjcf) is not None,
            f"agent.mjcf names no file: {self.mjcf!r} (a file, or <package>:<path inside it>).",
        )
        for key in ("joints", "feet"):
            names = getattr(self, key)
            check(
                len(names) > 0 and len(set(names)) == len(names),
                f"agent.{key} must list distinct names, at least one, got {list(names)}.",
            )
        check(
            self.integrator in INTEGRATORS,
            f"agent.integrator must be one of {list(INTEGRATORS)}, got {self.integrator!r}.",
        )
        positive(
            self,
            "timestep",
            "max_episode_steps",
            "no_progress_steps",
            "spawn_clearance",
            "spawn_footprint",
        )
        non_negative(
            self, "settle_steps", "spawn_xy_std", "spawn_yaw", "spawn_vel_std", "progress_margin"
        )
        check(
            self.finish_x > self.start_x,
            f"agent.finish_x ({self.finish_x}) must be ahead of agent.start_x ({self.start_x}).",
        )
