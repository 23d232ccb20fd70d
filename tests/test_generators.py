"""The terrain generator as a part (epoet/terrain/config.py `TerrainGenerator`): the registry of
kinds, and a second evolving generator, registered here, that ePOET reproduces through its real
loop, runner, tracker and artifacts."""

from __future__ import annotations

import sys
from pathlib import Path

import mlflow
import numpy as np
import pytest

import epoet.terrain
from conftest import BUSY_LOOP, TINY_EPOET
from epoet.config import load
from epoet.core.schema import ConfigError
from epoet.run import run
from epoet.terrain import Terrain, make_terrain, mutate_terrain, normalize, register
from epoet.terrain import config as terrain_config
from epoet.terrain.bowl import BowlGenerator
from epoet.terrain.config import MutationError, TerrainConfig

SHORTEST = 1.0  # metres: a mutation that shortens a ridge below this fails


class Ridges:
    """A toy kind: ridges across the course, one per wavelength (metres) of the genome, at a phase
    drawn from the seed; a child stretches or shrinks one ridge."""

    kind = "ridges"
    evolves = True
    unused_keys = BowlGenerator.unused_keys  # the CPPN's settings

    def encode(self, cfg: TerrainConfig, seed: int) -> tuple[float, ...]:
        return tuple(float(w) for w in np.random.default_rng(seed).uniform(2.0, 6.0, 3))

    def mutate(self, cfg: TerrainConfig, parent: tuple[float, ...], seed: int) -> tuple[float, ...]:
        rng = np.random.default_rng(seed)
        child = list(parent)
        k = int(rng.integers(len(child)))
        child[k] *= float(rng.uniform(0.5, 1.5))
        if child[k] < SHORTEST:
            raise MutationError(f"ridge {k} would be shorter than {SHORTEST} m.")
        return tuple(child)

    def render(
        self, cfg: TerrainConfig, genome: tuple[float, ...], seed: int, max_height: float
    ) -> np.ndarray:
        x = np.linspace(-cfg.size / 2, cfg.size / 2, cfg.grid)
        phase = np.random.default_rng(seed).uniform(0.0, 2 * np.pi)
        profile = sum(np.sin(2 * np.pi * x / w + phase) for w in genome)
        return normalize(np.tile(profile, (cfg.grid, 1)))  # rows follow y, columns x

    def describe(self, genome: tuple[float, ...]) -> str:
        return ",".join(map(repr, genome))

    def check(self, genome: object) -> None:
        if not (isinstance(genome, tuple) and all(isinstance(w, float) for w in genome)):
            raise ValueError("a 'ridges' terrain needs a tuple of wavelengths.")


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch) -> dict:
    """The registry as it is, restored after the test (a kind registered here leaves with it)."""
    generators = dict(terrain_config.GENERATORS)
    monkeypatch.setattr(terrain_config, "GENERATORS", generators)
    return generators


@pytest.fixture
def ridges(registry: dict) -> Ridges:
    return register(Ridges())


def test_the_built_in_kinds_are_registered_once_and_the_config_checks_against_them(
    registry: dict,
) -> None:
    assert sorted(registry) == ["bowl", "cppn"]
    with pytest.raises(ConfigError, match="terrain.kind must be 'bowl' or 'cppn', got 'lava'"):
        load(["terrain.kind=lava"])
    register(Ridges())
    with pytest.raises(ConfigError, match="must be 'bowl', 'cppn' or 'ridges', got 'lava'"):
        load(["terrain.kind=lava"])
    with pytest.raises(ConfigError, match="needs terrain=cppn or terrain=ridges .got terrain=bowl"):
        load(["terrain=bowl"])  # ePOET evolves its environments; the bowl does not mutate
    assert load(["terrain.kind=ridges"]).unused_keys()[:2] == ("terrain.cppn", "terrain.mutation")


def test_a_generator_is_found_by_the_name_of_its_module(
    registry: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest
) -> None:
    """`terrain.kind=dunes` imports epoet/terrain/dunes.py, which registers its generator: a new
    kind is one module (here in a folder added to the package's path) and its YAML."""
    (tmp_path / "dunes.py").write_text(
        "from epoet.terrain.bowl import BowlGenerator\n"
        "from epoet.terrain.config import register\n\n\n"
        "class Dunes(BowlGenerator):\n"
        '    kind = "dunes"\n\n\n'
        "register(Dunes())\n"
    )
    monkeypatch.setattr(epoet.terrain, "__path__", [*epoet.terrain.__path__, str(tmp_path)])

    def forget() -> None:
        sys.modules.pop("epoet.terrain.dunes", None)
        vars(epoet.terrain).pop("dunes", None)

    request.addfinalizer(forget)
    assert "dunes" not in registry
    cfg = load(["algo=ppo", "terrain.kind=dunes"]).terrain
    assert "dunes" in registry
    dunes, bowl = make_terrain(cfg, 3), make_terrain(load(["algo=ppo"]).terrain, 3)
    assert dunes.kind == "dunes" and dunes.id.startswith("dunes-g0-s3-")
    np.testing.assert_array_equal(dunes.heightmap, bowl.heightmap)


def test_a_registered_generators_terrains_mutate_render_and_round_trip(
    ridges: Ridges, tmp_path: Path
) -> None:
    cfg = load(["terrain.kind=ridges", "terrain.grid=40"]).terrain
    root = make_terrain(cfg, 5, iteration=2)
    assert root.kind == "ridges" and len(root.genome) == 3 and root.heightmap.shape == (40, 40)
    assert root.max_height == cfg.max_height + 2 * cfg.max_height_step  # the schedule's S
    child = mutate_terrain(root, cfg, 9, iteration=3)
    assert child.generation == 1 and child.parent_id == root.id
    assert sum(a != b for a, b in zip(root.genome, child.genome)) == 1  # one ridge changed
    loaded = Terrain.load(child.save(tmp_path / "child.npz"))
    assert loaded.id == child.id and loaded.genome == child.genome
    np.testing.assert_array_equal(loaded.heightmap, child.heightmap)
    with pytest.raises(ValueError, match="needs a tuple of wavelengths"):
        make_terrain(cfg, 5, genome=make_terrain(load([]).terrain, 5).genome)  # a CPPN's


def test_epoet_reproduces_a_registered_generators_environments(
    ridges: Ridges, compose, mlflow_uri: str, tmp_path: Path
) -> None:
    """A smoke run on ridges: reproduction (t = 2) admits mutated children of the root, each
    pair's terrain is its genome rendered, and the artifacts and params are the kind's."""
    loop = run(
        compose([*TINY_EPOET, *BUSY_LOOP, "terrain.kind=ridges", "budget.iterations=3"]),
        tmp_path / "run",
    )
    root, *children = loop.pool.pairs
    assert children, "reproduction should have admitted a child"
    for pair in children:
        assert pair.env.generation == 1 and pair.env.parent == 0
        assert sum(a != b for a, b in zip(root.env.genome, pair.env.genome)) == 1
    for pair in loop.pool.pairs:
        saved = Terrain.load(tmp_path / "run" / "terrains" / f"env{pair.env.index}.npz")
        assert saved.kind == "ridges" and saved.genome == pair.env.genome
        assert saved.generation == pair.env.generation
    client = mlflow.MlflowClient(mlflow_uri)
    (mlflow_run,) = client.search_runs([client.get_experiment_by_name("epoet").experiment_id])
    assert mlflow_run.data.tags["terrain"] == "ridges"
    assert not any(k.startswith("terrain.cppn") for k in mlflow_run.data.params)
