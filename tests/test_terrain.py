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

from epoet.config import compose, load, validate
from epoet.core.schema import ConfigError
from epoet.eval.gallery import COMMAND as GALLERY
from epoet.terrain import (
    CppnMutationError,
    Terrain,
    TerrainFileError,
    check_inputs,
    cppn_inputs,
    evaluate,
    genome_config,
    make_terrain,
    max_height_at,
    mix,
    mutate_genome,
    mutate_terrain,
    new_genome,
    normalize,
    random_bowl,
)
from epoet.terrain.config import TerrainConfig
from epoet.terrain.cppn import _ACTIVATIONS, fingerprint, has_input_output_path

ROOT = Path(__file__).resolve().parents[1]
CPPN = load(["budget=paper", "terrain.rendering=clean"]).terrain  # conf/terrain/cppn.yaml, clean
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
        try:
            terrain = mutate_terrain(terrain, cfg, seed)
        except CppnMutationError:
            continue  # a seed whose tries found no valid child; the chain goes on from here
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


def test_cppn_inputs_put_x_along_columns_and_y_along_rows(cfg):
    x, y = cppn_inputs(cfg)
    assert np.all(x[:, 2] == x[0, 2]) and np.all(y[2, :] == y[2, 0])
    assert x[0, 1] > x[0, 0] and y[1, 0] > y[0, 0]
    # Input (0, 0) lies at terrain.cppn_origin, and the inputs advance cppn_scale per metre.
    metres = np.linspace(-cfg.size / 2, cfg.size / 2, cfg.grid)
    np.testing.assert_allclose(x[0], (metres - cfg.cppn_origin[0]) * cfg.cppn_scale)
    np.testing.assert_allclose(y[:, 0], (metres - cfg.cppn_origin[1]) * cfg.cppn_scale)


def test_the_check_grid_is_the_references():
    """The reference checks children on ((i - 10) / 10, (j - 10) / 10) for i, j < 20."""
    x, y = check_inputs(20)
    assert x.shape == (20, 20) and x[0, 0] == y[0, 0] == -1.0
    assert x[0, -1] == pytest.approx(0.9) and y[-1, 0] == pytest.approx(0.9)


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
    assert has_input_output_path(child.genome)  # (a)
    assert parent.genome.distance(child.genome, gc) > rules.min_genome_distance  # (b), and
    # test_children_are_far_enough_from_parents_whose_response_needs_no_reset below
    out = evaluate(child.genome, *check_inputs(rules.check_grid))  # (c)
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
    distances = [
        parent.distance(mutate_genome(parent, cfg.cppn, rules, seed, cppn_inputs(cfg)), gc)
        for seed in range(12)
    ]
    assert min(distances) > rules.min_genome_distance


def _judged_peak(child: neat.DefaultGenome, rules) -> float:
    """The check-grid peak the rescale rule saw: the child's output at `output_response`."""
    probe = copy.deepcopy(child)
    probe.nodes[0].response = rules.output_response
    out = evaluate(probe, *check_inputs(rules.check_grid))
    return float((out - out.flat[0]).max())


def test_out_of_range_outputs_are_rescaled_as_the_reference_does(cfg):
    """The reference: a peak below 0.25 sets the response to U(0.25, 0.75) / peak, a peak above 16
    to U(12, 16) / peak; within [0.25, 16] the response stays at output_response."""
    rules, root = cfg.mutation, make_terrain(cfg, 1).genome
    steep = copy.deepcopy(root)  # a square output with strong inputs: its peaks pass 16
    steep.nodes[0].activation = "square"
    for (_, out), gene in steep.connections.items():
        gene.weight *= 4.0 if out == 0 else 1.0
    seen = {"small": False, "large": False, "kept": False}
    for seed in range(30):
        child = mutate_genome((root, steep)[seed % 2], cfg.cppn, rules, seed, cppn_inputs(cfg))
        peak, response = _judged_peak(child, rules), child.nodes[0].response
        if peak < 0.25:
            assert 0.25 / peak <= response <= 0.75 / peak
            seen["small"] = True
        elif peak > 16.0:
            assert 12.0 / peak <= response <= 16.0 / peak
            seen["large"] = True
        else:
            assert response == rules.output_response
            seen["kept"] = True
    assert all(seen.values()), f"seeds 0-29 must cover every case, saw {seen}"


def test_only_the_root_output_is_forced_to_sin(cfg):
    """The reference sets sin on the root genome; children keep the activation mutation gives."""
    root = make_terrain(cfg, 1).genome
    assert root.nodes[0].activation == "sin"
    children = [
        mutate_genome(root, cfg.cppn, cfg.mutation, seed, cppn_inputs(cfg)) for seed in range(40)
    ]
    assert {c.nodes[0].activation for c in children} - {"sin"}


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
    with pytest.raises(ValueError, match="only 'cppn' terrains mutate"):
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
    cppn = evaluate(terrain.genome, *cppn_inputs(cfg))
    np.testing.assert_array_equal(mix(bowl, cppn, 1.0), bowl)
    # Worked by hand (paper: w = 0.3): each part is normalised first (the bowl 0..4 to 0..1, the
    # CPPN 10..30 to 0..1), w weighs the bowl, and the sum is normalised again:
    # 0.3 * [0, .5, 1, .25] + 0.7 * [0, 1, .5, .25] = [0, .85, .65, .25], / .85.
    bowl, cppn = np.array([0.0, 2.0, 4.0, 1.0]), np.array([10.0, 30.0, 20.0, 15.0])
    np.testing.assert_allclose(mix(bowl, cppn, 0.3), [0.0, 1.0, 0.65 / 0.85, 0.25 / 0.85])
    np.testing.assert_allclose(mix(bowl, cppn, 0.0), [0.0, 1.0, 0.5, 0.25])  # the CPPN alone
    np.testing.assert_allclose(mix(bowl, cppn, 1.0), [0.0, 0.5, 1.0, 0.25])  # the bowl alone


def test_a_constant_map_normalises_to_flat_ground():
    np.testing.assert_array_equal(normalize(np.full((8, 8), 3.7)), np.zeros((8, 8)))


def test_max_height_schedule_grows_by_the_step_and_stops_at_the_limit(cfg):
    assert max_height_at(cfg, 0) == cfg.max_height
    assert max_height_at(cfg, 10) == pytest.approx(cfg.max_height + 10 * cfg.max_height_step)
    assert max_height_at(cfg, 10**6) == cfg.max_height_limit


# ---------------------------------------------------------------- files
def _wavelength(profile: np.ndarray, spacing: float) -> float:
    """Mean wavelength (metres) of a height profile, 2 pi rms(h) / rms(dh/dx) after removing its
    linear trend: exact for a sinusoid, and not snapped to a short window's frequency bins."""
    x = np.arange(profile.size)
    h = profile - np.polyval(np.polyfit(x, profile, 1), x)
    return float(2 * np.pi * np.sqrt(np.mean(h**2)) / np.sqrt(np.mean((np.diff(h) / spacing) ** 2)))


@pytest.mark.parametrize("seed", [3, 8, 10, 11])
def test_cppn_features_have_the_reference_wavelength(seed):
    """The reference evaluates its CPPN at cell (row r, column c < 120) on x = (c/5 - 17 - 12)
    pi/12, y = (r/5 - 20 - 12) pi/12, with the spawn at c = 85 (x = 0) and 5 cells per metre.
    Along the spawn row (r = 100), the features our terrain puts on the same metres must have
    the same dominant wavelength (the old [-1, 1]-over-the-field inputs made them ~5x longer)."""
    cfg = replace(CPPN, bowl_weight=0.0, max_height=1.0)  # the CPPN part alone
    genome = new_genome(cfg.cppn, seed)
    for step in range(3):
        genome = mutate_genome(genome, cfg.cppn, cfg.mutation, 100 * seed + step, cppn_inputs(cfg))
    cells = np.arange(120)
    reference = evaluate(
        genome,
        (cells / 5 - 17 - 12) * np.pi / 12,
        np.full(cells.size, (100 / 5 - 20 - 12) * np.pi / 12),
    )
    expected = _wavelength(reference, 0.2)
    assert expected < 12.0, "the window must hold a few features for the measure to mean much"
    # Our field, on the same metres: robot-frame x (c/5 - 17) sits at agent.start_x + that.
    start_x = load([]).agent.start_x
    metres = np.linspace(-cfg.size / 2, cfg.size / 2, cfg.grid)
    cols = (metres >= start_x - 17) & (metres < start_x + 7)
    row = int(np.argmin(np.abs(metres)))
    ours = make_terrain(cfg, seed=1, genome=genome).heightmap[row, cols]
    assert _wavelength(ours, cfg.size / (cfg.grid - 1)) == pytest.approx(expected, rel=0.2)


@pytest.mark.parametrize("kind", ["bowl", "cppn"])
def test_save_load_round_trips_exactly(tmp_path, kind):
    terrain = make_terrain(replace(CPPN if kind == "cppn" else BOWL, grid=40), 9, iteration=3)
    loaded = Terrain.load(terrain.save(tmp_path / "t.npz"))
    np.testing.assert_array_equal(loaded.heightmap, terrain.heightmap)
    assert loaded.heightmap.dtype == np.float64
    for name in ("id", "kind", "seed", "generation", "parent_id", "max_height", "size"):
        assert getattr(loaded, name) == getattr(terrain, name)
    if kind == "cppn":
        x, y = check_inputs(40)
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


@pytest.mark.parametrize("field, value", [("grid", 0), ("grid", -3), ("size", 0.0), ("size", -1.0)])
def test_non_positive_sizes_fail_validation_naming_the_field(field, value):
    raw = compose([f"terrain.{field}={value}"], config_name=GALLERY.name)
    with pytest.raises(ConfigError, match=f"terrain.{field} must be > 0"):
        validate(raw)


def test_a_genome_on_a_bowl_terrain_and_negative_seeds_are_rejected(cfg):
    with pytest.raises(ValueError, match="takes no genome"):
        make_terrain(replace(BOWL, grid=40), 0, genome=new_genome(cfg.cppn, 0))
    with pytest.raises(ValueError, match="seed must be an integer >= 0"):
        make_terrain(cfg, -1)


# ---------------------------------------------------------------- gallery command


def run_gallery(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "epoet.eval.gallery", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
    )


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


# ---------------------------------------------------------------- the reference's rendering


def _course_centre(terrain) -> np.ndarray:
    """Heights along the course centre: the five rows around y = 0, columns 80-180."""
    return terrain.heightmap[98:103, 80:180].mean(axis=0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_reference_rendering_has_the_step_and_the_clean_one_does_not(seed):
    """`terrain.rendering=reference` puts the reference's step where its CPPN window ends
    (column 120, 6.7 m past the spawn): the largest height change along the course centre is
    there; the clean rendering of the same genome and bowl has no step there."""
    reference = make_terrain(replace(CPPN, rendering="reference"), seed, iteration=90)
    clean = make_terrain(CPPN, seed, iteration=90)
    assert reference.max_height == clean.max_height == 1.0  # the niche's S from the schedule
    steps = np.abs(np.diff(_course_centre(reference)))
    assert abs(80 + int(steps.argmax()) - 120) <= 2
    clean_steps = np.abs(np.diff(_course_centre(clean)))
    assert abs(80 + int(clean_steps.argmax()) - 120) > 2
    assert clean_steps[38:43].max() < steps.max() / 2


def test_the_reference_rendering_drifts_beyond_its_window():
    """Beyond column 120 the reference reads no CPPN: each row drifts to the same constant, so
    two genomes on the same bowl differ inside the window and barely beyond it; rendered clean,
    they differ on both sides."""
    a, b = (
        mutate_genome(new_genome(CPPN.cppn, s), CPPN.cppn, CPPN.mutation, s, cppn_inputs(CPPN))
        for s in (4, 5)
    )

    def window_and_beyond(cfg):
        gap = np.abs(
            make_terrain(cfg, 7, 90, genome=a).heightmap
            - make_terrain(cfg, 7, 90, genome=b).heightmap
        )
        return gap[:, 20:110].mean(), gap[:, 160:].mean()

    inside, beyond = window_and_beyond(replace(CPPN, rendering="reference"))
    assert beyond < inside / 5
    inside, beyond = window_and_beyond(CPPN)
    assert beyond > inside / 5


def test_the_reference_rendering_is_refused_off_its_field():
    with pytest.raises(ConfigError, match="terrain.rendering=reference is defined on"):
        validate(compose(["terrain.rendering=reference", "terrain.size=30"]))


def test_the_reference_rendering_on_another_grid_is_the_same_terrain_resampled():
    fine = make_terrain(replace(CPPN, rendering="reference"), 2, iteration=90)
    coarse = make_terrain(replace(CPPN, rendering="reference", grid=100), 2, iteration=90)
    assert coarse.heightmap.shape == (100, 100)
    at = np.round(np.linspace(0, 199, 100)).astype(int)
    assert np.abs(coarse.heightmap - fine.heightmap[np.ix_(at, at)]).mean() < 0.02
    with pytest.raises(ConfigError, match="terrain.rendering must be"):
        validate(compose(["terrain.rendering=fancy"]))
