"""Observation normalisation for ES (Salimans et al. 2017): the folded policy acts on raw
observations as the ES parameters act on standardised ones, the statistics are those of the
recorded ES episodes, and a run with it exports agents that score what the loop measured."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import serial_loop
from epoet.config import load
from epoet.core.checkpoint import load_checkpoint
from epoet.es.obs_norm import VAR_FLOOR, ObsNormalizer
from epoet.open_ended.keys import Key
from epoet.open_ended.loop import Epoet
from epoet.rollout.policy import fold, forward, init_params
from epoet.rollout.populations import Agents, Request
from epoet.run import run
from epoet.terrain.config import TerrainConfig

SIZES = (53, 8, 18)
SMOKE = ["budget=smoke", "workers.num=1", "algo.es.hidden=[8]", "terrain.grid=40"]


def test_the_folded_policy_on_raw_observations_is_theta_on_standardised_ones() -> None:
    rng = np.random.default_rng(0)
    theta = init_params(1, SIZES, std=0.5)
    mean, std = rng.normal(size=53), rng.uniform(0.1, 5.0, size=53)
    obs = rng.normal(size=(7, 53)) * std + mean
    np.testing.assert_allclose(
        forward(fold(theta, mean, std, SIZES), obs, SIZES),
        forward(theta, (obs - mean) / std, SIZES),
        atol=1e-12,
    )
    both = fold(np.stack([theta, -theta]), mean, std, SIZES)
    np.testing.assert_array_equal(both[0], fold(theta, mean, std, SIZES))
    assert not np.array_equal(both[0], theta)


def test_statistics_start_at_the_identity_and_follow_the_data() -> None:
    norm = ObsNormalizer(3)
    theta = init_params(2, (3, 4, 2))
    np.testing.assert_array_equal(norm.standardizer((3, 4, 2)).fold(theta), theta)
    rng = np.random.default_rng(1)
    parts = [rng.normal([1.0, -2.0, 5.0], [3.0, 0.5, 0.01], size=(n, 3)) for n in (10, 200)]
    for part in parts:
        norm.update(part)
    data = np.concatenate(parts)
    assert norm.count == len(data)
    np.testing.assert_allclose(norm.mean, data.mean(axis=0))
    # the third input barely varies: its variance is floored, not divided by ~0
    np.testing.assert_allclose(norm.std, np.sqrt(np.maximum(data.var(axis=0), VAR_FLOOR)))
    assert norm.std[2] == pytest.approx(np.sqrt(VAR_FLOOR))


def _epoet(terrain_cfg: TerrainConfig, episodes: int) -> Epoet:
    paper = load(["budget=paper"])
    agent = replace(paper.agent, max_episode_steps=30, settle_steps=2)
    es = replace(paper.algo.es, obs_norm_episodes=episodes)
    return serial_loop(
        replace(paper.algo, es=es), agent, terrain_cfg, SIZES, seed=4, n_pairs=3, eval_episodes=2
    )


def test_the_loop_standardises_with_the_recorded_episodes(terrain_cfg: TerrainConfig) -> None:
    loop = _epoet(terrain_cfg, episodes=2)
    metrics = loop.run_iteration()
    norm = loop.service.obs_norm
    assert 0 < norm.count <= 2 * 30 and metrics["obs_norm/count"] == norm.count
    assert not np.allclose(norm.std, 1.0)
    pair = loop.pool.active[0]
    # the evaluation ran the folded policy: replaying it from the same starts gives the score
    service = loop.service
    seeds = service.seeds(service.eval_episodes, Key.EVAL, pair.env.index, 0)
    again = service.evaluator.run(
        [Request(service.terrain(pair.env, 0), Agents.of(service.policy(pair.theta)[None], seeds))]
    )
    assert again[0].returns.mean() == pytest.approx(pair.score, abs=1e-9)
    np.testing.assert_array_equal(pair.best_theta, service.policy(pair.theta))
    # without normalisation the same seed runs other policies
    plain = _epoet(terrain_cfg, episodes=0)
    plain.run_iteration()
    assert plain.service.obs_norm is None and plain.pool.active[0].score != pair.score


def test_an_epoet_run_with_normalisation_exports_raw_policies_and_resumes(
    compose, mlflow_uri: str, tmp_path: Path
) -> None:
    norm = ["algo.es.obs_norm_episodes=1", "checkpoint_every=1"]
    run(compose(SMOKE + norm + ["budget.iterations=3"]), tmp_path / "straight")
    run(compose(SMOKE + norm + ["budget.iterations=2"]), tmp_path / "killed")
    run(
        compose(SMOKE + norm + ["budget.iterations=3", f"resume={tmp_path / 'killed'}"]),
        tmp_path / "resumed",
    )
    straight = load_checkpoint(tmp_path / "straight" / "checkpoint.pkl")["open_ended"]
    resumed = load_checkpoint(tmp_path / "resumed" / "checkpoint.pkl")["open_ended"]
    assert straight["obs_norm"]["count"] > 0
    for key in ("count", "sum", "sumsq"):
        np.testing.assert_array_equal(straight["obs_norm"][key], resumed["obs_norm"][key])
    np.testing.assert_array_equal(
        straight["active"][0]["es"]["theta"], resumed["active"][0]["es"]["theta"]
    )
    stats = straight["obs_norm"]
    mean = stats["sum"] / stats["count"]
    std = np.sqrt(np.maximum(stats["sumsq"] / stats["count"] - mean**2, VAR_FLOOR))
    with np.load(tmp_path / "straight" / "policies" / "env0.npz") as saved:
        sizes = tuple(saved["layer_sizes"])
        np.testing.assert_allclose(
            saved["final_theta"], fold(straight["active"][0]["es"]["theta"], mean, std, sizes)
        )


def test_the_workstation_budget_normalises_epoet_and_epoet_sac_observations() -> None:
    """The screen's survivor is the workstation budget's default for ePOET and ePOET-SAC (one
    set of statistics for its pool and SAC learner, tests/test_epoet_sac.py); the paper's and
    the laptop budget keep raw observations. ePOET-SAC starts its learner cold there, as at every
    budget (docs/algorithms/epoet-sac.md)."""
    for algo in ("epoet", "epoet_sac"):
        assert load(["budget=workstation", f"algo={algo}"]).algo.es.obs_norm_episodes == 1
        for budget in ("paper", "laptop", "smoke"):
            assert load([f"budget={budget}", f"algo={algo}"]).algo.es.obs_norm_episodes == 0
    assert load(["budget=workstation", "algo=epoet_sac"]).algo.sac_init is None
