"""The locomotion task, vectorised over a batch of robots: observation, reward, episode end.

Both the gymnasium env (a batch of one) and the ES rollout engine (hundreds of robots stepped in
lockstep) call this one implementation, so the reward ES optimises is the reward the RL baselines
see. Every robot's task is this one, read through its model's `Layout` (epoet.envs.model): the
observation follows epoet.envs.spaces' rule, the reward the paper's Eq. 1 with the robot's
weights. Inputs are raw MuJoCo arrays gathered per step: qpos (B, nq), qvel (B, nv), sensordata
(B, feet + joints) (the hexapod's: 25, 24, 24).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import astuple, dataclass, fields
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from epoet.envs.config import AgentConfig, RewardConfig
from epoet.envs.model import Layout
from epoet.envs.spaces import observation_size

# MuJoCo's own bound on a sane state value (mjMAXVAL): beyond it, or NaN, the physics blew up.
MAX_STATE = 1e10
REWARD_TERMS = ("velocity", "heading", "lateral", "penalty", "bonus")


@dataclass
class EpisodeState:
    """Per-robot episode bookkeeping, arrays of shape (B,)."""

    prev_heading: np.ndarray
    prev_y: np.ndarray
    best_x: np.ndarray
    stalled: np.ndarray  # consecutive steps without a new best x
    steps: np.ndarray
    finished: np.ndarray  # finish line crossed (the bonus is paid once)
    unstable: np.ndarray  # the physics blew up in the last step (the episode ended on it)

    @classmethod
    def zeros(cls, batch: int) -> "EpisodeState":
        f = lambda: np.zeros(batch)  # noqa: E731
        return cls(
            f(),
            f(),
            f(),
            np.zeros(batch, np.int64),
            np.zeros(batch, np.int64),
            np.zeros(batch, bool),
            np.zeros(batch, bool),
        )


# What the compiled step reads of the config and the model layout, as a namedtuple (numba takes
# one where it cannot take a dataclass): every reward weight under its config name, then the
# episode rules, the index of the first actuator-force sensor and the number of actuators.
if TYPE_CHECKING:

    class _Constants(RewardConfig):
        """What the type checker sees of the namedtuple below (its fields are built at run time)."""

        v_ref: float
        finish_x: float
        progress_margin: float
        half_size: float
        max_episode_steps: int
        no_progress_steps: int
        actuator_force: int
        actuators: int

        def __init__(self, *values: float) -> None: ...
else:
    _Constants = namedtuple(
        "_Constants",
        [f.name for f in fields(RewardConfig)]
        + [
            "v_ref",
            "finish_x",
            "progress_margin",
            "half_size",
            "max_episode_steps",
            "no_progress_steps",
            "actuator_force",
            "actuators",
        ],
    )


@njit(cache=True)
def heading_deviation(w: float) -> float:
    """Total rotation angle of the torso, 2 acos(|qw|), in [0, pi] (q and -q fold together)."""
    return 2.0 * np.arccos(_clip(np.abs(w), 0.0, 1.0))


@njit(cache=True)
def roll_pitch(w: float, x: float, y: float, z: float) -> tuple[float, float]:
    """Roll and pitch (ZYX Euler) of the quaternion (w, x, y, z)."""
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(_clip(2.0 * (w * y - z * x), -1.0, 1.0))
    return roll, pitch


@njit(cache=True)
def _clip(v: float, low: float, high: float) -> float:
    """np.clip of one value (NaN stays NaN)."""
    return low if v < low else high if v > high else v


@njit(cache=True)
def _mean_square(row: np.ndarray) -> float:
    """np.mean(row * row) of a row of 1 to 128 values (epoet.envs.mjcf refuses more), bit for
    bit: numpy adds fewer than 8 in order, more in 8 partial sums (the unrolled block of its
    pairwise summation), then the leftovers."""
    n = row.size
    if n < 8:
        total = 0.0
        for i in range(n):
            total += row[i] * row[i]
        return total / n
    r = np.empty(8)
    for j in range(8):
        r[j] = row[j] * row[j]
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += row[i + j] * row[i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += row[i] * row[i]
        i += 1
    return total / n


@njit(cache=True)
def _step(
    c: _Constants,
    at: tuple[int, int, int, int, int],
    qpos: np.ndarray,
    qvel: np.ndarray,
    sensordata: np.ndarray,
    prev_heading: np.ndarray,
    prev_y: np.ndarray,
    best_x: np.ndarray,
    stalled: np.ndarray,
    steps: np.ndarray,
    finished: np.ndarray,
    unstable: np.ndarray,
    reward: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    terms: np.ndarray,
    obs: np.ndarray,
) -> None:
    """`Task.step` for every row, compiled: one call instead of ~80 numpy calls a step
    (at 16 robots those took about a quarter of the physics' time)."""
    for b in range(qpos.shape[0]):
        x, y = qpos[b, 0], qpos[b, 1]
        vx, vy, vz = qvel[b, 0], qvel[b, 1], qvel[b, 2]
        w, qx, qy, qz = qpos[b, 3], qpos[b, 4], qpos[b, 5], qpos[b, 6]
        heading = heading_deviation(w)
        roll, pitch = roll_pitch(w, qx, qy, qz)

        velocity = (1.0 / (np.abs(vx - c.target_speed) + 1.0) - c.v_ref) / (
            1.0 + c.lateral_speed_penalty * vy * vy
        )
        # Correcting heading and lateral drift is rewarded as a potential difference
        # (Azayev et al.).
        heading_gain = np.abs(prev_heading[b]) - heading
        lateral_gain = np.abs(prev_y[b]) - np.abs(y)
        force = sensordata[b, c.actuator_force : c.actuator_force + c.actuators]
        penalty = (
            c.c_lateral * y * y
            + c.c_heading * heading * heading
            + c.c_pitch * pitch * pitch
            + c.c_roll * roll * roll
            + c.c_actuator * _mean_square(force)
            + c.c_vertical * vz * vz
        )
        crossed = x >= c.finish_x and not finished[b]
        bonus = c.finish_bonus if crossed else 0.0
        r = (
            c.w_velocity * velocity
            + c.w_heading * heading_gain
            + c.w_lateral * lateral_gain
            - penalty
            + bonus
        )

        prev_heading[b] = heading
        prev_y[b] = y
        finished[b] = finished[b] or crossed
        # Progress is a new best x by more than a margin, so a robot jittering in place stalls
        # while slow but steady walking (the margin accumulates over steps) does not.
        if x > best_x[b] + c.progress_margin:
            best_x[b] = x
            stalled[b] = 0
        else:
            stalled[b] += 1
        steps[b] += 1

        # A physics blow-up (NaN, Inf or a huge state; MuJoCo's automatic reset is disabled in
        # build_model) ends the episode as a fall would, and its step earns nothing: the
        # episode's return is what it earned while the physics was sound.
        sound = True
        for v in qpos[b]:
            sound = sound and np.abs(v) <= MAX_STATE
        for v in qvel[b]:
            sound = sound and np.abs(v) <= MAX_STATE
        unstable[b] = not sound
        if not sound:
            r = 0.0
            finished[b] = False
        # Falling off: below the terrain's lowest point (height 0) or past its edge.
        fell = qpos[b, 2] < 0.0 or np.abs(x) > c.half_size or np.abs(y) > c.half_size
        terminated[b] = finished[b] or fell or not sound
        truncated[b] = not terminated[b] and (
            steps[b] >= c.max_episode_steps or stalled[b] > c.no_progress_steps
        )
        reward[b] = r
        terms[b, 0] = c.w_velocity * velocity
        terms[b, 1] = c.w_heading * heading_gain
        terms[b, 2] = c.w_lateral * lateral_gain
        terms[b, 3] = -penalty
        terms[b, 4] = bonus
        _observe_row(qpos[b], qvel[b], sensordata[b], at, obs[b])


@njit(cache=True)
def _observe(
    qpos: np.ndarray,
    qvel: np.ndarray,
    sensordata: np.ndarray,
    at: tuple[int, int, int, int, int],
    out: np.ndarray,
) -> None:
    """`Task.observe` for every row, compiled."""
    for b in range(qpos.shape[0]):
        _observe_row(qpos[b], qvel[b], sensordata[b], at, out[b])


@njit(cache=True)
def _observe_row(
    qpos: np.ndarray,
    qvel: np.ndarray,
    sensordata: np.ndarray,
    at: tuple[int, int, int, int, int],
    row: np.ndarray,
) -> None:
    """One robot's observation (epoet.envs.spaces' rule); `at` holds the first index of the
    joint angles in qpos, of the joint velocities in qvel and of the contact sensors in
    sensordata, and the number of joints and of feet."""
    joint_qpos, joint_qvel, contact, n, feet = at
    row[0:n] = qpos[joint_qpos : joint_qpos + n]
    row[n : 2 * n] = qvel[joint_qvel : joint_qvel + n]
    row[2 * n : 2 * n + 6] = qvel[0:6]
    row[2 * n + 6 : 2 * n + 10] = qpos[3:7]
    row[2 * n + 10] = qpos[1]
    for k in range(feet):
        row[2 * n + 11 + k] = 1.0 if sensordata[contact + k] > 0.0 else 0.0
    # A blown-up robot's (terminal) observation is stored as zeros, never NaN: a replay buffer
    # multiplies terminal next-observations' values by zero, and NaN * 0 is NaN.
    for k in range(row.size):
        if not np.isfinite(row[k]):
            row[k] = 0.0


class Task:
    """Observation, reward and termination of the paper's task (docs/reference.md), for the
    robot whose model `layout` describes.

    Both run compiled (numba) over the rows, one call per step: with a few dozen numpy calls on
    (B,) arrays per step, the engine spent about a third of its time here rather than in MuJoCo.
    """

    def __init__(self, agent: AgentConfig, layout: Layout, half_size: float) -> None:
        rw = agent.reward
        self._c = _Constants(
            *astuple(rw),
            1.0 / (1.0 + rw.target_speed),
            agent.finish_x,
            agent.progress_margin,
            float(half_size),
            agent.max_episode_steps,
            agent.no_progress_steps,
            layout.actuator_force.start,
            layout.joints,
        )
        self._at = (
            layout.joint_qpos.start,
            layout.joint_qvel.start,
            layout.contact.start,
            layout.joints,
            layout.feet,
        )
        self.obs_dim = observation_size(layout.joints, layout.feet)
        self.act_dim = layout.joints

    def observe(
        self, qpos: np.ndarray, qvel: np.ndarray, sensordata: np.ndarray, out: np.ndarray
    ) -> np.ndarray:
        """Joint angles, joint velocities, torso linear + angular velocity, torso quaternion
        (w, x, y, z), torso y, foot contacts (1 when the foot touches): the hexapod's 53 dims
        (epoet.envs.spaces). A blown-up robot's (terminal) observation is zeros, never NaN."""
        _observe(qpos, qvel, sensordata, self._at, out)
        return out

    def begin(self, qpos: np.ndarray, state: EpisodeState, rows: np.ndarray | slice) -> None:
        """Start episodes for `rows` from their (settled) initial state."""
        state.prev_heading[rows] = [heading_deviation(w) for w in qpos[rows, 3]]
        state.prev_y[rows] = qpos[rows, 1]
        state.best_x[rows] = qpos[rows, 0]
        state.stalled[rows] = 0
        state.steps[rows] = 0
        state.finished[rows] = False
        state.unstable[rows] = False

    def step(
        self,
        qpos: np.ndarray,
        qvel: np.ndarray,
        sensordata: np.ndarray,
        state: EpisodeState,
        obs: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Reward and episode end after one control step; updates `state` in place and writes
        the new observation (`observe`) into `obs` if given (the same compiled call).

        Returns reward (B,), terminated (B,), truncated (B,), and the reward terms (B, 5), in
        the order of REWARD_TERMS (they sum to the reward, but for a blown-up row's 0).
        """
        n = qpos.shape[0]
        reward, terms = np.empty(n), np.empty((n, len(REWARD_TERMS)))
        terminated, truncated = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
        _step(
            self._c,
            self._at,
            qpos,
            qvel,
            sensordata,
            state.prev_heading,
            state.prev_y,
            state.best_x,
            state.stalled,
            state.steps,
            state.finished,
            state.unstable,
            reward,
            terminated,
            truncated,
            terms,
            np.empty((n, self.obs_dim)) if obs is None else obs,
        )
        return reward, terminated, truncated, terms


HexapodTask = Task  # the name the hexapod's tests know it by
