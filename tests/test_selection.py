"""Which agent a run exports (`selection`, epoet/rollout/selection.py): the held-out choice
among every niche's best and last parameters, recorded beside the run's own choice."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from conftest import authors, serial_loop
from epoet.config import load
from epoet.core.schema import ConfigError
from epoet.eval.agents import policy_in
from epoet.open_ended.exported_agent import candidates, export_agent, niches_of
from epoet.open_ended.loop import Epoet
from epoet.open_ended.pairs import Environment
from epoet.rollout.agent_files import ES_POLICIES, EXPORTED_AGENT, read_es_policy
from epoet.rollout.selection import CHOICE_FILE, held_out_terrains, rank

SIZES = (53, 40, 40, 18)  # the authors' ES agents'


def run_config(*overrides: str):
    return load(["budget=paper", "selection.terrains=3", "selection.generations=1", *overrides])


def pool_with_a_misleading_own_score(cfg) -> Epoet:
    """A pool whose root agent stands still but holds the best own-terrain score, beside a
    niche with the authors' walker and a poor own score."""
    agent = replace(cfg.agent, max_episode_steps=120)
    terrain = replace(cfg.terrain, grid=40)
    loop = serial_loop(cfg.algo, agent, terrain, SIZES, seed=3, n_pairs=2)
    root = loop.pool.active[0]
    root.es.reset(np.zeros_like(root.theta))
    loop.pool.record(root, 5000.0)
    walker, _ = read_es_policy(authors("agents", "poet_twin22", "e6cf5d0d.npz"))
    env = Environment(index=1, genome=root.env.genome, generation=1, parent=0, created_at=1)
    pair = loop.pool.admit(env, loop.service.optimizer_for(env, walker))
    loop.pool.record(pair, 10.0)
    return loop


def test_a_pool_whose_own_best_is_not_the_held_out_best_exports_the_held_out_best(tmp_path):
    cfg = run_config()
    loop = pool_with_a_misleading_own_score(cfg)
    record = export_agent(loop, tmp_path, cfg)
    assert record["own"] == "env0/best"  # the run's own rule: the best own-terrain score
    assert record["validation"] == record["exported"] == "env1/best"
    held_out = record["candidates"]
    assert held_out["env1/best"]["mean_return"] > held_out["env0/best"]["mean_return"]
    exported, _ = read_es_policy(tmp_path / ES_POLICIES / EXPORTED_AGENT)
    np.testing.assert_array_equal(
        exported, read_es_policy(authors("agents", "poet_twin22", "e6cf5d0d.npz"))[0]
    )
    assert json.loads((tmp_path / ES_POLICIES / CHOICE_FILE).read_text()) == record
    # evaluation and the tables take the exported agent as the run's
    found = policy_in(tmp_path)
    assert found is not None and found[0].path.name == EXPORTED_AGENT


def test_rule_own_exports_the_own_choice_and_still_records_the_held_out_one(tmp_path):
    cfg = run_config("selection.rule=own")
    record = export_agent(pool_with_a_misleading_own_score(cfg), tmp_path, cfg)
    assert record["exported"] == record["own"] == "env0/best"
    assert record["validation"] == "env1/best"
    exported, _ = read_es_policy(tmp_path / ES_POLICIES / EXPORTED_AGENT)
    assert not exported.any()


def test_held_out_terrains_taller_than_the_runs_cap_on_s_are_walked_in_a_model_that_fits(tmp_path):
    """A run that holds S below the held-out terrains' (ePOET at the workstation budget caps it
    at the paper suite's 1 m; `selection.max_height` may ask for more) walks them in a
    heightfield that reaches them, as a suite's is: exactly as a run capped at their S."""
    records = []
    for limit in (0.5, 1.0):  # below, and at, the held-out S of 1 m
        cfg = run_config(f"terrain.max_height_limit={limit}")
        assert cfg.selection.max_height == 1.0
        loop = pool_with_a_misleading_own_score(cfg)
        records.append(export_agent(loop, tmp_path / str(limit), cfg)["candidates"])
    assert records[0] == records[1]


def test_candidates_are_every_niches_best_and_distinct_last_parameters():
    loop = pool_with_a_misleading_own_score(run_config())
    pair = loop.pool.active[1]
    pair.es.reset(pair.theta + 0.1)  # its last parameters move away from its best
    names, thetas, scores = candidates(niches_of(loop))
    assert names == ["env0/best", "env1/best", "env1/final"]
    assert thetas.shape == (3, pair.theta.size) and scores[:2] == [5000.0, 10.0]


def test_ranking_prefers_solved_terrains_then_mean_return_then_the_earlier_candidate():
    names = ["a", "b", "c"]
    solved = np.array([[0, 1], [1, 1], [1, 1]], dtype=bool)
    returns = np.array([[3000.0, 3000.0], [10.0, 20.0], [10.0, 20.0]])
    assert rank(names, solved, returns)["chosen"] == "b"
    assert rank(names, np.zeros((3, 2), bool), returns)["chosen"] == "a"


def test_held_out_terrains_are_a_function_of_the_run_seed_and_never_the_training_ones():
    cfg = run_config()
    terrain = replace(cfg.terrain, grid=40)
    first = held_out_terrains(terrain, cfg.selection, 1)
    again = held_out_terrains(terrain, cfg.selection, 1)
    other = held_out_terrains(terrain, cfg.selection, 2)
    assert len(first) == cfg.selection.terrains
    assert all(a.id == b.id for a, b in zip(first, again))
    assert not {t.id for t in first} & {t.id for t in other}
    assert {t.max_height for t in first} == {cfg.selection.max_height}
    assert all(t.generation == cfg.selection.generations for t in first)


@pytest.mark.parametrize(
    "override, message",
    [
        ("selection.rule=best", "selection.rule must be 'validation' or 'own'"),
        ("selection.terrains=0", "selection.rule=validation needs held-out terrains"),
        ("terrain.size=30", "selection.rendering=reference renders the held-out terrains"),
    ],
)
def test_bad_selections_are_refused_at_start_up(override, message):
    with pytest.raises(ConfigError, match=message):
        load([override])


def test_a_baseline_whose_last_policy_is_worse_than_an_earlier_one_exports_the_earlier(tmp_path):
    """The authors' PPO policy kept at an evaluation point, then a last policy that stands
    still: the run exports the kept one, the last beside it, both choices recorded."""
    import torch

    from epoet.rl.candidates import CANDIDATES, Candidates
    from epoet.rl.policy_file import POLICY_FILE
    from epoet.rollout.agent_files import LAST_POLICY

    cfg = load(["algo=ppo", "budget=paper", "budget.episode_steps=60", "selection.terrains=2"])
    walker = authors("agents", "ppo", "0.pt")
    candidates = Candidates(cfg, tmp_path)
    candidates.keep(1000, lambda path: path.write_bytes(walker.read_bytes()))
    spec = torch.load(walker, weights_only=True)
    spec["state_dict"] = {k: torch.zeros_like(v) for k, v in spec["state_dict"].items()}
    torch.save(spec, tmp_path / POLICY_FILE)  # the run's last policy: all zeros
    record = candidates.export(tmp_path)
    assert record["own"] == "last" and record["validation"] == record["exported"] == "frames1000"
    assert (tmp_path / POLICY_FILE).read_bytes() == walker.read_bytes()
    assert (
        torch.load(tmp_path / LAST_POLICY, weights_only=True)["state_dict"]["0.weight"].abs().sum()
        == 0
    )
    assert (tmp_path / CHOICE_FILE).is_file()
    # the kept policy's held-out result is cached: a later choice walks only the last again
    cached = json.loads((tmp_path / CANDIDATES / "held_out.json").read_text())
    assert list(cached) == ["frames1000"]
