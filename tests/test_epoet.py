"""The ePOET loop on the real rollout engine: reproduction, archive, transfer, tracking, resume."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import mlflow
import numpy as np
import pytest

from conftest import BUSY_LOOP, TINY_EPOET, run_epoet
from epoet.config import load
from epoet.core.checkpoint import load_checkpoint
from epoet.open_ended.keys import Key
from epoet.open_ended.loop import Epoet
from epoet.open_ended.reproduction import best_agent_for, minimal_criterion, propose_children
from epoet.open_ended.runner import layer_sizes
from epoet.rollout.backends.serial import SerialEvaluator
from epoet.rollout.evaluators import make_evaluator
from epoet.run import run
from epoet.terrain.config import TerrainConfig
from pool_state import assert_same_state

ROOT = Path(__file__).resolve().parent.parent
SIZES = (53, 8, 18)
PAPER = load(["budget=paper"])  # the paper's agent (RK4) and ePOET settings
SMOKE = TINY_EPOET


def make_epoet(terrain_cfg: TerrainConfig, seed: int = 3, **algo) -> Epoet:
    agent = replace(PAPER.agent, max_episode_steps=20, settle_steps=2)
    evaluator = SerialEvaluator(agent, terrain_cfg, batch=8, layer_sizes=SIZES)
    return Epoet(
        replace(PAPER.algo, **algo),
        terrain_cfg,
        evaluator,
        seed=seed,
        n_pairs=2,
        eval_episodes=1,
        score_scale=1.0,
    )


OPEN = dict(repro_threshold=-1e9, mc_lower=-1e9, mc_upper=1e9)  # every child passes


def test_reproduction_admits_at_most_one_child(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=4, **OPEN)
    loop.run_iteration()
    assert loop.reproduce(loop.iteration) == 1
    child = loop.pool.active[-1]
    assert len(loop.pool.active) == 2 and child.env.index == 1
    assert child.env.generation == 1 and child.env.parent == 0
    assert child.env.genome is not loop.pool.active[0].env.genome
    terrain = loop.service.terrain(child.env, loop.iteration)
    assert terrain.generation == 1 and terrain.parent_id == "env0"


def test_reproduction_requires_minimal_criterion(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=3, repro_threshold=-1e9, mc_lower=1e8, mc_upper=1e9)
    loop.run_iteration()
    assert loop.reproduce(loop.iteration) == 0 and len(loop.pool.active) == 1


def test_reproduction_requires_threshold(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=3, repro_threshold=1e9, mc_lower=-1e9, mc_upper=1e9)
    loop.run_iteration()
    assert loop.reproduce(loop.iteration) == 0


def test_oldest_pair_is_archived(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=2, max_num_envs=1, **OPEN)
    loop.run_iteration()
    loop.reproduce(loop.iteration)
    assert [p.env.index for p in loop.pool.active] == [1]
    assert [p.env.index for p in loop.pool.archived] == [0]
    metrics = loop.run_iteration()
    assert metrics["archived_envs"] == 1 and metrics["active_envs"] == 1


def test_transfer_replaces_a_beaten_agent(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=2, **OPEN)
    loop.run_iteration()
    loop.reproduce(loop.iteration)
    target = loop.pool.active[1]
    target.scores[:] = [-1e9]  # any other agent beats this incumbent
    target.es.tell(*_fake_step(target))  # move its optimiser away from the initial state
    before = target.theta.copy()
    assert loop.transfer(loop.iteration) >= 1
    assert not np.array_equal(target.theta, before)
    assert target.es.state_dict()["t"] == 0  # Adam state reset on acceptance


def _fake_step(pair):
    seeds = pair.es.sample_seeds()
    return seeds, np.arange(len(seeds), dtype=float), -np.arange(len(seeds), dtype=float)


def test_annecs_counts_solved_children(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=2, **OPEN)
    loop.run_iteration()
    loop.reproduce(loop.iteration)
    # every score clears the (open) threshold: the child is solved
    assert loop.run_iteration()["annecs"] == 1


def test_best_score_is_the_best_score_so_far(
    terrain_cfg: TerrainConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`score` is this iteration's best active score, `best_score` the best of any iteration so
    far (it equalled `score` before): evaluations scripted to fall and rise again."""
    loop = make_epoet(terrain_cfg)
    scripted = iter([5.0, 3.0, 4.0, 6.0])
    monkeypatch.setattr(
        loop.service, "scores", lambda requests: [np.array([next(scripted)]) for _ in requests]
    )
    logged = []
    for _ in range(4):
        loop.run_iteration()
        logged.append((loop.score, loop.best_score))
    assert logged == [(5.0, 5.0), (3.0, 5.0), (4.0, 5.0), (6.0, 6.0)]
    restored = make_epoet(terrain_cfg)
    restored.load_state_dict(loop.state_dict())
    assert restored.best_score == 6.0


def _runs(uri: str) -> list:
    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("epoet")
    return [] if exp is None else client.search_runs([exp.experiment_id])


def test_smoke_run_is_tracked(compose, mlflow_uri: str, tmp_path: Path) -> None:
    loop = run(compose(SMOKE), tmp_path / "run")
    (r,) = _runs(mlflow_uri)
    assert r.info.status == "FINISHED"
    for key in (
        "pair0/return_mean",
        "pair0/return_max",
        "pair0/score",
        "pair0/lr",
        "pair0/sigma",
        "best_score",
        "active_envs",
        "archived_envs",
        "annecs",
        "env_steps",
        "time/iteration",
    ):
        assert key in r.data.metrics, key
    history = mlflow.MlflowClient(mlflow_uri).get_metric_history(r.info.run_id, "best_score")
    assert [m.step for m in history] == [0, 1, 2]
    assert r.data.tags["algo"] == "epoet" and r.data.tags["seed"] == "0"
    assert r.data.tags["budget"] == "smoke" and "mlflow.source.git.commit" in r.data.tags
    assert r.data.params["algo.iterations_before_transfer"] == "15"
    client = mlflow.MlflowClient(mlflow_uri)
    names = {a.path for a in client.list_artifacts(r.info.run_id)}
    assert {"config.yaml", "terrains", "policies"} <= names
    terrains = {a.path for a in client.list_artifacts(r.info.run_id, "terrains")}
    assert {"terrains/env0.npz", "terrains/env0.png"} <= terrains
    policy = np.load(tmp_path / "run" / "policies" / "env0.npz")
    np.testing.assert_array_equal(policy["theta"], loop.pool.active[0].theta)


def _state(run_dir: Path) -> dict:
    return load_checkpoint(run_dir / "checkpoint.pkl")["open_ended"]


def _assert_same(a: dict, b: dict) -> None:
    assert_same_state(a, b)  # every entry, the pairs' bests and the env genomes included


def test_resume_ends_in_the_uninterrupted_state(compose, mlflow_uri: str, tmp_path: Path) -> None:
    # Small intervals so reproduction (t=2, 4) and transfers happen on both sides of the cut
    # (seed 1: a transfer at t=2, 3 and 4).
    algo = [*BUSY_LOOP, "checkpoint_every=1", "seed=1"]
    run(compose(SMOKE + algo + ["budget.iterations=5"]), tmp_path / "straight")
    run(compose(SMOKE + algo + ["budget.iterations=3"]), tmp_path / "killed")
    run(
        compose(SMOKE + algo + ["budget.iterations=5", f"resume={tmp_path / 'killed'}"]),
        tmp_path / "resumed",
    )
    straight, resumed = _state(tmp_path / "straight"), _state(tmp_path / "resumed")
    assert len(straight["active"]) > 1, "reproduction should have happened"
    assert straight["transfers"] > 0, "transfers should have happened"
    assert any(p["best_score"] > p["scores"][-1] for p in straight["active"]), (
        "some pair's best evaluation should not be its last"
    )
    _assert_same(straight, resumed)
    runs = {r.info.run_id: r for r in _runs(mlflow_uri)}
    assert len(runs) == 2  # the resumed run continued the killed one
    killed_id = load_checkpoint(tmp_path / "resumed" / "checkpoint.pkl")["run_id"]
    history = mlflow.MlflowClient(mlflow_uri).get_metric_history(killed_id, "best_score")
    assert sorted(m.step for m in history) == [0, 1, 2, 3, 4]


def test_multirun_has_one_parent_and_two_children(mlflow_uri: str, tmp_path: Path) -> None:
    # Parent and children do not depend on the algorithm; every algorithm's multirun is
    # exercised by test_evaluation's `make paper` call.
    out = run_epoet(
        ["-m", *SMOKE, "budget.iterations=1", "seed=1,2", f"hydra.sweep.dir={tmp_path / 'sweep'}"],
        tmp_path,
        mlflow_uri,
    )
    assert out.returncode == 0, out.stderr
    runs = _runs(mlflow_uri)
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in runs if "mlflow.parentRunId" in r.data.tags]
    assert len(parents) == 1 and len(children) == 2
    assert {c.data.tags["mlflow.parentRunId"] for c in children} == {parents[0].info.run_id}
    assert sorted(c.data.tags["seed"] for c in children) == ["1", "2"]


def test_transfer_accepts_only_fine_tuned_proposals(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, num_children=2, **OPEN)
    loop.run_iteration()
    loop.reproduce(loop.iteration)
    for pair in loop.pool.active:
        pair.scores[:] = [-1e9]  # every direct transfer clears the bar
    before = [p.theta.copy() for p in loop.pool.active]
    assert loop.transfer(loop.iteration) == len(loop.pool.active)
    for pair in loop.pool.active:
        # A proposal is a fine-tuned agent: it equals none of the agents as they were.
        assert not any(np.array_equal(pair.theta, theta) for theta in before)


def test_the_transfer_bar_is_the_best_of_the_last_evaluations(terrain_cfg: TerrainConfig) -> None:
    """The reference's bar: the best of the target's last 5 evaluations; a great score 6
    evaluations ago no longer guards the agent."""
    loop = make_epoet(terrain_cfg, num_children=2, **OPEN)
    assert loop.cfg.transfer_bar_window == 5
    loop.run_iteration()
    loop.reproduce(loop.iteration)
    for pair in loop.pool.active:
        pair.scores[:] = [1e9] + [-1e9] * 5
    assert loop.transfer(loop.iteration) == len(loop.pool.active)
    for pair in loop.pool.active:
        pair.scores[:] = [-1e9] + [1e9] + [-1e9] * 4
    assert loop.transfer(loop.iteration) == 0


@pytest.mark.parametrize("later, due", [(5, [75, 150, 225]), (1, [75, 90, 105, 120])])
def test_reproduction_schedule(terrain_cfg: TerrainConfig, later, due) -> None:
    """The paper reproduces every 75 iterations; the reference at 75 and then every 15."""
    loop = make_epoet(terrain_cfg, later_adjust_interval=later)
    assert [t for t in range(1, 121 if later == 1 else 226) if loop.reproduce_due(t)] == due


def test_a_child_whose_best_agent_fails_the_minimal_criterion_is_not_admitted(
    terrain_cfg: TerrainConfig,
) -> None:
    # Learn the child's scores on the real engine (they do not depend on the thresholds) ...
    probe = make_epoet(terrain_cfg, num_children=1, **OPEN)
    probe.run_iteration()
    service, t = probe.service, probe.iteration
    ((child, parent),) = propose_children(service, probe.cfg, probe.pool.active, t)
    mc_score = float(
        service.scores(
            [service.eval_request(child.terrain, parent.theta[None], Key.MC, t, child.slot)]
        )[0][0]
    )
    best_score, _ = best_agent_for(probe.pool, service, probe.cfg, child, t)
    assert best_score != mc_score
    # ... then set the window so that the parent's agent passes and the best agent does not.
    middle = (mc_score + best_score) / 2
    window = (mc_score - 1.0, middle) if best_score > mc_score else (middle, mc_score + 1.0)
    loop = make_epoet(
        terrain_cfg, num_children=1, repro_threshold=-1e9, mc_lower=window[0], mc_upper=window[1]
    )
    loop.run_iteration()
    t = loop.iteration
    children = propose_children(loop.service, loop.cfg, loop.pool.active, t)
    assert len(minimal_criterion(loop.pool, loop.service, children, t)) == 1
    assert loop.reproduce(loop.iteration) == 0 and len(loop.pool.active) == 1


def test_admission_fine_tunes_with_a_fresh_optimiser(terrain_cfg: TerrainConfig) -> None:
    loop = make_epoet(terrain_cfg, seed=4, num_children=1, **OPEN)
    loop.run_iteration()
    t = loop.iteration
    ((child, _),) = propose_children(loop.service, loop.cfg, loop.pool.active, t)
    score, theta = best_agent_for(loop.pool, loop.service, loop.cfg, child, t)
    assert not np.array_equal(theta, loop.pool.active[0].theta), "seed 4: a fine-tuned agent wins"
    es = loop.pool.active[0].es  # the incumbent's optimiser state must not matter
    es.m[:], es.v[:], es.t, es.lr, es.sigma = 1.0, 1.0, 50, 0.5, 0.3
    again, theta_again = best_agent_for(loop.pool, loop.service, loop.cfg, child, t)
    assert again == score
    np.testing.assert_array_equal(theta_again, theta)


def test_one_and_two_workers_run_the_same_loop(terrain_cfg: TerrainConfig) -> None:
    def final_state(workers: int) -> dict:
        agent = replace(PAPER.agent, max_episode_steps=20, settle_steps=2)
        with make_evaluator(agent, terrain_cfg, workers, batch=3, layer_sizes=SIZES) as ev:
            every = dict(iterations_before_transfer=1, adjust_interval=1, later_adjust_interval=1)
            loop = Epoet(
                replace(PAPER.algo, num_children=2, **every, **OPEN),
                terrain_cfg,
                ev,
                seed=5,
                n_pairs=3,
                eval_episodes=2,
                score_scale=1.0,
            )
            for _ in range(3):
                loop.run_iteration()
            return loop.state_dict()

    one, two = final_state(1), final_state(2)
    assert len(one["active"]) == 3 and one["transfers"] > 0
    _assert_same(one, two)


# docs/configs.md: what each budget runs with (thresholds x, transfer / reproduce every, S per
# iteration, integrator); `paper`'s are the paper's.
SCHEDULES = {
    "smoke": (0.025, 15, 75, 0.01, "implicitfast"),
    "laptop": (0.125, 10, 20, 0.005, "implicitfast"),
    "workstation": (1.0, 15, 75, 0.01, "implicitfast"),
    "paper": (1.0, 15, 75, 0.01, "rk4"),
}


@pytest.mark.parametrize(
    "budget", sorted(p.stem for p in (ROOT / "conf" / "budget").glob("*.yaml"))
)
def test_every_budget_composes_and_only_the_paper_keeps_the_papers_schedule(budget: str) -> None:
    """Small budgets may trade integrator, intervals and S schedule for time; `paper` may not.
    Each budget runs with its docs/configs.md row (a budget's own file missing or misnamed falls back to
    the paper's RK4 and S schedule), and every smaller one trades something."""
    cfg = load([f"budget={budget}"])
    assert cfg.agent.max_episode_steps == cfg.budget.episode_steps
    loop = Epoet.from_config(cfg, SerialEvaluator(cfg.agent, cfg.terrain, 1, layer_sizes(cfg)))
    runs_with = (
        cfg.budget.score_scale,
        loop.transfer_interval,
        loop.reproduce_interval,
        cfg.terrain.max_height_step,
        cfg.agent.integrator,
    )
    assert runs_with == SCHEDULES[budget]
    assert (runs_with == SCHEDULES["paper"]) == (budget == "paper")
    assert (cfg.budget.hours == 24.0) == (budget == "paper")


@pytest.mark.parametrize("choice", ["best", "final"])
def test_a_run_exports_each_pairs_best_or_final_agent(
    compose, mlflow_uri: str, tmp_path: Path, choice: str
) -> None:
    """Each pair keeps the parameters of its best evaluation (the reference's best.json per
    niche); `agent_choice` picks which the run exports, and both are in the file. The run is
    stopped and resumed after every iteration, so each checkpoint shows the parameters that
    iteration evaluated (an iteration's ES step comes before its evaluation) and their score."""
    folder = tmp_path / "run"
    evaluated: list[tuple[np.ndarray, float]] = []
    for iterations in range(1, 5):
        resume = [f"resume={folder}"] if evaluated else []
        run(
            compose(SMOKE + [f"budget.iterations={iterations}", f"agent_choice={choice}", *resume]),
            folder,
        )
        (pair,) = load_checkpoint(folder / "checkpoint.pkl")["open_ended"]["active"]  # no child yet
        evaluated.append((pair["es"]["theta"].copy(), pair["scores"][-1]))
    scores = [score for _, score in evaluated]
    assert pair["scores"] == scores
    best = int(np.argmax(scores))
    assert 0 < best < 3, f"seed 0: the best evaluation is neither the first nor the last {scores}"
    with np.load(folder / "policies" / "env0.npz") as saved:
        np.testing.assert_array_equal(saved["best_theta"], evaluated[best][0])
        assert float(saved["best_score"]) == scores[best]
        np.testing.assert_array_equal(saved["final_theta"], evaluated[-1][0])
        assert float(saved["final_score"]) == scores[-1]
        assert str(saved["choice"]) == choice
        np.testing.assert_array_equal(saved["theta"], saved[f"{choice}_theta"])
        assert float(saved["score"]) == float(saved[f"{choice}_score"])
