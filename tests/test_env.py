"""The hexapod task: gymnasium/TorchRL conformance, reward formulas, contacts, spawn, episode end."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from epoet.core.schema import ConfigError
from epoet.env_factory import ENV_ID, action_to_targets, make_terrain_env
from epoet.envs.model import TerrainMismatchError, layout
from epoet.envs.task import REWARD_TERMS, EpisodeState, HexapodTask, heading_deviation, roll_pitch
from epoet.envs.terrain_env import TerrainEnv
from epoet.terrain import Terrain, make_terrain
from epoet.terrain.config import TerrainConfig


@pytest.mark.parametrize("kind", ["bowl", "cppn"])
def test_gymnasium_check_env(kind: str) -> None:
    env = make_terrain_env(terrain={"kind": kind, "grid": 40})
    check_env(env, skip_render_check=True)


def test_torchrl_check_env_specs() -> None:
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import check_env_specs

    env = GymWrapper(make_terrain_env(terrain={"kind": "bowl", "grid": 40}))
    check_env_specs(env, seed=0)


def test_import_epoet_registers_the_ids_without_the_training_stack() -> None:
    """`import epoet` alone registers the ids (and imports no MuJoCo, torch or Hydra), and
    gymnasium's `module:id` form works from a fresh interpreter."""
    code = (
        "import sys, gymnasium as gym, epoet\n"
        "heavy = [m for m in ('torch', 'mujoco', 'hydra', 'epoet.env_factory') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "assert gym.make('epoet/Hexapod-v0').observation_space.shape == (53,)\n"
    )
    for script in (code, "import gymnasium as gym; gym.make('epoet:epoet/Ant-v0').reset(seed=0)"):
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]


def test_registered_and_shapes(flat: Terrain) -> None:
    env = gym.make(ENV_ID, terrain={"kind": "bowl", "grid": 40})
    obs, info = env.reset(seed=0, options={"terrain": flat})
    assert obs.shape == (53,) and env.action_space.shape == (18,)
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    assert set(info) >= {"x", "finished", "roughness"}
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert obs.shape == (53,) and np.isfinite(reward)
    assert set(info["reward_terms"]) == {"velocity", "heading", "lateral", "penalty", "bonus"}
    assert np.isclose(sum(info["reward_terms"].values()), reward)
    assert set(np.unique(obs[47:53])) <= {0.0, 1.0}


def test_action_maps_to_targets() -> None:
    lo = action_to_targets(-np.ones(18))
    hi = action_to_targets(np.ones(18))
    np.testing.assert_allclose(lo[:3], [-0.6, -1.4, -0.8])
    np.testing.assert_allclose(hi[:3], [0.6, 0.4, 0.8])
    np.testing.assert_allclose(action_to_targets(np.zeros(18))[:3], [0.0, -0.5, 0.0])


def test_reward_terms_match_reference_formulas() -> None:
    env = make_terrain_env(terrain={"kind": "bowl", "grid": 40})
    task = HexapodTask(env.agent_cfg, layout(env.model), 10.0)
    rng = np.random.default_rng(0)
    qpos = np.zeros((1, 25))
    qvel = np.zeros((1, 24))
    sensordata = np.zeros((1, 24))
    yaw, tilt = 0.3, 0.1
    quat = np.array([np.cos(yaw / 2), np.sin(tilt / 2), 0.0, np.sin(yaw / 2)])
    qpos[0, :7] = [1.0, 0.2, 0.15, *(quat / np.linalg.norm(quat))]
    qvel[0, :3] = [0.3, -0.1, 0.05]
    sensordata[0, 6:] = rng.normal(0, 5, 18)
    state = EpisodeState.zeros(1)
    state.prev_heading[:] = 0.5
    state.prev_y[:] = -0.3
    state.best_x[:] = 0.0
    reward, terminated, truncated, terms = task.step(qpos, qvel, sensordata, state)
    terms = dict(zip(REWARD_TERMS, terms[0]))

    vx, vy, vz = qvel[0, :3]
    q = qpos[0, 3:7]
    dev = 2 * np.arccos(abs(q[0]))
    roll = np.arctan2(2 * (q[0] * q[1] + q[2] * q[3]), 1 - 2 * (q[1] ** 2 + q[2] ** 2))
    pitch = np.arcsin(2 * (q[0] * q[2] - q[3] * q[1]))
    r_vel = (1 / (abs(vx - 0.4) + 1) - 1 / 1.4) / (1 + 30 * vy**2)
    r_pos = 6 * r_vel + 10 * (0.5 - dev) + 10 * (0.3 - 0.2)
    r_neg = (
        0.1 * 0.2**2
        + 0.1 * dev**2
        + 0.5 * pitch**2
        + 0.5 * roll**2
        + 1e-4 * np.mean(sensordata[0, 6:] ** 2)
        + 0.7 * vz**2
    )
    assert reward[0] == pytest.approx(r_pos - r_neg, rel=1e-12)
    assert terms["velocity"] == pytest.approx(6 * r_vel)
    assert terms["penalty"] == pytest.approx(-r_neg)
    assert heading_deviation(q[0]) == pytest.approx(dev)
    assert roll_pitch(*q) == pytest.approx((roll, pitch))
    assert r_vel <= 1 - 1 / 1.4 + 1e-12  # the velocity term's maximum, reached at vx = 0.4
    assert not terminated[0] and not truncated[0]


def test_a_blown_up_row_ends_without_reward_and_leaves_the_others_alone() -> None:
    env = make_terrain_env(terrain={"kind": "bowl", "grid": 40})
    task = HexapodTask(replace(env.agent_cfg, finish_x=0.5), layout(env.model), 10.0)
    qpos = np.zeros((4, 25))
    qpos[:, 3] = 1.0
    qpos[:, 2] = 0.2
    qpos[:, 0] = 1.0
    qvel = np.full((4, 24), 0.1)
    sd = np.ones((4, 24))
    qpos[1, 5] = np.nan  # NaN
    qvel[2, 7] = 1e11  # beyond mjMAXVAL
    qpos[3, 8] = np.inf  # infinite
    state = EpisodeState.zeros(4)
    reward, terminated, truncated, _ = task.step(qpos, qvel, sd, state)
    np.testing.assert_array_equal(state.unstable, [False, True, True, True])
    np.testing.assert_array_equal(reward[1:], 0.0)  # every row crossed the line: no bonus either
    np.testing.assert_array_equal(state.finished, [True, False, False, False])
    assert terminated.all() and not truncated.any()
    alone = EpisodeState.zeros(1)
    assert reward[0] == task.step(qpos[:1], qvel[:1], sd[:1], alone)[0][0]
    assert reward[0] > 400  # the finish bonus
    obs = task.observe(qpos, qvel, sd, np.empty((4, 53)))
    stepped = np.full((4, 53), np.nan)
    task.step(qpos, qvel, sd, EpisodeState.zeros(4), stepped)  # step observes as observe does
    np.testing.assert_array_equal(stepped, obs)
    assert np.isfinite(obs).all() and obs[1, 42:46].tolist() == [1.0, 0.0, 0.0, 0.0]
    assert obs[3, 1] == 0.0 and obs[2, 19] == 1e11  # inf reads as zero, finite values stay


def test_finish_bonus_paid_once() -> None:
    env = make_terrain_env(terrain={"kind": "bowl", "grid": 40})
    task = HexapodTask(replace(env.agent_cfg, finish_x=6.0), layout(env.model), 10.0)
    qpos = np.zeros((1, 25))
    qpos[0, 3] = 1.0
    qpos[0, 2] = 0.1
    qvel = np.zeros((1, 24))
    sd = np.zeros((1, 24))
    state = EpisodeState.zeros(1)
    qpos[0, 0] = 5.9
    bonus = REWARD_TERMS.index("bonus")
    assert task.step(qpos, qvel, sd, state)[3][0, bonus] == 0.0
    qpos[0, 0] = 6.1
    _, terminated, _, terms = task.step(qpos, qvel, sd, state)
    assert terms[0, bonus] == 500.0 and terminated[0] and state.finished[0]
    assert task.step(qpos, qvel, sd, state)[3][0, bonus] == 0.0


def test_finish_in_env_reports_finished(flat: Terrain) -> None:
    env = make_terrain_env(terrain={"kind": "bowl", "grid": 40})
    env.reset(seed=0, options={"terrain": flat})
    env.data.qpos[0] = env.agent_cfg.finish_x + 0.01  # carried over the line
    _, reward, terminated, _, info = env.step(np.zeros(18))
    assert terminated and info["finished"] and info["reward_terms"]["bonus"] == 500.0


def _settle(env: TerrainEnv, action: np.ndarray, steps: int) -> np.ndarray:
    obs = None
    for _ in range(steps):
        obs, *_ = env.step(action)
    return obs


def test_contacts_standing_and_lifted_leg(flat: Terrain) -> None:
    env = make_terrain_env(
        agent={"spawn_yaw": 0.0, "spawn_vel_std": 0.0}, terrain={"kind": "bowl", "grid": 40}
    )
    env.reset(seed=0, options={"terrain": flat})
    stand = np.zeros(18)
    stand[1::3] = 0.2  # femurs slightly down: body lifted on six feet
    obs = _settle(env, stand, 60)
    np.testing.assert_array_equal(obs[47:53], np.ones(6))
    lifted = stand.copy()
    lifted[1] = -1.0  # front-left femur fully up
    obs = _settle(env, lifted, 40)
    assert obs[47] == 0.0, "the lifted front-left foot must not report contact"
    assert obs[48:53].sum() >= 4, "the other feet stay on the ground"


@pytest.mark.parametrize("integrator", ["rk4", "implicitfast"])
def test_contact_flags_describe_the_state_after_the_step(
    integrator: str, terrain_cfg: TerrainConfig
) -> None:
    """Joint angles and contact flags describe one instant: the state the step ended in."""
    env = make_terrain_env(agent={"integrator": integrator, "spawn_yaw": 0.0}, terrain=terrain_cfg)
    obs, _ = env.reset(seed=1)
    current = mujoco.MjData(env.model)
    contacts = layout(env.model).contact
    rng = np.random.default_rng(0)
    flags = []
    for _ in range(300):
        obs, *_ = env.step(rng.uniform(-1.0, 1.0, 18))
        mujoco.mj_copyData(current, env.model, env.data)
        mujoco.mj_forward(env.model, current)  # everything recomputed from this state alone
        np.testing.assert_array_equal(obs[47:53], current.sensordata[contacts] > 0)
        np.testing.assert_array_equal(obs[0:18], current.qpos[7:25])
        flags.append(obs[47:53].copy())
    flags = np.array(flags)
    assert 0.05 < flags.mean() < 0.95 and (np.diff(flags, axis=0) != 0).any()


def test_robot_geoms_never_collide_with_each_other(terrain_cfg: TerrainConfig) -> None:
    """As the reference's robot (conaffinity 0): in a crouch with every tibia folded onto its
    coxa (past the tibia's limit; the old model reported 6 self-contacts here) no contact joins
    two robot geoms, while the torso resting on the ground still touches it."""
    env = make_terrain_env(terrain=replace(terrain_cfg, max_height=0.0))  # flat ground
    env.reset(seed=0)
    model, data = env.model, env.data
    terrain = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "terrain")
    robot = [g for g in range(model.ngeom) if g != terrain]
    for a in robot:  # MuJoCo's filter: contype of one & conaffinity of the other
        assert model.geom_contype[a] & model.geom_conaffinity[terrain]
        for b in robot:
            assert not model.geom_contype[a] & model.geom_conaffinity[b]
    mujoco.mj_resetData(model, data)
    data.qpos[:3] = env.agent_cfg.start_x, 0.0, 0.01  # the torso on the ground
    data.qpos[3] = 1.0
    data.qpos[7:] = np.tile([0.0, 0.3, 2.0], 6)
    mujoco.mj_forward(model, data)
    pairs = [(c.geom1, c.geom2) for c in data.contact[: data.ncon]]
    assert pairs and all(terrain in pair for pair in pairs)


def test_spawn_above_local_ground_on_rough_terrain(terrain_cfg: TerrainConfig) -> None:
    cfg = replace(terrain_cfg, max_height=1.5, max_height_step=0.0)
    env = make_terrain_env(agent={"settle_steps": 0}, terrain=cfg)
    for seed in range(5):
        rough = make_terrain(cfg, seed=seed)
        env.reset(seed=seed, options={"terrain": rough})
        x, y, z = env.data.qpos[:3]
        assert z >= env.ground.max_around(x, y, 0.35) + env.agent_cfg.spawn_clearance - 1e-9
        mujoco.mj_forward(env.model, env.data)
        assert all(env.data.contact.dist >= -1e-6), "spawned inside the terrain"


def test_no_progress_rule_ends_episode(flat: Terrain) -> None:
    env = make_terrain_env(
        agent={"no_progress_steps": 15, "spawn_vel_std": 0.0}, terrain={"kind": "bowl", "grid": 40}
    )
    env.reset(seed=0, options={"terrain": flat})
    for step in range(1, 300):
        _, _, terminated, truncated, info = env.step(np.zeros(18))  # standing still
        if terminated or truncated:
            break
    assert truncated and not terminated
    assert step < 300 and env.unwrapped._state.stalled[0] > 15


def test_max_episode_steps_truncates(flat: Terrain) -> None:
    env = make_terrain_env(agent={"max_episode_steps": 25}, terrain={"kind": "bowl", "grid": 40})
    env.reset(seed=0, options={"terrain": flat})
    for step in range(1, 26):
        *_, terminated, truncated, _ = env.step(np.zeros(18))
    assert truncated and not terminated and step == 25


def test_terrain_swap_without_recompiling(terrain_cfg: TerrainConfig) -> None:
    env = make_terrain_env(terrain=terrain_cfg)
    model = env.model
    a, b = make_terrain(terrain_cfg, seed=1), make_terrain(terrain_cfg, seed=2)
    env.reset(seed=0, options={"terrain": a})
    data_a = model.hfield_data.copy()
    env.reset(seed=0, options={"terrain": b})
    assert env.model is model and not np.array_equal(model.hfield_data, data_a)
    # Physical relief is S (not S^2): the highest sample stands max_height above zero.
    assert env.ground.heights.max() == pytest.approx(b.max_height)
    assert model.hfield_data.max() * model.hfield_size[0, 2] == pytest.approx(b.max_height)


def test_resample_terrain_every_episode(terrain_cfg: TerrainConfig) -> None:
    env = make_terrain_env(terrain=terrain_cfg, resample_terrain=True)
    env.reset(seed=0)
    first = env.terrain
    env.reset()
    assert env.terrain.id != first.id
    assert env.terrain.max_height > first.max_height  # the height schedule advances per episode


def test_roughness_is_patch_variance(terrain_cfg: TerrainConfig) -> None:
    env = make_terrain_env(terrain=terrain_cfg)
    terrain = make_terrain(terrain_cfg, seed=3)
    env.set_terrain(terrain)
    r, c = 20, 10
    x = (c / (terrain.grid - 1) * 2 - 1) * terrain_cfg.size / 2
    y = (r / (terrain.grid - 1) * 2 - 1) * terrain_cfg.size / 2
    expected = (terrain.heightmap[r - 2 : r + 3, c - 2 : c + 3] * terrain.max_height).var()
    assert env.ground.roughness(x, y)[0] == pytest.approx(expected)


def test_bad_input_is_clear(flat: Terrain, terrain_cfg: TerrainConfig) -> None:
    with pytest.raises(ConfigError, match="terrain.kind"):
        make_terrain_env(terrain={"kind": "lava"})
    with pytest.raises(ConfigError, match="terrain.grid"):
        make_terrain_env(terrain={"grid": -5})
    with pytest.raises(ConfigError, match="max_episode_steps"):
        make_terrain_env(agent={"max_episode_steps": 0})
    env = make_terrain_env(terrain=terrain_cfg)
    too_big = Terrain(np.zeros((50, 50)), 0.0, 20.0, "bowl", 0)
    with pytest.raises(TerrainMismatchError, match="heightfield"):
        env.set_terrain(too_big)
    with pytest.raises(TerrainMismatchError, match="elevation"):
        env.set_terrain(Terrain(np.zeros((40, 40)), 5.0, 40.0, "bowl", 0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(18, np.nan))
