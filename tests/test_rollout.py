"""The batched rollout engine and the evaluation backends, on real MuJoCo physics."""

from __future__ import annotations

import os
import signal
import time
from dataclasses import replace

import numpy as np
import pytest

from conftest import ES_SIZES
from epoet.config import load
from epoet.envs.model import TerrainMismatchError
from epoet.envs.terrain_env import TerrainEnv
from epoet.rollout.engine import RolloutEngine
from epoet.rollout.evaluators import make_evaluator
from epoet.rollout.policy import forward, init_params
from epoet.rollout.populations import Agents, Mirrored, Request, mirrored_population
from epoet.terrain import Terrain, make_terrain

PAPER = load(["budget=paper"])  # the paper's agent (RK4) and CPPN terrain
BOWL = load(["algo=ppo", "budget=paper"]).terrain
TERRAIN_CFG = replace(PAPER.terrain, grid=40, max_height=0.3)
# Episodes end at different times: stalls after 8 steps without progress, 40 steps at most.
AGENT = replace(PAPER.agent, max_episode_steps=40, no_progress_steps=8)
# Spawned 0.05 m before the finish line, about a third of the robots start past it.
NEAR_FINISH = replace(PAPER.agent, max_episode_steps=40, start_x=5.95, finish_x=6.0)


@pytest.fixture(scope="module")
def terrain() -> Terrain:
    return make_terrain(TERRAIN_CFG, seed=1, iteration=10)


def population(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n different policies (std 0.3 makes them act differently) and n spawn seeds."""
    params = np.stack([init_params(seed * 1000 + i, ES_SIZES, std=0.3) for i in range(n)])
    return params, np.arange(n) + 100 * seed


@pytest.mark.parametrize("integrator", ["rk4", "implicitfast"])
def test_engine_reproduces_the_gym_env_episode_for_episode(terrain, integrator):
    agent = replace(AGENT, integrator=integrator)
    params, seeds = population(4, seed=3)
    # batch 2 < 4 episodes: slots are refilled as episodes end.
    episodes = RolloutEngine(agent, TERRAIN_CFG, 2, ES_SIZES).run(terrain, params, seeds)
    env = TerrainEnv(agent=agent, terrain=TERRAIN_CFG)
    for e in range(len(seeds)):
        obs, _ = env.reset(seed=int(seeds[e]), options={"terrain": terrain})
        total, steps, done, info = 0.0, 0, False, {}
        while not done:
            obs, reward, terminated, truncated, info = env.step(forward(params[e], obs, ES_SIZES))
            total, steps, done = total + reward, steps + 1, terminated or truncated
        assert episodes.returns[e] == pytest.approx(total, abs=1e-9)
        assert episodes.lengths[e] == steps
        assert episodes.finished[e] == info["finished"]
    assert len(set(episodes.lengths.tolist())) > 1  # the refill path was exercised


def test_results_do_not_depend_on_batch_size(terrain):
    params, seeds = population(6, seed=4)
    runs = [
        RolloutEngine(AGENT, TERRAIN_CFG, b, ES_SIZES).run(terrain, params, seeds, record=True)
        for b in (1, 4, 8)
    ]
    assert len(set(runs[0].lengths.tolist())) >= 3  # slots free up at different steps
    for other in runs[1:]:
        np.testing.assert_array_equal(other.returns, runs[0].returns)
        np.testing.assert_array_equal(other.lengths, runs[0].lengths)
        for key, value in runs[0].transitions.items():
            np.testing.assert_array_equal(other.transitions[key], value)


def test_finished_episodes_stop_while_others_run_on(terrain):
    params, seeds = population(8, seed=2)
    engine = RolloutEngine(NEAR_FINISH, TERRAIN_CFG, 8, ES_SIZES)
    episodes = engine.run(terrain, params, seeds)
    finished = episodes.finished
    assert finished.any() and not finished.all()
    assert episodes.lengths[finished].max() < episodes.lengths[~finished].min()
    assert (episodes.returns[finished] > 400).all()  # the finish bonus of 500
    # With 8 slots for 8 episodes each MjData ran exactly one episode: its clock shows that a
    # finished episode's physics stopped (settling steps + its own length), not the longest one.
    dt, settle = NEAR_FINISH.timestep, NEAR_FINISH.settle_steps
    clocks = engine._sims.time.copy()
    np.testing.assert_allclose(clocks, (settle + episodes.lengths) * dt)


def test_recorded_transitions_add_up_to_the_returns(terrain):
    params, seeds = population(5, seed=3)
    episodes = RolloutEngine(AGENT, TERRAIN_CFG, 3, ES_SIZES).run(
        terrain, params, seeds, record=True
    )
    t = episodes.transitions
    assert len(t["reward"]) == episodes.lengths.sum()
    for e in range(len(seeds)):
        mine = t["episode"] == e
        # recorded in float32 (SAC's replay): sums and actions to float32 precision
        assert t["reward"].dtype == t["obs"].dtype == t["action"].dtype == np.float32
        assert t["reward"][mine].sum(dtype=np.float64) == pytest.approx(
            episodes.returns[e], rel=1e-5, abs=1e-4
        )
        np.testing.assert_array_equal(t["obs"][mine][1:], t["next_obs"][mine][:-1])
        np.testing.assert_allclose(
            t["action"][mine][0],
            forward(params[e], t["obs"][mine][0].astype(np.float64), ES_SIZES),
            rtol=1e-4,
            atol=1e-5,
        )
        assert not t["terminated"][mine][:-1].any()


def test_one_and_two_workers_give_identical_results(terrain):
    theta = init_params(7, ES_SIZES)
    es = Request(terrain, Mirrored.of(theta, np.array([11, 12, 13]), 0.05, np.array([21, 22, 23])))
    evaluation = Request(terrain, Agents.of(np.stack([theta, -theta]), np.array([5, 6])))
    with (
        make_evaluator(AGENT, TERRAIN_CFG, 1, 2, ES_SIZES) as one,
        make_evaluator(AGENT, TERRAIN_CFG, 2, 2, ES_SIZES) as two,
    ):
        (returns,) = [e.returns for e in one.run([es])]
        np.testing.assert_array_equal(two.run([es])[0].returns, returns)
        evaluation = evaluation._replace(record=len(evaluation.population))  # record them all
        (ev1,), (ev2,) = one.run([evaluation]), two.run([evaluation])
        assert ev1.returns.shape == (2, 2)
        np.testing.assert_array_equal(ev2.returns, ev1.returns)
        for key, value in ev1.transitions.items():
            np.testing.assert_array_equal(ev2.transitions[key], value)
        # A worker's exception reaches the caller with its type, and the pool carries on.
        wrong_grid = make_terrain(replace(BOWL, grid=20), seed=0)
        with pytest.raises(TerrainMismatchError):
            two.run([es._replace(terrain=wrong_grid)])
        np.testing.assert_array_equal(two.run([es])[0].returns, returns)
        # A worker that died (killed here) is replaced, and the call gives the same results.
        # (Once the executor has seen the death: a call made before that can finish on the
        # surviving worker alone, which then restarts on the next call instead, as a loaded
        # machine showed.)
        os.kill(next(iter(two._pool._processes)), signal.SIGKILL)
        deadline = time.monotonic() + 60
        while not two._pool._broken and time.monotonic() < deadline:
            time.sleep(0.01)
        np.testing.assert_array_equal(two.run([es])[0].returns, returns)
        assert two.restarts == 1
    # The mirrored population is the one `mirrored_population` builds, pairs sharing a start.
    direct = RolloutEngine(AGENT, TERRAIN_CFG, 6, ES_SIZES).run(
        terrain, mirrored_population(theta, np.array([11, 12, 13]), 0.05), np.tile([21, 22, 23], 2)
    )
    np.testing.assert_array_equal(direct.returns, returns)
    with pytest.raises(RuntimeError, match="closed"):
        two.run([es])


def test_one_call_of_many_requests_equals_one_call_each(terrain):
    """An iteration's work goes out as one call over several terrains; results are those of
    separate calls, in request order, for any worker count."""
    other = make_terrain(TERRAIN_CFG, seed=2, iteration=30)
    theta = init_params(3, ES_SIZES)
    requests = [
        Request(terrain, Mirrored.of(theta, np.array([1, 2, 3]), 0.05, np.array([4, 5, 6]))),
        Request(other, Agents.of(np.stack([theta, -theta]), np.array([7, 8, 9]))),
        Request(terrain, Agents.of(theta[None], np.array([10]))),
    ]
    requests = [r._replace(record=len(r.population)) for r in requests]  # record them all
    with (
        make_evaluator(AGENT, TERRAIN_CFG, 1, 2, ES_SIZES) as one,
        make_evaluator(AGENT, TERRAIN_CFG, 2, 4, ES_SIZES) as two,
    ):
        separate = [one.run([r])[0] for r in requests]
        for evaluator in (one, two):
            together = evaluator.run(requests)
            assert [e.returns.shape for e in together] == [(6,), (2, 3), (1, 1)]
            for got, want in zip(together, separate):
                np.testing.assert_array_equal(got.returns, want.returns)
                np.testing.assert_array_equal(got.lengths, want.lengths)
                for key, value in want.transitions.items():
                    np.testing.assert_array_equal(got.transitions[key], value)
        # Each request ran on its own terrain: the second one's agents do differently here.
        elsewhere = one.run([Request(terrain, requests[1].population)])[0]
        assert not np.array_equal(elsewhere.returns, separate[1].returns)


def test_a_request_records_its_first_episodes_from_the_worker_processes(terrain):
    """ePOET-SAC's shared replay takes a bounded share of an ES step: the first `record`
    episodes of a request come back recorded from the workers, step for step, with the same
    results as an unrecorded call."""
    theta = init_params(5, ES_SIZES)
    es = Request(terrain, Mirrored.of(theta, np.array([1, 2, 3, 4]), 0.05, np.arange(4)), record=3)
    evaluation = Request(terrain, Agents.of(theta[None], np.array([9, 10])))
    with make_evaluator(AGENT, TERRAIN_CFG, 2, 2, ES_SIZES) as pool:
        recorded, unrecorded = pool.run([es, evaluation])
        plain = pool.run([es._replace(record=0)])[0]
    t = recorded.transitions
    np.testing.assert_array_equal(np.unique(t["episode"]), [0, 1, 2])
    assert len(t["reward"]) == int(recorded.lengths[:3].sum())
    for e in range(3):
        np.testing.assert_allclose(
            t["reward"][t["episode"] == e].sum(dtype=np.float64), recorded.returns[e], rtol=1e-5
        )
    assert unrecorded.transitions is None and plain.transitions is None
    np.testing.assert_array_equal(plain.returns, recorded.returns)


def test_bad_input_is_refused_in_one_sentence(terrain):
    engine = RolloutEngine(AGENT, TERRAIN_CFG, 2, ES_SIZES)
    params, seeds = population(3)
    with pytest.raises(ValueError, match="episode_seeds must have shape"):
        engine.run(terrain, params, seeds[:2])
    with pytest.raises(ValueError, match="params must have shape"):
        engine.run(terrain, params[:, :-1], seeds)
    with pytest.raises(ValueError, match="integers >= 0"):
        engine.run(terrain, params, seeds - 1)
    with make_evaluator(AGENT, TERRAIN_CFG, 1, 2, ES_SIZES) as evaluator:
        with pytest.raises(ValueError, match="one seed per noise seed"):
            evaluator.run(
                [Request(terrain, Mirrored.of(params[0], np.arange(3), 0.02, np.arange(2)))]
            )
        with pytest.raises(ValueError, match="spawn_seeds must have shape"):
            evaluator.run([Request(terrain, Agents.of(params, np.zeros((2, 4), dtype=int)))])
    for workers in (0, "ray"):
        with pytest.raises(ValueError, match="workers must be"):
            make_evaluator(AGENT, TERRAIN_CFG, workers, 2, ES_SIZES)
