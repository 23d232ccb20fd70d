"""A robot's terrain-walking task as a gymnasium.Env, on validated configs (from the YAML
defaults and gymnasium's ids: epoet.env_factory)."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

from epoet.envs.config import AgentConfig
from epoet.envs.model import Ground, action_to_ctrl, build_model, layout, stepper
from epoet.envs.spawn import spawn
from epoet.envs.task import REWARD_TERMS, EpisodeState, Task
from epoet.terrain import make_terrain
from epoet.terrain.config import TerrainConfig
from epoet.terrain.terrain import TerrainLike


class TerrainEnv(gym.Env):
    """A robot (the agent config's: the 18-DoF hexapod, the ant) walking towards the +x finish
    line of a heightfield terrain.

    Terrain swaps between episodes without recompiling: pass `options={"terrain": Terrain}` to
    `reset`, or call `set_terrain`. With no terrain given, the env makes one from its terrain
    config on the first reset (seeded by that reset's seed); `resample_terrain=True` makes a new
    one every episode, its maximum height following the config's schedule per episode.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        agent: AgentConfig,
        terrain: TerrainConfig,
        resample_terrain: bool = False,
        render_mode: str | None = None,
        width: int = 320,
        height: int = 240,
    ) -> None:
        self.agent_cfg, self.terrain_cfg = agent, terrain
        self.model = build_model(self.agent_cfg, self.terrain_cfg)
        self.data = mujoco.MjData(self.model)
        self._step = stepper(self.model)
        self.ground = Ground(self.model)
        self.layout = layout(self.model)
        self.task = Task(self.agent_cfg, self.layout, self.ground.half_x)
        self.resample_terrain = resample_terrain
        self.render_mode = render_mode
        self.render_size = (height, width)  # pixels of `render()`'s frames
        obs_dim, act_dim = self.task.obs_dim, self.task.act_dim
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float64)
        self.action_space: gym.spaces.Box = gym.spaces.Box(-1.0, 1.0, (act_dim,), np.float32)
        self.terrain: TerrainLike | None = None
        self.episodes = 0
        self._state = EpisodeState.zeros(1)
        self._obs = np.zeros((1, obs_dim))
        self._renderer: mujoco.Renderer | None = None

    def set_terrain(self, terrain: TerrainLike) -> None:
        """Swap the heightfield in place (takes effect now; call before `reset`)."""
        self.ground.set(self.model, terrain.heightmap, terrain.max_height, terrain.size)
        self.terrain = terrain
        mujoco.mj_forward(self.model, self.data)
        if self._renderer is not None:
            mujoco.mjr_uploadHField(self.model, self._renderer._mjr_context, 0)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        if "terrain" in options:
            self.set_terrain(options["terrain"])
        elif self.terrain is None or self.resample_terrain:
            terrain_seed = int(self.np_random.integers(2**31 - 1))
            self.set_terrain(
                make_terrain(self.terrain_cfg, seed=terrain_seed, iteration=self.episodes)
            )
        self.episodes += 1
        spawn(self.model, self.data, self.ground, self.agent_cfg, self.layout, self.np_random)
        qpos, qvel, sensordata = self._gather()
        self.task.begin(qpos, self._state, slice(None))
        self.task.observe(qpos, qvel, sensordata, self._obs)
        return self._obs[0].copy(), self._info(qpos)

    def step(self, action: np.ndarray):
        action = np.asarray(action, dtype=np.float64)
        if not np.isfinite(action).all():
            # MuJoCo would silently reset the simulation on a NaN control; a diverged policy
            # must be visible instead.
            raise ValueError(f"action contains NaN or inf: {action}")
        action_to_ctrl(self.layout, action, out=self.data.ctrl)
        self._step(self.model, self.data)
        qpos, qvel, sensordata = self._gather()
        reward, terminated, truncated, terms = self.task.step(
            qpos, qvel, sensordata, self._state, self._obs
        )
        info = self._info(qpos)
        info["reward_terms"] = dict(zip(REWARD_TERMS, terms[0].tolist()))
        return (
            self._obs[0].copy(),
            float(reward[0]),
            bool(terminated[0]),
            bool(truncated[0]),
            info,
        )

    def _gather(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = self.data
        return d.qpos[None, :], d.qvel[None, :], d.sensordata[None, :]

    def _info(self, qpos: np.ndarray) -> dict:
        x, y = qpos[0, 0], qpos[0, 1]
        return {
            "x": float(x),
            "finished": bool(self._state.finished[0]),
            "roughness": float(self.ground.roughness(x, y)[0]),
            "steps": int(self._state.steps[0]),
        }

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            height, width = self.render_size
            # The offscreen buffer (MJCF default 640 x 480) must hold the frame.
            vis = self.model.vis.global_
            vis.offwidth, vis.offheight = max(vis.offwidth, width), max(vis.offheight, height)
            self._renderer = mujoco.Renderer(self.model, height, width)
            mujoco.mjr_uploadHField(self.model, self._renderer._mjr_context, 0)
        self._renderer.update_scene(self.data, camera="track")
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
