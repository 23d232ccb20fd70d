"""The authors' published agents and terrains, read from their files and converted on use
(epoet.eval.reference): they walk in our env as far as their logs say, the layout is what makes
them walk, the paper suite is the reference's arithmetic, and what cannot be read is refused in
one sentence. (tests/test_authors_files.py: where the files are read from, the cache, and that
none of theirs is in the repository.)"""

from __future__ import annotations

import json
import math
import pickle
import subprocess
import sys

import gymnasium as gym
import mlflow
import numpy as np
import pytest
from scipy import ndimage

from conftest import authors, subset_suite
from epoet.env_factory import ENV_ID
from epoet.eval.agents import AgentError, AgentSource, resolve_run
from epoet.eval.reference import folder, manifest
from epoet.eval.reference.files import GENOMES, ReferenceFileError, source
from epoet.eval.reference.pickles import read_genome, read_pickle
from epoet.eval.suite import load_suite
from epoet.rollout.policy import forward

pytestmark = pytest.mark.usefixtures("authors_files")


@pytest.fixture(scope="module")
def authors_files():
    """Every test here reads the authors' files: skipped where they are absent."""
    authors()


def _returns(policy, seeds=(0, 1, 2), steps: int = 2000) -> list[float]:
    """Episode returns on the task the authors trained on: RK4, 2000 steps, S = 0.1 m."""
    env = gym.make(
        ENV_ID, agent={"integrator": "rk4", "max_episode_steps": steps}, terrain={"max_height": 0.1}
    )
    totals = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            total, done = total + reward, terminated or truncated
        totals.append(total)
    env.close()
    return totals


def _theirs(name: str) -> AgentSource:
    entry = manifest()["agents"][name]
    return AgentSource(entry["kind"], folder() / entry["file"])


def test_the_authors_epoet_agent_walks_as_far_as_its_log_says():
    returns = _returns(_theirs("poet_hexA8/flat").load())
    assert manifest()["agents"]["poet_hexA8/flat"]["logged_score"] == pytest.approx(
        2602.175, abs=1e-3
    )
    assert np.mean(returns) >= 2300, returns


def test_the_same_vector_in_our_leg_order_does_not_walk():
    with np.load(folder() / manifest()["agents"]["poet_hexA8/flat"]["file"]) as data:
        raw, sizes = data["reference_theta"], tuple(data["layer_sizes"])
        assert not np.array_equal(raw, data["theta"])
    returns = _returns(lambda obs: forward(raw, obs, sizes))
    assert np.mean(returns) < 500, returns


def test_the_authors_ppo_agent_walks_with_its_normaliser():
    source = _theirs("ppo/0")
    spec = __import__("torch").load(source.path, weights_only=True)
    assert spec["obs_loc"] is not None and spec["activation"] == "tanh"
    assert np.mean(_returns(source.load())) >= 2300


def _activation(name: str, z: float) -> float:
    """neat-python's activations, scalar (as the reference's neat 0.92 computed them)."""
    if name == "sin":
        return math.sin(max(-60.0, min(60.0, 5.0 * z)))
    if name == "sigmoid":
        return 1.0 / (1.0 + math.exp(-max(-60.0, min(60.0, 5.0 * z))))
    if name == "tanh":
        return math.tanh(max(-60.0, min(60.0, 2.5 * z)))
    if name == "gauss":
        return math.exp(-5.0 * max(-3.4, min(3.4, z)) ** 2)
    return {"identity": z, "square": z * z}[name]


def _reference_heights(genome: dict, seed: int, s: float = 1.0) -> np.ndarray:
    """The reference's Hexapod.gen_terrains + _generate_terrain, written out scalar by scalar
    from docs/reference.md: the test's own computation, sharing nothing with the product."""
    nodes = {k: (b, r, a) for k, b, r, a, _ in genome["nodes"]}
    links = [(i, o, w) for i, o, w, on in genome["connections"] if on]

    def value(node: int, x: float, y: float, memo: dict) -> float:
        if node == -1:
            return x
        if node == -2:
            return y
        if node not in memo:
            bias, response, act = nodes[node]
            total = sum(w * value(i, x, y, memo) for i, o, w in links if o == node)
            memo[node] = _activation(act, bias + response * total)
        return memo[node]

    half, velocity, z, z_norm = s / 2, 0.0, s / 2, 0.0
    field = np.zeros((200, 200))
    for row in range(200):
        for col in range(200):
            velocity = 0.8 * velocity + 0.08 * np.sign(half - z)
            z += velocity
            if col < 120:
                f = value(0, (col / 5 - 17 - 12) * np.pi / 12, (row / 5 - 20 - 12) * np.pi / 12, {})
                z = half + f
                if row == 110 and col == 110:
                    z_norm = f
                z -= z_norm
            field[row, col] = z
    cppn = (field - field.min()) / (field.max() - field.min()) * (s - 0.2) + 0.2
    rng = np.random.default_rng(seed)
    level = rng.uniform(0.5, s + 0.5)
    r, c = np.ogrid[-1:1:200j, -1:1:200j]
    bowl = (level - np.cos(2 * np.pi * np.clip(np.sqrt(c**2 + r**2), 0.04, 1)) / 2) * ndimage.zoom(
        rng.uniform(0.15, 1, (20, 20)), 10.0
    )
    bowl = (bowl - bowl.min()) / (bowl.max() - bowl.min()) * s
    mixed = 0.3 * bowl + 0.7 * cppn
    return (mixed - mixed.min()) / (mixed.max() - mixed.min())


@pytest.mark.parametrize("name", ["r0c0", "r2c5"])
def test_a_paper_terrain_is_the_reference_arithmetic_on_its_genome(name):
    genomes = json.loads((folder() / "genomes.json").read_text())
    suite = load_suite("paper")
    terrain = suite.by_name(name)
    expected = _reference_heights(genomes[name], terrain.info["seed"])
    assert np.abs(terrain.heightmap - expected).max() <= 1.0 / 65535
    assert terrain.max_height == 1.0 and len(suite.terrains) == 32
    assert suite.level_counts() == {"easy": 9, "medium": 14, "hard": 9, "extreme": 0}


def test_the_authors_pickles_are_read_without_running_their_code(tmp_path):
    # the first genome of the authors' cppngenomes_b, as published
    genome = read_genome(sorted((source() / GENOMES).glob("*.pickle"))[0])
    shipped = json.loads((folder() / "genomes.json").read_text())["r0c0"]
    assert genome == {k: v for k, v in shipped.items() if k != "source"}
    assert genome["nodes"][0][:4] == [0, genome["nodes"][0][1], 10.0, "sin"]
    # a pickle that would call os.system gets a harmless record instead
    evil = tmp_path / "evil.pickle"
    evil.write_bytes(b"cos\nsystem\n(S'touch " + str(tmp_path / "ran").encode() + b"'\ntR.")
    assert type(read_pickle(evil)).__name__ == "system" and not (tmp_path / "ran").exists()
    not_genome = tmp_path / "list.pickle"
    not_genome.write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(ReferenceFileError, match="is not a pickled neat genome"):
        read_genome(not_genome)
    garbage = tmp_path / "garbage.pickle"
    garbage.write_bytes(b"not a pickle")
    with pytest.raises(ReferenceFileError, match="is not a readable pickle"):
        read_genome(garbage)


def test_a_reference_spec_names_a_shipped_agent_or_lists_them(mlflow_uri):
    with pytest.raises(AgentError, match="reference:poet_hexA8/flat") as err:
        resolve_run("reference:poet_hexA8/nope", mlflow_uri)
    assert "\n" not in str(err.value)
    run = resolve_run("reference:poet_twin22/sac_58", mlflow_uri)
    assert (run.algo, run.seed, run.agent_config(None).integrator) == ("epoet_sac", "sac_58", "rk4")
    again = resolve_run("reference:poet_twin22/sac_58", mlflow_uri)
    assert again.run_id == run.run_id  # one MLflow run per agent, made once
    model = mlflow.pyfunc.load_model(f"runs:/{run.run_id}/agent")
    obs = np.zeros((2, 53), dtype=np.float64)
    assert np.allclose(model.predict(obs), run.agent.load()(obs))


def test_the_evaluate_command_runs_a_reference_agent_on_paper_terrains(mlflow_uri, tmp_path):
    """`python -m epoet.eval.evaluate run=reference:...` on a terrain of each level of the paper
    suite (the authors' agents on the whole suite: the committed docs/results/reference/), and
    the figures read its MLflow run like any other."""
    picks = [("easy", 0), ("medium", 0), ("hard", 0)]
    suite = subset_suite(tmp_path / "paper_terrains", picks, "paper")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "epoet.eval.evaluate",
            "run=reference:poet_hexA8/flat",
            f"suite={suite}",
            "episodes=1",
            "processes=1",
            f"out={tmp_path / 'out'}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    assert "success rate" in done.stdout
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["episodes_per_terrain"] == 1 and summary["label"] == "reference:poet_hexA8/flat"
    # a t-SNE panel, no training curves needed
    from analysis.figures import write_figures

    written = write_figures("reference", tmp_path / "figures", str(suite), tracking_uri=mlflow_uri)
    assert tmp_path / "figures" / "tsne.png" in written


def test_the_authors_sac_critics_prefer_their_actors_actions_in_our_layout():
    """The converted twin Q networks (our observation and action order) value the converted
    actor's action above random ones on the states it walks through; a wrong action or
    observation order would scramble that."""
    import torch
    from torch import nn

    from epoet.sac.loss import TwinQ

    entry = manifest()["agents"]["sac/42"]
    spec = torch.load(folder() / entry["critics"], weights_only=True)
    critics = TwinQ(53 + 18, spec["hidden"], nn.ReLU)
    critics.load_state_dict(spec["state_dict"])
    actor = _theirs("sac/42").load()
    env = gym.make(
        ENV_ID, agent={"integrator": "rk4", "max_episode_steps": 300}, terrain={"max_height": 0.1}
    )
    obs, _ = env.reset(seed=0)
    states = []
    for _ in range(300):
        states.append(obs)
        obs, *_ = env.step(actor(obs))
    states = torch.as_tensor(np.array(states[50::10]), dtype=torch.float32)
    with torch.no_grad():
        chosen = critics(states, torch.as_tensor(actor(states.numpy()))).min(0).values
        rng = torch.Generator().manual_seed(0)
        noise = torch.rand((20, *chosen.shape, 18), generator=rng) * 2 - 1
        random = torch.stack([critics(states, a).min(0).values for a in noise]).mean(0)
    assert (chosen > random).float().mean() >= 0.9, chosen - random


def test_the_validation_suite_shares_no_genome_or_terrain_with_the_paper_suite():
    """suite=admitted: 32 genomes of the authors' admitted folders only, none of them (by their
    genes, and by their rendered heights) one of the paper suite's, levelled by rank 9 / 14 / 9."""
    admitted, paper = load_suite("admitted"), load_suite("paper")
    assert len(admitted.terrains) == 32
    by_roughness = sorted(admitted.terrains, key=lambda t: t.roughness)
    assert [t.level for t in by_roughness] == ["easy"] * 9 + ["medium"] * 14 + ["hard"] * 9
    theirs = [read_genome(p) for p in sorted((source() / GENOMES).glob("*.pickle"))]
    genomes = [read_genome(source() / t.info["genome"]) for t in admitted.terrains]
    assert all("/cppngenomes_admitted" in t.info["genome"] for t in admitted.terrains)
    assert not [g for g in genomes if g in theirs]
    assert len({json.dumps(g) for g in genomes}) == 32
    for terrain in admitted.terrains:
        assert not any(np.array_equal(terrain.heightmap, p.heightmap) for p in paper.terrains)
