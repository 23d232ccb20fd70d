"""Generating the evaluation suite (`python -m epoet.eval.suite`): the procedure the module
docstring of epoet/eval/suite.py describes, the suite folder writer, and the bit-for-bit check
of a stored suite against a regeneration (`check=true`, `make suite`)."""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
from pathlib import Path

import numpy as np

from epoet.core.files import atomic_write, savez
from epoet.eval.config import SuiteConfig
from epoet.eval.suite_format import (
    LEVEL_BOUNDS,
    LEVELS,
    SUITE_FORMAT,
    Course,
    dequantize,
    level_of,
    quantize,
)
from epoet.terrain.config import MutationError, TerrainConfig
from epoet.terrain.generate import make_terrain, mutate_terrain
from epoet.terrain.terrain import Terrain


def _miss(roughness: float, level: str) -> float:
    """How far (in log10 units) a roughness lies outside a level's band; 0 inside it."""
    k = LEVELS.index(level)
    lo = LEVEL_BOUNDS[k - 1] if k > 0 else 0.0
    hi = LEVEL_BOUNDS[k] if k < len(LEVEL_BOUNDS) else math.inf
    r = max(roughness, 1e-12)
    return max(
        0.0,
        math.log10(lo) - math.log10(r) if lo > 0 else 0.0,
        math.log10(r) - math.log10(hi) if hi < math.inf else 0.0,
    )


def _at_height(cfg: TerrainConfig, max_height: float) -> TerrainConfig:
    """The terrain config with S fixed at `max_height` (the bowl part's level depends on S)."""
    return dataclasses.replace(cfg, max_height=max_height, max_height_step=0.0)


def generate(cfg: SuiteConfig, progress: bool = False) -> tuple[list[Terrain], list[dict]]:
    """The suite's terrains (heightmaps already quantised as stored) and their index entries."""
    course = Course.of(cfg.agent, cfg.episode_ratio)
    # Each (round, lineage) draws its mutation seeds from its own key, so a suite with fewer
    # rounds or lineages is an exact prefix of a bigger one.
    root_seed = int(np.random.SeedSequence(cfg.seed).generate_state(1)[0])
    root = make_terrain(_at_height(cfg.terrain, cfg.max_heights[0]), root_seed)
    parents = [root] * cfg.children
    terrains, entries = [], []
    for rnd, height in enumerate(cfg.max_heights):
        target = LEVELS[min(rnd, len(LEVELS) - 1)]
        tcfg = _at_height(cfg.terrain, height)
        for lineage in range(cfg.children):
            tries = (
                np.random.SeedSequence(cfg.seed, spawn_key=(rnd, lineage))
                .generate_state(cfg.max_tries)
                .tolist()
            )
            child, rough = _search(parents[lineage], tcfg, course, target, tries)
            parents[lineage] = child
            name = f"r{rnd}l{lineage}"
            terrains.append(child)
            entries.append(
                {
                    "name": name,
                    "level": level_of(rough),
                    "roughness": rough,
                    "max_height": height,
                    "round": rnd,
                    "lineage": lineage,
                    "target": target,
                    "seed": child.seed,
                    "generation": child.generation,
                }
            )
            if progress:
                print(
                    f"  {name}: S={height:.2f} m roughness={rough:.5f} -> {level_of(rough)} "
                    f"(aimed at {target})",
                    flush=True,
                )
    return terrains, entries


def _search(
    parent: Terrain, cfg: TerrainConfig, course: Course, target: str, seeds: list[int]
) -> tuple[Terrain, float]:
    """Mutate until a child lands in `target`; otherwise climb towards it from the closest."""
    best: tuple[float, Terrain, float] | None = None
    current = parent
    for seed in seeds:
        try:
            child = mutate_terrain(current, cfg, seed)
        except MutationError:
            continue
        child = dataclasses.replace(child, heightmap=dequantize(quantize(child.heightmap)))
        rough = course.roughness(child.heightmap, child.max_height, child.size)
        miss = _miss(rough, target)
        if best is None or miss < best[0]:
            best = (miss, child, rough)
            current = child
        if miss == 0.0:
            break
    if best is None:
        raise MutationError(f"no valid mutation of terrain {parent.id} in {len(seeds)} tries.")
    return best[1], best[2]


def write_suite(folder: Path, terrains: list[Terrain], entries: list[dict], course: Course) -> None:
    """Write the three files, each atomically (a failed write leaves the old file)."""
    folder.mkdir(parents=True, exist_ok=True)
    size = terrains[0].size
    index = {
        "format": SUITE_FORMAT,
        "size": size,
        "grid": terrains[0].grid,
        "course": dataclasses.asdict(course),
        "levels": dict(zip(LEVELS[1:], LEVEL_BOUNDS)),
        "terrains": entries,
    }
    with atomic_write(folder / "heights.npz") as f:
        savez(f, {e["name"]: quantize(t.heightmap) for t, e in zip(terrains, entries)})
    with atomic_write(folder / "genomes.npz") as f:
        savez(
            f,
            {
                e["name"]: np.frombuffer(pickle.dumps(t.genome), np.uint8)
                for t, e in zip(terrains, entries)
            },
        )
    with atomic_write(folder / "suite.json") as f:
        f.write((json.dumps(index, indent=1) + "\n").encode())


def differences(folder: Path, terrains: list[Terrain], entries: list[dict]) -> list[str]:
    """What differs between generated terrains and the first ones in `folder`, a suite
    `load_suite` has read (empty: bit for bit; a suite made with fewer rounds is compared with
    the folder's first rounds)."""
    index = json.loads((folder / "suite.json").read_text())
    stored = index["terrains"][: len(entries)]
    if [e["name"] for e in stored] != [e["name"] for e in entries]:
        return [f"terrain names differ: {[e['name'] for e in stored]}"]
    found = []
    if stored != json.loads(json.dumps(entries)):
        found.append("suite.json entries differ")
    with np.load(folder / "heights.npz") as heights, np.load(folder / "genomes.npz") as genomes:
        for terrain, entry in zip(terrains, entries):
            name = entry["name"]
            if not np.array_equal(heights[name], quantize(terrain.heightmap)):
                found.append(f"{name}: heights differ")
            if genomes[name].tobytes() != pickle.dumps(terrain.genome):
                found.append(f"{name}: genome differs")
    return found
