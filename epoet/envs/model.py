"""A robot's MuJoCo model on a run-time heightfield, and the index maps the task reads.

The robot's MJCF (agent.mjcf) fixes the body; epoet.envs.mjcf checks it against the robot's
config and adds the terrain and the sensors. The heightfield's resolution, extent and elevation
come from the terrain config, applied through MjSpec before compiling, so one compiled model
serves every terrain of a run: `Ground.set` rewrites `hfield_data` in place (no recompilation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from numba import njit
from scipy.ndimage import uniform_filter

from epoet.envs.config import INTEGRATORS, AgentConfig
from epoet.envs.mjcf import add_sensors, add_terrain, robot_spec
from epoet.terrain.config import TerrainConfig

# The schema's choices (epoet.envs.config.INTEGRATORS), as MuJoCo's enum.
_MJ_INTEGRATORS = {
    name: getattr(mujoco.mjtIntegrator, f"mjINT_{name.upper()}") for name in INTEGRATORS
}


class TerrainMismatchError(ValueError):
    """A terrain that does not fit the model's heightfield (grid, extent or elevation)."""


@dataclass(frozen=True)
class Layout:
    """Where the task's quantities live in qpos/qvel/sensordata/ctrl, in the joints' order (the
    one order of the observation, the action, the forces; the feet's for the contacts)."""

    joint_qpos: slice
    joint_qvel: slice
    contact: slice
    actuator_force: slice
    ctrl_index: np.ndarray  # the actuator of each joint
    ctrl_low: np.ndarray  # its ctrlrange: the action's -1 ...
    ctrl_span: np.ndarray  # ... and +1 map to low and low + span

    @property
    def joints(self) -> int:
        return self.joint_qpos.stop - self.joint_qpos.start

    @property
    def feet(self) -> int:
        return self.contact.stop - self.contact.start


def build_model(agent: AgentConfig, terrain: TerrainConfig) -> mujoco.MjModel:
    """Compile the robot (checked against `agent`: ConfigError) on a heightfield sized by the
    terrain config."""
    half = terrain.size / 2
    if not (abs(agent.start_x) < half and abs(agent.finish_x) < half):
        raise TerrainMismatchError(
            f"agent.start_x/finish_x ({agent.start_x}, {agent.finish_x}) must lie inside the "
            f"terrain (|x| < {half} m for terrain.size={terrain.size})."
        )
    spec = robot_spec(agent)
    add_terrain(spec, terrain)
    add_sensors(spec, agent)
    spec.option.timestep = agent.timestep
    spec.option.integrator = _MJ_INTEGRATORS[agent.integrator]
    # On a blow-up MuJoCo would silently reset the robot to its initial pose and go on; the
    # task sees the NaN or huge state instead and ends the episode (epoet.envs.task).
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    return spec.compile()


def begin(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Compute the current state's position- and velocity-dependent quantities (contacts and
    their sensors included), as a `stepper` step leaves them: call it after setting a state by
    hand."""
    mujoco.mj_step1(model, data)


def stepper(model: mujoco.MjModel) -> Callable[[mujoco.MjModel, mujoco.MjData], None]:
    """The step function for this model's integrator: `step(model, data)` advances one physics
    step after which qpos, qvel and the foot contacts all describe the new state.

    mj_step computes sensors in its forward pass, before integrating, so afterwards the contact
    sensors would still describe the previous state (about 11% of flags differed). Euler and
    implicit integrators can split the step: mj_step2 finishes it (actuation, acceleration,
    integration) and mj_step1 starts the next one (kinematics, collisions, position and velocity
    sensors), the same work as mj_step, bit for bit, with the sensors moved after the integration.
    RK4 cannot be split (mj_step2 would integrate with Euler), so it recomputes kinematics,
    collisions and position sensors after mj_step. Actuator forces (acceleration-stage sensors)
    keep describing the force applied during the step, which is what the reward penalises.
    Chosen once per model: the step is in the rollout hot loop.
    """
    return _step_rk4 if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else _step_split


def _step_rk4(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    mujoco.mj_step(model, data)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_collision(model, data)
    mujoco.mj_sensorPos(model, data)


def _step_split(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    mujoco.mj_step2(model, data)
    mujoco.mj_step1(model, data)


def layout(model: mujoco.MjModel) -> Layout:
    """The index maps of a model `build_model` compiled: the joints after the free root, the
    contact sensors, then the actuator-force sensors (one value each, in the joints' order)."""
    joints = model.njnt - 1
    contacts = np.flatnonzero(model.sensor_type == mujoco.mjtSensor.mjSENS_CONTACT)
    first = int(model.sensor_adr[contacts[0]])
    ctrl_index = np.array(
        [np.flatnonzero(model.actuator_trnid[:, 0] == j)[0] for j in range(1, model.njnt)]
    )
    low, high = model.actuator_ctrlrange[ctrl_index].T
    return Layout(
        joint_qpos=slice(int(model.jnt_qposadr[1]), int(model.jnt_qposadr[1]) + joints),
        joint_qvel=slice(int(model.jnt_dofadr[1]), int(model.jnt_dofadr[1]) + joints),
        contact=slice(first, first + len(contacts)),
        actuator_force=slice(first + len(contacts), first + len(contacts) + joints),
        ctrl_index=ctrl_index,
        ctrl_low=low.copy(),
        ctrl_span=high - low,
    )


def action_to_ctrl(layout: Layout, action: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The controls of actions in [-1, 1], (n,) or (B, n) in the joints' order: each spans its
    actuator's ctrlrange, q* = (a/2 + 1/2)(high - low) + low (the hexapod's position targets,
    docs/reference.md; the ant's motor torques)."""
    out = np.empty_like(action) if out is None else out
    targets_rows(
        np.atleast_2d(action),
        layout.ctrl_low,
        layout.ctrl_span,
        layout.ctrl_index,
        np.atleast_2d(out),
    )
    return out


@njit(cache=True)
def targets_rows(
    action: np.ndarray, low: np.ndarray, span: np.ndarray, index: np.ndarray, out: np.ndarray
) -> None:
    """`action_to_ctrl` of (B, n) actions, compiled (the rollout engine writes its batch's
    ctrl rows with it)."""
    for b in range(action.shape[0]):
        for j in range(action.shape[1]):
            a = min(max(action[b, j], -1.0), 1.0)
            out[b, index[j]] = (a * 0.5 + 0.5) * span[j] + low[j]


class Ground:
    """Heights of the current terrain in world metres, for spawning and roughness.

    MuJoCo's hfield convention: row r spans y, column c spans x, row 0 at -y and column 0 at -x.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.nrow = int(model.hfield_nrow[0])
        self.ncol = int(model.hfield_ncol[0])
        self.half_x, self.half_y, self.elevation, self.base = (
            float(v) for v in model.hfield_size[0]
        )
        self.heights = np.zeros((self.nrow, self.ncol))  # metres
        self._roughness: np.ndarray | None = None  # computed on first use (the engine needs none)
        self.heightmap = np.zeros((self.nrow, self.ncol))  # terrain units in [0, 1]
        self.max_height = 0.0

    def set(
        self, model: mujoco.MjModel, heightmap: np.ndarray, max_height: float, size: float
    ) -> None:
        """Write a terrain into the model in place; the caller runs mj_forward afterwards."""
        if abs(size - 2 * self.half_x) > 1e-9:
            raise TerrainMismatchError(
                f"terrain is {size} m wide but the model's heightfield is {2 * self.half_x} m "
                f"(terrain.size)."
            )
        if heightmap.shape != (self.nrow, self.ncol):
            raise TerrainMismatchError(
                f"terrain heightmap is {heightmap.shape} but the model's heightfield is "
                f"{(self.nrow, self.ncol)}; build the env with the terrain's grid size."
            )
        if not 0.0 <= max_height <= self.elevation + 1e-12:
            raise TerrainMismatchError(
                f"terrain max_height {max_height} m is outside [0, {self.elevation}] m, the "
                f"model's heightfield elevation (terrain.max_height_limit)."
            )
        self.heightmap = np.asarray(heightmap, dtype=np.float64)
        self.max_height = float(max_height)
        self.heights = self.heightmap * self.max_height
        self._roughness = None
        model.hfield_data[:] = (self.heightmap * (self.max_height / self.elevation)).ravel()

    def cell(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Nearest (row, col) of world points, clipped to the grid."""
        col = np.rint((np.asarray(x) / self.half_x + 1) * 0.5 * (self.ncol - 1)).astype(int)
        row = np.rint((np.asarray(y) / self.half_y + 1) * 0.5 * (self.nrow - 1)).astype(int)
        return np.clip(row, 0, self.nrow - 1), np.clip(col, 0, self.ncol - 1)

    def max_around(self, x: float, y: float, radius: float) -> float:
        """Highest ground within a square of half-width `radius` around (x, y)."""
        r0, c0 = self.cell(x - radius, y - radius)
        r1, c1 = self.cell(x + radius, y + radius)
        return float(self.heights[r0 : r1 + 1, c0 : c1 + 1].max())

    def roughness(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Variance of the 5 x 5 height patch (metres) under each point: the difficulty measure.

        The reference computes it on hfield data that held heights in [0, S]; heights in metres
        are the same quantity now that the relief is S, not S^2.
        """
        if self._roughness is None:
            self._roughness = patch_variance(self.heights)
        return self._roughness[self.cell(np.atleast_1d(x), np.atleast_1d(y))]


def patch_variance(heights: np.ndarray, size: int = 5) -> np.ndarray:
    """Variance of the size x size patch around every cell (edges repeat the border).

    Computed once per terrain (E[h^2] - E[h]^2 over box filters) so a step is a lookup.
    """
    mean = uniform_filter(heights, size, mode="nearest")
    mean_sq = uniform_filter(heights * heights, size, mode="nearest")
    return np.maximum(mean_sq - mean * mean, 0.0)
