"""The locomotion task, vectorised over a batch of robots: observation, reward, episode end.

Both the gymnasium env (a batch of one) and the ES rollout engine (hundreds of robots stepped in
lockstep) call this one implementation, so the reward ES optimises is the reward the RL baselines
see. Inputs are raw MuJoCo arrays gathered per step: qpos (B, 25), qvel (B, 24), sensordata (B, 24).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from epoet.config import AgentConfig
from epoet.envs.model import Layout

OBS_DIM = 53
ACT_DIM = 18
# MuJoCo's own bound on a sane state value (mjMAXVAL): beyond it, or NaN, the physics blew up.
MAX_STATE = 1e10
REWARD_TERMS = ("velocity", "heading", "lateral", "penalty", "bonus")


@dataclass
class EpisodeState:
    """Per-robot episode bookkeeping, arrays of shape (B,)."""

    prev_heading: np.ndarray
    prev_y: np.ndarray
    best_x: np.ndarray
    stalled: np.ndarray     # consecutive steps without a new best x
    steps: np.ndarray
    finished: np.ndarray    # finish line crossed (the bonus is paid once)
    unstable: np.ndarray    # the physics blew up in the last step (the episode ended on it)

    @classmethod
    def zeros(cls, batch: int) -> "EpisodeState":
        f = lambda: np.zeros(batch)  # noqa: E731
        return cls(f(), f(), f(), np.zeros(batch, np.int64), np.zeros(batch, np.int64),
                   np.zeros(batch, bool), np.zeros(batch, bool))


def heading_deviation(quat: np.ndarray) -> np.ndarray:
    """Total rotation angle of the torso, 2 acos(|qw|), in [0, pi] (q and -q fold together)."""
    return 2.0 * np.arccos(np.clip(np.abs(quat[..., 0]), 0.0, 1.0))


def roll_pitch(quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (ZYX Euler) of (w, x, y, z) quaternions."""
    w, x, y, z = (quat[..., i] for i in range(4))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    return roll, pitch


class HexapodTask:
    """Observation, reward and termination of the paper's task (REFERENCE.md sections 1-3)."""

    def __init__(self, agent: AgentConfig, layout: Layout, half_size: float) -> None:
        self.cfg = agent
        self.rw = agent.reward
        self.layout = layout
        self.half_size = half_size
        self._v_ref = 1.0 / (1.0 + self.rw.target_speed)

    def observe(self, qpos: np.ndarray, qvel: np.ndarray, sensordata: np.ndarray,
                out: np.ndarray) -> np.ndarray:
        """53 dims: 18 joint angles, 18 joint velocities, torso linear + angular velocity,
        torso quaternion (w, x, y, z), torso y, 6 foot contacts (1 when the foot touches)."""
        lay = self.layout
        out[:, 0:18] = qpos[:, lay.joint_qpos]
        out[:, 18:36] = qvel[:, lay.joint_qvel]
        out[:, 36:42] = qvel[:, 0:6]
        out[:, 42:46] = qpos[:, 3:7]
        out[:, 46] = qpos[:, 1]
        np.greater(sensordata[:, lay.contact], 0.0, out=out[:, 47:53])
        # A blown-up robot's (terminal) observation is stored as zeros, never NaN: a replay
        # buffer multiplies terminal next-observations' values by zero, and NaN * 0 is NaN.
        # (The check is cheap; nan_to_num itself costs ~20 us a step, paid only on a blow-up.)
        if not np.isfinite(out).all():
            np.nan_to_num(out, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        return out

    def begin(self, qpos: np.ndarray, state: EpisodeState, rows: np.ndarray | slice) -> None:
        """Start episodes for `rows` from their (settled) initial state."""
        state.prev_heading[rows] = heading_deviation(qpos[rows, 3:7])
        state.prev_y[rows] = qpos[rows, 1]
        state.best_x[rows] = qpos[rows, 0]
        state.stalled[rows] = 0
        state.steps[rows] = 0
        state.finished[rows] = False
        state.unstable[rows] = False

    def step(self, qpos: np.ndarray, qvel: np.ndarray, sensordata: np.ndarray,
             state: EpisodeState) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Reward and episode end after one control step; updates `state` in place.

        Returns reward (B,), terminated (B,), truncated (B,), and the reward terms (B,) each.
        """
        rw = self.rw
        x, y = qpos[:, 0], qpos[:, 1]
        vx, vy, vz = qvel[:, 0], qvel[:, 1], qvel[:, 2]
        quat = qpos[:, 3:7]
        heading = heading_deviation(quat)
        roll, pitch = roll_pitch(quat)

        velocity = (1.0 / (np.abs(vx - rw.target_speed) + 1.0) - self._v_ref) \
            / (1.0 + rw.lateral_speed_penalty * vy * vy)
        # Correcting heading and lateral drift is rewarded as a potential difference (Azayev et al.).
        heading_gain = np.abs(state.prev_heading) - heading
        lateral_gain = np.abs(state.prev_y) - np.abs(y)
        force = sensordata[:, self.layout.actuator_force]
        penalty = (rw.c_lateral * y * y + rw.c_heading * heading * heading
                   + rw.c_pitch * pitch * pitch + rw.c_roll * roll * roll
                   + rw.c_actuator * np.mean(force * force, axis=1) + rw.c_vertical * vz * vz)
        crossed = (x >= self.cfg.finish_x) & ~state.finished
        bonus = np.where(crossed, rw.finish_bonus, 0.0)
        reward = (rw.w_velocity * velocity + rw.w_heading * heading_gain
                  + rw.w_lateral * lateral_gain - penalty + bonus)

        state.prev_heading[:] = heading
        state.prev_y[:] = y
        state.finished |= crossed
        # Progress is a new best x by more than a margin, so a robot jittering in place stalls
        # while slow but steady walking (the margin accumulates over steps) does not.
        progressed = x > state.best_x + self.cfg.progress_margin
        state.best_x[:] = np.where(progressed, x, state.best_x)
        state.stalled[:] = np.where(progressed, 0, state.stalled + 1)
        state.steps += 1

        # A physics blow-up (NaN, Inf or a huge state; MuJoCo's automatic reset is disabled in
        # build_model) ends the episode as a fall would, and its step earns nothing: the
        # episode's return is what it earned while the physics was sound.
        # One whole-batch test per step (NaN fails it too); rows are sorted out only when it
        # fails, which is rare, so the rollout hot path pays ~8 us instead of ~17.
        if np.abs(qvel).max() <= MAX_STATE and np.abs(qpos).max() <= MAX_STATE:
            state.unstable[:] = False
        else:
            state.unstable[:] = ~((np.abs(qpos) <= MAX_STATE).all(axis=1)
                                  & (np.abs(qvel) <= MAX_STATE).all(axis=1))
            reward[state.unstable] = 0.0
            state.finished &= ~state.unstable
        # Falling off: below the terrain's lowest point (height 0) or past its edge.
        fell = (qpos[:, 2] < 0.0) | (np.abs(x) > self.half_size) | (np.abs(y) > self.half_size)
        terminated = state.finished | fell | state.unstable
        truncated = ~terminated & ((state.steps >= self.cfg.max_episode_steps)
                                   | (state.stalled > self.cfg.no_progress_steps))
        terms = {"velocity": rw.w_velocity * velocity, "heading": rw.w_heading * heading_gain,
                 "lateral": rw.w_lateral * lateral_gain, "penalty": -penalty, "bonus": bonus}
        return reward, terminated, truncated, terms
