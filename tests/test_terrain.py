"""Terrains: bowl, CPPN (real neat-python genomes), mixing, mutation rules, files, gallery."""
from __future__ import annotations

import copy
import random
import subprocess
import sys
import types
from dataclasses import replace
from pathlib import Path

import neat
import numpy as np
import pytest

from epoet.config import ConfigError, TerrainConfig, compose, load, validate
from epoet.terrain import (CppnMutationError, Terrain, TerrainFileError, evaluate,
                           genome_config, grid_inputs, make_terrain, max_height_at, mix,
                           mutate_genome, mutate_terrain, new_genome, normalize, random_bowl)
from epoet.terrain.cppn import _ACTIVATIONS, fingerprint, has_input_output_path

ROOT = Path(__file__).resolve().parents[1]
CPPN = load(["budget=paper"]).terrain       # the paper's ePOET terrain (conf/terrain/cppn.yaml)
BOWL = load(["algo=ppo", "budget=paper"]).terrain  # the baselines' (conf/terrain/bowl.yaml)


@pytest.fixture
def cfg() -> TerrainConfig:
    return copy.deepcopy(replace(CPPN, grid=40, max_height=0.2))  # tests may edit cfg.cppn


def neat_network(genome: neat.DefaultGenome, cfg: TerrainConfig) -> neat.nn.FeedForwardNetwork:
    # FeedForwardNetwork.create reads only `config.genome_config`.
    holder = types.SimpleNamespace(genome_config=genome_config(cfg.cppn))
    return neat.nn.FeedForwardNetwork.create(genome, holder)


# ---------------------------------------------------------------- CPPN evaluation

@pytest.mark.parametrize("aggregations", [["sum"], ["sum", "product", "max", "min", "mean"]])
def test_vectorised_cppn_equals_neat_feed_forward_network(cfg, aggregations):
    cfg.cppn.aggregation_options = aggregations
    cfg.cppn.aggregation_default = "random"
    genomes = [new_genome(cfg.cppn, 3)]
    terrain = make_terrain(cfg, 3, genome=genomes[0])
    for seed in range(11, 23):  # a chain of mutations: nodes are added and deleted
        terrain = mutate_terrain(terrain, cfg, seed)
        genomes.append(terrain.genome)
    assert max(len(g.nodes) for g in genomes) > len(genomes[0].nodes)
    points = np.random.default_rng(0).uniform(-1.0, 1.0, size=(200, 2))
    for genome in genomes:
        net = neat_network(genome, cfg)
        expected = np.array([net.activate(list(p))[0] for p in points])
        got = evaluate(genome, points[:, 0], points[:, 1])
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_every_numpy_activation_equals_neats():
    neat_defs = neat.activations.ActivationFunctionSet()
    z = np.concatenate([np.linspace(-15.0, 15.0, 301), [0.0, 1e-9, -1e-9, 80.0, -80.0]])
    for name, fn in _ACTIVATIONS.items():
        expected = np.array([neat_defs.get(name)(float(v)) for v in z])
        np.testing.assert_allclose(fn(z), expected, rtol=1e-13, atol=1e-15, err_msg=name)


def test_grid_inputs_put_x_along_columns_and_y_along_rows():
    x, y = grid_inputs(5)
    assert x[0, 0] == -1.0 and x[0, -1] == 1.0 and np.all(x[:, 2] == x[0, 2])
    assert y[0, 0] == -1.0 and y[-1, 0] == 1.0 and np.all(y[2, :] == y[2, 0])


def test_genome_creation_is_seeded_and_leaves_the_global_random_stream_alone(cfg):
    random.seed(123)
    expected = random.random()
    random.seed(123)
    a = new_genome(cfg.cppn, 5)
    assert random.random() == expected
    assert fingerprint(a) == fingerprint(new_genome(cfg.cppn, 5))
    assert fingerprint(a) != fingerprint(new_genome(cfg.cppn, 6))
    assert a.nodes[0].activation == "sin" and len(a.nodes) == 3  # output + 2 hidden (Table 5)


# ---------------------------------------------------------------- mutation

def test_mutated_child_obeys_the_validity_rules(cfg):
    parent = make_terrain(cfg, 1)
    child = mutate_terrain(parent, cfg, 7, iteration=10)
    rules, gc = cfg.mutation, genome_config(cfg.cppn)
    assert has_input_output_path(child.genome)                                   # (a)
    assert parent.genome.distance(child.genome, gc) > rules.min_genome_distance  # (b), and
    # test_children_are_far_enough_from_parents_whose_response_needs_no_reset below
    out = evaluate(child.genome, *grid_inputs(rules.check_grid))                 # (c)
    shifted = out - out[0, 0]
    assert shifted.max() > rules.min_range and shifted.var() > rules.min_variance
    assert child.generation == parent.generation + 1 and child.parent_id == parent.id
    assert child.max_height == pytest.approx(max_height_at(cfg, 10))


def test_children_are_far_enough_from_parents_whose_response_needs_no_reset(cfg):
    """Rule (b) itself: a root's output response (1.0) is reset to `output_response` before
    mutating, which alone exceeds the distance bar, so test parents already at that value."""
    rules, gc = cfg.mutation, genome_config(cfg.cppn)
    parent = make_terrain(cfg, 1).genome
    parent.nodes[0].response = rules.output_response
    distances = [parent.distance(mutate_genome(parent, cfg.cppn, rules, seed, cfg.grid), gc)
                 for seed in range(12)]
    assert min(distances) > rules.min_genome_distance


def test_an_out_of_range_output_is_rescaled_as_the_reference_does(cfg):
    """Peak outside [rescale_low, rescale_high]: response = U(target_low, target_high) / peak."""
    rules = cfg.mutation
    child = mutate_genome(make_terrain(cfg, 1).genome, cfg.cppn, rules, 11, cfg.grid)
    probe = copy.deepcopy(child)
    probe.nodes[0].response = rules.output_response  # the output the rule judged
    out = evaluate(probe, *grid_inputs(rules.check_grid))
    peak = float((out - out.flat[0]).max())
    assert rules.min_range < peak < rules.response_rescale_low, "seed 11 must need a rescale"
    response = child.nodes[0].response
    assert rules.response_target_low / peak <= response <= rules.response_target_high / peak


def test_mutation_is_deterministic_per_seed(cfg):
    parent = make_terrain(cfg, 1)
    a, b = mutate_terrain(parent, cfg, 7), mutate_terrain(parent, cfg, 7)
    np.testing.assert_array_equal(a.heightmap, b.heightmap)
    assert fingerprint(a.genome) == fingerprint(b.genome) and a.id == b.id
    c = mutate_terrain(parent, cfg, 8)
    assert fingerprint(c.genome) != fingerprint(a.genome)
    assert not np.array_equal(c.heightmap, a.heightmap)


def test_mutation_without_a_valid_child_raises_a_clear_error(cfg):
    cfg.mutation.min_genome_distance = 1e9
    cfg.mutation.max_tries = 3
    with pytest.raises(CppnMutationError, match="no valid CPPN child in 3 tries"):
        mutate_terrain(make_terrain(cfg, 1), cfg, 7)


def test_bowl_terrains_do_not_mutate(cfg):
    bowl = make_terrain(replace(BOWL, grid=40), 1)
    with pytest.raises(ValueError, match="only CPPN terrains mutate"):
        mutate_terrain(bowl, cfg, 2)


# ---------------------------------------------------------------- bowl, mixing, schedule

def test_bowl_is_in_unit_range_and_deterministic():
    a = random_bowl(np.random.default_rng(4), 50, 0.5)
    assert a.shape == (50, 50) and a.min() == 0.0 and a.max() == 1.0
    np.testing.assert_array_equal(a, random_bowl(np.random.default_rng(4), 50, 0.5))
    assert not np.array_equal(a, random_bowl(np.random.default_rng(5), 50, 0.5))


def test_mixed_heightmap_is_in_unit_range_and_weight_one_is_bowl_only(cfg):
    terrain = make_terrain(cfg, 2)
    assert terrain.heightmap.min() >= 0.0 and terrain.heightmap.max() <= 1.0
    assert terrain.heightmap.max() == 1.0 and terrain.kind == "cppn"
    bowl = random_bowl(np.random.default_rng(2), 40, 0.2)
    cppn = evaluate(terrain.genome, *grid_inputs(40))
    np.testing.assert_array_equal(mix(bowl, cppn, 1.0), bowl)
    np.testing.assert_allclose(mix(bowl, cppn, 0.3),
                               normalize(0.3 * bowl + 0.7 * normalize(cppn)))


def test_a_constant_map_normalises_to_flat_ground():
    np.testing.assert_array_equal(normalize(np.full((8, 8), 3.7)), np.zeros((8, 8)))


def test_max_height_schedule_grows_by_the_step_and_stops_at_the_limit(cfg):
    assert max_height_at(cfg, 0) == cfg.max_height
    assert max_height_at(cfg, 10) == pytest.approx(cfg.max_height + 10 * cfg.max_height_step)
    assert max_height_at(cfg, 10**6) == cfg.max_height_limit


# ---------------------------------------------------------------- files
def test_terrains_keep_the_reference_feature_scale():
    """Features live in normalised coordinates, so the extent sets the slopes: at the same S the
    terrain users run must be as steep as the reference's 40 m x 40 m, 200 x 200 field (a 20 m
    field would be twice as steep)."""
    users = CPPN
    reference = replace(users, size=40.0, grid=200)

    def max_slope(tc: TerrainConfig, genome: neat.DefaultGenome) -> float:
        """Steepest grid step per metre of S (budgets change S's schedule, not the geometry)."""
        t = make_terrain(tc, seed=4, iteration=50, genome=genome)
        metres = t.heightmap  # in units of S
        spacing = tc.size / (tc.grid - 1)
        return max(np.abs(np.diff(metres, axis=0)).max(), np.abs(np.diff(metres, axis=1)).max()) \
            / spacing

    genome = mutate_genome(new_genome(reference.cppn, 2), reference.cppn, reference.mutation, 5,
                           reference.grid)
    assert max_slope(users, genome) == pytest.approx(max_slope(reference, genome), rel=0.1)



@pytest.mark.parametrize("kind", ["bowl", "cppn"])
def test_save_load_round_trips_exactly(tmp_path, kind):
    terrain = make_terrain(replace(CPPN if kind == "cppn" else BOWL, grid=40), 9, iteration=3)
    loaded = Terrain.load(terrain.save(tmp_path / "t.npz"))
    np.testing.assert_array_equal(loaded.heightmap, terrain.heightmap)
    assert loaded.heightmap.dtype == np.float64
    for name in ("id", "kind", "seed", "generation", "parent_id", "max_height", "size"):
        assert getattr(loaded, name) == getattr(terrain, name)
    if kind == "cppn":
        x, y = grid_inputs(40)
        np.testing.assert_array_equal(evaluate(loaded.genome, x, y), evaluate(terrain.genome, x, y))
    else:
        assert loaded.genome is None
    assert [p.name for p in tmp_path.iterdir()] == ["t.npz"]  # no temp file left behind


def test_missing_file_is_a_terrain_file_error_naming_the_path(tmp_path):
    path = tmp_path / "nope.npz"
    with pytest.raises(TerrainFileError, match=f"{path} does not exist"):
        Terrain.load(path)


def test_corrupt_files_are_terrain_file_errors(tmp_path, cfg):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file at all")
    with pytest.raises(TerrainFileError, match=f"{garbage} is corrupt"):
        Terrain.load(garbage)
    good = make_terrain(cfg, 1).save(tmp_path / "good.npz")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:2000])
    with pytest.raises(TerrainFileError, match=f"{truncated} is corrupt"):
        Terrain.load(truncated)
    with np.load(good) as data:  # metadata edited by hand: the stored id no longer matches
        arrays = dict(data)
    arrays["meta"] = np.array(str(arrays["meta"][()]).replace('"seed": 1', '"seed": 2'))
    tampered = tmp_path / "tampered.npz"
    np.savez(tampered, **arrays)
    with pytest.raises(TerrainFileError, match="do not match its stored id"):
        Terrain.load(tampered)


def test_to_png_writes_an_image(tmp_path, cfg):
    path = make_terrain(cfg, 1).to_png(tmp_path / "t.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------- bad input

def test_unknown_kind_is_rejected_by_make_terrain(cfg):
    cfg.kind = "hill"  # the schema rejects it too; the public function must not trust that
    with pytest.raises(ValueError, match="terrain.kind must be 'bowl' or 'cppn', got 'hill'"):
        make_terrain(cfg, 0)


@pytest.mark.parametrize("field, value", [("grid", 0), ("grid", -3), ("size", 0.0),
                                          ("size", -1.0)])
def test_non_positive_sizes_fail_validation_naming_the_field(field, value):
    raw = compose([f"terrain.{field}={value}"], config_name="gallery")
    with pytest.raises(ConfigError, match=f"terrain.{field} must be > 0"):
        validate(raw)


def test_a_genome_on_a_bowl_terrain_and_negative_seeds_are_rejected(cfg):
    with pytest.raises(ValueError, match="takes no CPPN genome"):
        make_terrain(replace(BOWL, grid=40), 0, genome=new_genome(cfg.cppn, 0))
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        make_terrain(cfg, -1)


# ---------------------------------------------------------------- gallery command

def run_gallery(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "epoet.terrain", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def test_gallery_writes_a_png_and_the_terrains(tmp_path):
    out = tmp_path / "gal"
    proc = run_gallery("terrain=cppn", "n=3", "terrain.grid=40", f"out={out}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (out / "gallery.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    saved = sorted(Terrain.load(p).generation for p in out.glob("*.npz"))
    assert saved == [0, 1, 2]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gal"]  # no outputs/ or logs


def test_gallery_bad_value_exits_non_zero_with_one_line(tmp_path):
    proc = run_gallery("n=-1", f"out={tmp_path / 'gal'}", cwd=tmp_path)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "n must be > 0" in lines[0]
    proc = run_gallery("terrain=unknown", cwd=tmp_path)
    assert proc.returncode != 0 and len(proc.stderr.strip().splitlines()) == 1
    assert "terrain/unknown" in proc.stderr
