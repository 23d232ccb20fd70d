"""The hexapod's and its episode's settings (conf/agent/); the integrators are those
`epoet.envs.model` implements."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

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


@dataclass
class AgentConfig:
    """The hexapod and its episode rules (docs/reference.md "Robot, reward, episode end")."""

    KEY: ClassVar[str] = "agent"

    name: str
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
    reward: RewardConfig

    def __post_init__(self) -> None:
        check(self.name == "hexapod", f"agent.name must be 'hexapod', got {self.name!r}.")
        check(
            self.integrator in INTEGRATORS,
            f"agent.integrator must be one of {list(INTEGRATORS)}, got {self.integrator!r}.",
        )
        positive(self, "timestep", "max_episode_steps", "no_progress_steps", "spawn_clearance")
        non_negative(
            self, "settle_steps", "spawn_xy_std", "spawn_yaw", "spawn_vel_std", "progress_margin"
        )
        check(
            self.finish_x > self.start_x,
            f"agent.finish_x ({self.finish_x}) must be ahead of agent.start_x ({self.start_x}).",
        )
