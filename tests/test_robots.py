"""The robot as a part (docs/architecture.md "Adding a robot"): the ant from gymnasium's MJCF
walks the hexapod's task by the same observation rule, every algorithm trains it and its agents
are evaluated and served; agent files carry their robot, and a file or a start made for another
robot is refused in one sentence."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import gymnasium as gym
import mlflow
import mujoco
import numpy as np
import pytest

import epoet.env_factory  # noqa: F401  (registers the envs)
from conftest import ACT_DIM, OBS_DIM, TINY_EPOET, authors, tiny_run
from epoet.config import load, saved_agent
from epoet.core.checkpoint import load_checkpoint
from epoet.core.schema import ConfigError
from epoet.envs.model import layout
from epoet.envs.spaces import layout_of, observation_names, robot_sizes
from epoet.eval.agents import AgentError, policy_in, resolve_run
from epoet.eval.reference.layout import LEGS, SEGMENTS
from epoet.registry import names
from epoet.rollout.agent_files import LAYOUT, check_robot
from epoet.rollout.policy import init_params
from epoet.run import prepare, run

ANT = "epoet/Ant-v0"
ANT_JOINTS = ["hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3", "hip_4", "ankle_4"]


def test_the_ant_observes_by_the_hexapods_rule() -> None:
    """31 entries named by epoet.envs.spaces, each read from the state the step ended in: its
    8 joints' angles and velocities, the torso's velocities, quaternion and y, 4 foot contacts."""
    env = gym.make(ANT, terrain={"kind": "cppn", "grid": 40}).unwrapped
    names = observation_names(ANT_JOINTS, env.agent_cfg.feet)
    assert env.observation_space.shape == (len(names),) == (31,)
    assert env.action_space.shape == (8,) and robot_sizes(env.agent_cfg) == (31, 8)
    env.reset(seed=0)
    current, rng, flags = mujoco.MjData(env.model), np.random.default_rng(0), []
    for _ in range(200):
        obs, *_ = env.step(rng.uniform(-1.0, 1.0, 8))
        mujoco.mj_copyData(current, env.model, env.data)
        mujoco.mj_forward(env.model, current)
        q, v = current.qpos, current.qvel
        contacts = current.sensordata[layout(env.model).contact] > 0
        expected = np.concatenate([q[7:15], v[6:14], v[0:6], q[3:7], q[1:2], contacts])
        np.testing.assert_array_equal(obs, expected)
        flags.append(contacts)
    assert 0.05 < np.mean(flags) < 0.95, "the feet touch the terrain, not always"
    assert names[16:27] == [f"torso.{e}" for e in ("vx", "vy", "vz", "wx", "wy", "wz")] + [
        f"torso.{e}" for e in ("qw", "qx", "qy", "qz", "y")
    ]


def test_each_action_drives_its_joints_actuator_and_force() -> None:
    """The ant's MJCF lists its motors from hip_4; the action and the forces follow its joints."""
    env = gym.make(ANT, terrain={"kind": "bowl", "grid": 40}).unwrapped
    model, data = env.model, env.data
    env.reset(seed=0)
    for j, name in enumerate(ANT_JOINTS):
        action = np.zeros(8)
        action[j] = 1.0
        env.step(action)
        driven = np.flatnonzero(data.ctrl != 0.0)
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert len(driven) == 1 and model.actuator_trnid[driven[0], 0] == joint
        assert data.ctrl[driven[0]] == 1.0  # the ant's motors: ctrlrange [-1, 1]
        # its force sensor, in the joints' order (a motor's actuator force is its control)
        forces = data.sensordata[layout(model).actuator_force]
        assert forces[j] == 1.0 and np.count_nonzero(forces) == 1
    assert model.actuator_trnid[0, 0] != 1, "the MJCF's own order is not the joints'"


def test_the_ant_spawns_above_the_ground_and_settles_standing() -> None:
    env = gym.make(ANT, terrain={"kind": "cppn", "grid": 40, "max_height": 1.0}).unwrapped
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        data = env.data
        assert all(data.contact.dist[: data.ncon] >= -0.02)  # resting on it, not inside
        assert obs[-4:].sum() >= 3, "it stands on its feet"
        x, y = data.qpos[:2]
        assert data.qpos[2] > env.ground.max_around(x, y, 0.3) + 0.2  # torso above the ground


def test_the_hexapods_leg_order_is_its_configs() -> None:
    """The authors' agents are converted into the hexapod's joints and feet as its YAML lists
    them (epoet/eval/reference/layout.py)."""
    hexapod = load(["agent=hexapod"]).agent
    assert hexapod.joints == [f"{leg}_{seg}" for leg in LEGS for seg in SEGMENTS]
    assert hexapod.feet == [f"{leg}_tibia" for leg in LEGS]
    assert robot_sizes(hexapod) == (OBS_DIM, ACT_DIM) == (53, 18)


@pytest.mark.parametrize(
    "override, message",
    [
        ("agent.feet=[left_ankle_geom,nose]", "agent.feet: ant.xml has no geom 'nose'"),
        ("agent.joints=[hip_1,hip_2]", "agent.joints must be the MJCF's joints after the root"),
        ("agent.mjcf=gymnasium:envs/mujoco/assets/no_robot.xml", "agent.mjcf names no file"),
    ],
)
def test_a_robot_that_does_not_fit_its_mjcf_is_one_sentence(
    compose, override: str, message: str, tmp_path: Path
) -> None:
    with pytest.raises(ConfigError, match=message):
        prepare(compose(["agent=ant", override]), tmp_path / "run")
    assert not (tmp_path / "run").exists()


def _agent_file(path: Path, sizes: tuple[int, ...], layout: dict | None) -> Path:
    arrays = {"theta": init_params(0, sizes), "layer_sizes": np.array(sizes)}
    if layout is not None:
        arrays[LAYOUT] = np.array(json.dumps(layout))
    np.savez(path, **arrays)
    return path


def test_an_agent_file_runs_only_on_the_robot_it_records(tmp_path: Path) -> None:
    hexapod, ant = load(["agent=hexapod"]).agent, load(["agent=ant"]).agent
    old = _agent_file(tmp_path / "old.npz", (53, 8, 18), None)  # before robots were parts
    check_robot(old, "es", hexapod)
    with pytest.raises(AgentError, match="was trained on the hexapod, not on the ant"):
        check_robot(old, "es", ant)
    mine = _agent_file(tmp_path / "ant.npz", (31, 8, 8), layout_of(ant))
    check_robot(mine, "es", ant)
    with pytest.raises(AgentError, match="was trained on the ant, not on the hexapod"):
        resolve_run(str(mine)).agent_config(hexapod)  # a bare file runs on agent=<robot>
    moved = dict(layout_of(ant), action=ANT_JOINTS[::-1])
    with pytest.raises(AgentError, match="observation or action layout"):
        check_robot(_agent_file(tmp_path / "moved.npz", (31, 8, 8), moved), "es", ant)
    theirs = authors("agents", "poet_hexA8", "flat.npz")
    check_robot(theirs, "es", hexapod)
    paper = dataclasses.replace(hexapod, integrator="rk4")  # they record no integrator
    assert resolve_run(str(theirs)).agent_config(paper).integrator == "rk4"
    with pytest.raises(AgentError, match="trained on the hexapod, not on the ant"):
        check_robot(theirs, "es", ant)


def test_a_config_from_before_robots_is_the_hexapods() -> None:
    today = load(["agent=hexapod"]).agent
    old = {k: v for k, v in vars(today).items() if k not in ("mjcf", "joints", "feet")}
    assert saved_agent(old)["mjcf"] == today.mjcf and saved_agent(old)["feet"] == today.feet


def test_the_ant_starts_epoet_sac_cold_and_refuses_the_authors_hexapod_sac(
    compose, tmp_path: Path
) -> None:
    assert load(["agent=ant", "algo=epoet_sac"]).algo.sac_init is None
    assert load(["algo=epoet_sac"]).algo.sac_init is None
    authors()  # the refusal below reads the authors' SAC agent first
    with pytest.raises(ConfigError, match="not this robot's published SAC agent.*starts cold"):
        prepare(
            compose(["agent=ant", "algo=epoet_sac", "algo.sac_init=reference:sac/42"]),
            tmp_path / "run",
        )


@pytest.mark.parametrize("algo", names())
def test_every_algorithm_trains_the_ant_and_its_agent_is_evaluated_and_served(
    algo: str, compose, mlflow_uri: str, tmp_path: Path
) -> None:
    """`python -m epoet agent=ant algo=<algo> budget=smoke`, tiny: it trains, its exported
    agent records the ant, the end-of-run evaluation runs it on the shipped suite, and its
    MLflow model acts on the ant's observations."""
    folder = tmp_path / "run"
    run(compose(["agent=ant", *tiny_run(algo), "evaluate=true"]), folder)
    found = policy_in(folder)
    assert found is not None
    trained = resolve_run(str(folder), mlflow_uri)
    assert trained.agent_config(load([]).agent).name == "ant"
    # the bare agent file runs with the integrator it was trained with, not evaluation's RK4
    trained_with = load(["agent=ant", "budget=smoke"]).agent.integrator
    evaluation_default = dataclasses.replace(load(["agent=ant"]).agent, integrator="rk4")
    assert trained_with != "rk4"
    bare = resolve_run(str(found[0].path))
    assert bare.agent_config(evaluation_default).integrator == trained_with
    run_id = load_checkpoint(folder / "checkpoint.pkl")["run_id"]
    record = mlflow.MlflowClient(mlflow_uri).get_run(run_id).data
    assert record.tags["agent"] == "ant" and "suite/shipped/success_rate" in record.metrics
    assert (folder / "evaluation" / "shipped" / "episodes.csv").is_file()
    model = mlflow.pyfunc.load_model(f"runs:/{run_id}/agent")
    observations = np.random.default_rng(0).normal(size=(3, 31))
    actions = model.predict(observations)
    assert actions.shape == (3, 8)
    policy = found[0].load()
    np.testing.assert_allclose(actions, [policy(o) for o in observations], rtol=1e-6, atol=1e-7)


def test_a_run_logs_its_first_walker_once(compose, mlflow_uri: str, tmp_path: Path) -> None:
    """walker/*: what the run took until an evaluation first reached the reproduction threshold
    (here: any score), logged at that iteration only."""
    run(compose([*TINY_EPOET, "agent=ant", "algo.repro_threshold=-100000"]), tmp_path / "run")
    run_id = load_checkpoint(tmp_path / "run" / "checkpoint.pkl")["run_id"]
    client = mlflow.MlflowClient(mlflow_uri)
    history = client.get_metric_history(run_id, "walker/cpu_time")
    assert [m.step for m in history] == [0]
    steps = client.get_metric_history(run_id, "walker/env_steps")[0].value
    assert steps == client.get_metric_history(run_id, "env_steps")[0].value > 0


def test_tables_read_an_ant_experiment_and_keep_robots_apart(
    compose, mlflow_uri: str, tmp_path: Path
) -> None:
    from analysis.store import AnalysisError
    from analysis.tables import make_tables

    tiny = [*TINY_EPOET, "budget.iterations=1"]
    run(compose(["agent=ant", *tiny, "evaluate=true"]), tmp_path / "ant")
    written = make_tables("epoet", tmp_path / "results")
    table1 = next(p for p in written if p.name.startswith("table1") and p.suffix == ".csv")
    assert "epoet" in table1.read_text()
    run(compose([*tiny, "evaluate=true"]), tmp_path / "hexapod")
    with pytest.raises(AnalysisError, match=r"several robots \(ant, hexapod\)"):
        make_tables("epoet", tmp_path / "again")


def test_render_films_an_ant_agent_and_refuses_it_on_the_hexapod(tmp_path: Path) -> None:
    """Checked before MuJoCo picks its GL backend: one line naming the robot; with agent=ant
    the film (where this machine can render offscreen)."""
    from test_render import decoded, one_error_line, render_cli, skip_without_gl

    ant = load(["agent=ant"]).agent
    policy = _agent_file(tmp_path / "ant.npz", (31, 8, 8), layout_of(ant))
    args = [f"run={policy}", "terrain=r0l0", "steps=3", "width=64", "height=48"]
    line = one_error_line(render_cli(*args, cwd=tmp_path))
    assert "was trained on the ant, not on the hexapod" in line
    proc = render_cli(*args, "agent=ant", f"out={tmp_path / 'ant.mp4'}", cwd=tmp_path)
    skip_without_gl(proc)
    assert proc.returncode == 0, proc.stderr
    assert len(decoded(tmp_path / "ant.mp4")) == 4
