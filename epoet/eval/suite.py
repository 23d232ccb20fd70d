"""The fixed evaluation suite: 32 CPPN terrains at four difficulty levels (paper Section 4).

The paper evaluates every agent on 32 terrains taken from a separate ePOET run (4 reproduction
rounds x 8 children). Here the suite comes from a deterministic procedure of the same shape that
needs no agent: `children` lineages start from one root genome, and each reproduction round
mutates every lineage's last terrain once more, with S rising round by round. A lineage keeps
the first mutation whose course roughness falls in the round's level (round r aims at level r,
the way ePOET's minimal criterion keeps children that are neither too easy nor too hard); when
none of `max_tries` mutations does, it keeps the one closest to that level and its level is
whatever its roughness says.

Difficulty is the terrain's **course roughness**: the variance of the 5 x 5 height patch (metres)
under each cell, averaged over the straight course the robot walks (x from the agent's start_x
to finish_x, |y| <= the spawn footprint). The buckets are the reference's (docs/reference.md
"Evaluation"): easy < 0.001 <= medium < 0.01 <= hard < 0.1 <= extreme. The reference read the
variance under the robot along its own path; a fixed course makes the level a property of the
terrain, the same for every agent.

Suite folder format (any folder in this format can be evaluated, `suite=<folder>`):
- `suite.json`: {"format": "epoet-suite/2", "size": metres per side, "grid": samples per side,
  "course": {"start_x", "finish_x", "half_width", "episode_steps", "episode_ratio"},
  "terrains": [{"name",
  "max_height", and
  optionally "level", "roughness", "round", "lineage", "seed", "generation"}, ...]};
  a terrain without "level" gets it from its roughness along "course".
- `heights.npz`: one (grid, grid) array per terrain name with heights in [0, 1] (uint16 as
  q / 65535, or float); height 1 stands for the terrain's max_height metres.
- `genomes.npz` (optional): each terrain's pickled neat genome as uint8, for provenance.

A suite's NAME keys its evaluations in a run (`epoet.eval.keys`): "shipped" (epoet/suite/),
"paper" (the authors' evaluation terrains) and "admitted" (the validation suite: terrains their
runs admitted; both converted on use from their files, epoet/eval/reference/suites.py), the
`SUITES`, or another folder's (`suite_name`).

This module is the format, its loader and the command `python -m epoet.eval.suite`; the
procedure above and the writer live in epoet/eval/suite_generation.py, and what the two share
(the course, the levels, the stored heights) in epoet/eval/suite_format.py.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from epoet.cli import KeyValueCommand
from epoet.config import load
from epoet.core.cli import fail
from epoet.core.schema import ConfigError, closest
from epoet.eval.config import SuiteConfig
from epoet.eval.keys import ADMITTED_NAME, PAPER_NAME, SHIPPED_NAME
from epoet.eval.suite_format import (
    LEVELS,
    SHIPPED,
    SUITE_FORMAT,
    Course,
    dequantize,
    level_of,
)
from epoet.eval.suite_generation import differences, generate, write_suite
from epoet.terrain.config import MutationError, TerrainConfig


class SuiteError(ValueError):
    """A suite folder that cannot be used; the message names the folder and the problem."""


def _converted(subfolder: str) -> Callable[[], Path]:
    """An authors' suite: its folder in their files' conversion, made on first use."""

    def folder() -> Path:
        from epoet.eval.reference import folder as reference_folder
        from epoet.eval.reference.files import ReferenceFileError

        try:
            return reference_folder() / subfolder
        except ReferenceFileError as err:
            raise SuiteError(str(err)) from None

    return folder


# The named suites, each a function giving its folder (the authors' need their files).
SUITES: dict[str, Callable[[], Path]] = {
    SHIPPED_NAME: lambda: SHIPPED,
    PAPER_NAME: _converted("suite"),
    ADMITTED_NAME: _converted("admitted"),  # the validation suite (reference/suites.py)
}


def terrain_config_for(terrains: Sequence[Any]) -> TerrainConfig:
    """The CPPN terrain config with these terrains' grid and extent and room for their tallest
    S: the env's heightfield is compiled from it, so any suite or terrain file fits."""
    base = load(["algo=epoet"]).terrain
    return dataclasses.replace(
        base, grid=terrains[0].heightmap.shape[0], size=terrains[0].size
    ).reaching(*(t.max_height for t in terrains))


@dataclass(frozen=True)
class SuiteTerrain:
    """One suite terrain: what the env needs (heightmap, max_height, size) and its label."""

    name: str
    level: str
    roughness: float
    heightmap: np.ndarray
    max_height: float
    size: float
    info: dict[str, Any] = dataclasses.field(default_factory=dict)  # round, lineage, seed, ...

    # What plot_terrain reads of a Terrain, so galleries draw suite terrains the same way.
    @property
    def id(self) -> str:
        return f"{self.name} ({self.level})"

    @property
    def generation(self) -> int:
        return int(self.info.get("generation", 0))

    @property
    def grid(self) -> int:
        return int(self.heightmap.shape[0])


@dataclass(frozen=True)
class Suite:
    folder: Path
    terrains: list[SuiteTerrain]
    course: Course
    name: str  # the key of its evaluations in a run (module docstring)

    def by_name(self, name: str) -> SuiteTerrain:
        for terrain in self.terrains:
            if terrain.name == name:
                return terrain
        raise SuiteError(
            f"suite {self.folder} has no terrain {name!r} (it has "
            f"{self.terrains[0].name} .. {self.terrains[-1].name})."
        )

    @functools.cached_property
    def fingerprint(self) -> str:
        """Identifies the suite's contents, so a store knows which runs were evaluated on it."""
        digest = hashlib.sha1(json.dumps(dataclasses.asdict(self.course)).encode())
        for terrain in self.terrains:
            digest.update(terrain.name.encode())
            digest.update(repr(terrain.max_height).encode())
            digest.update(np.ascontiguousarray(terrain.heightmap).tobytes())
        return digest.hexdigest()[:12]

    def level_counts(self) -> dict[str, int]:
        return {level: sum(t.level == level for t in self.terrains) for level in LEVELS}


# --- loading --------------------------------------------------------------------------------


def example_terrain(level: str = "medium", suite: Suite | None = None) -> str:
    """A terrain of `level` (else the first) of `suite` (None: the shipped one), for hints."""
    entries = (
        [{"name": t.name, "level": t.level} for t in suite.terrains]
        if suite
        else json.loads((SHIPPED / "suite.json").read_text())["terrains"]
    )
    return next((e["name"] for e in entries if e.get("level") == level), entries[0]["name"])


def suite_name(folder: Path) -> str:
    """A named suite's folder: its name; another: its basename in [A-Za-z0-9_.-], "dir-" before a
    named suite's name (`paper/` is no paper suite); `eval_suite/<name>` tells same names apart."""
    named = {SHIPPED.resolve(): SHIPPED_NAME}
    if _is_converted(folder):  # no conversion is made just to name a folder
        named |= {path().resolve(): name for name, path in SUITES.items()}
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", folder.resolve().name).strip(".") or "suite"
    return named.get(folder.resolve()) or (f"dir-{base}" if base in SUITES else base)


def _is_converted(folder: Path) -> bool:
    from epoet.eval.reference.files import cache_root

    return folder.resolve().is_relative_to(cache_root().resolve())


def load_suite(folder: str | Path | None = None) -> Suite:
    """Read and check a suite: a name of `SUITES` (None: shipped; a name wins over a folder of
    that name: pass `./paper`) or a folder; SuiteError names any problem."""
    key = SHIPPED_NAME if folder is None else str(folder)
    if key not in SUITES and not Path(key).exists():  # a typo of a name, or a missing folder
        meant = closest(key, list(SUITES))
        raise SuiteError(
            f"there is no suite {key}: a suite is {', '.join(SUITES)} or a suite folder"
            + (f"; did you mean {meant}?" if meant else f", and no folder {key} exists.")
        )
    folder, key = (SUITES[key](), key) if key in SUITES else (Path(key), suite_name(Path(key)))
    if not (folder / "suite.json").is_file():
        raise SuiteError(f"{folder} is not a suite folder: it has no suite.json.")
    if not (folder / "heights.npz").is_file():
        raise SuiteError(f"suite {folder} has no heights.npz.")
    try:
        index = json.loads((folder / "suite.json").read_text())
        if index.get("format") != SUITE_FORMAT:
            raise ValueError(
                f"format is {index.get('format')!r}, not {SUITE_FORMAT!r} "
                "(regenerate it with python -m epoet.eval.suite out=<folder>)"
            )
        size, grid = float(index["size"]), int(index["grid"])
        course = Course(**index["course"])
        terrains = []
        with np.load(folder / "heights.npz", allow_pickle=False) as heights:
            for entry in index["terrains"]:
                name, height = str(entry["name"]), float(entry["max_height"])
                if name not in heights:
                    raise ValueError(f"heights.npz has no array {name!r}")
                hm = dequantize(heights[name])
                if hm.shape != (grid, grid) or not (hm.min() >= 0.0 and hm.max() <= 1.0):
                    raise ValueError(
                        f"{name} must be a ({grid}, {grid}) array in [0, 1], got shape {hm.shape}"
                    )
                if not height >= 0.0:
                    raise ValueError(f"{name} has max_height {height}")
                hm.setflags(write=False)
                rough = course.roughness(hm, height, size)
                level = entry.get("level") or level_of(rough)
                if level not in LEVELS:
                    raise ValueError(f"{name} has level {level!r}, not one of {list(LEVELS)}")
                info = {
                    k: v
                    for k, v in entry.items()
                    if k not in ("name", "level", "roughness", "max_height")
                }
                terrains.append(SuiteTerrain(name, level, rough, hm, height, size, info))
    except Exception as err:  # json, zip, missing keys, wrong shapes
        raise SuiteError(f"suite {folder} is malformed: {str(err).splitlines()[0]}.") from err
    if not terrains:
        raise SuiteError(f"suite {folder} lists no terrains.")
    if len({t.name for t in terrains}) != len(terrains):
        raise SuiteError(f"suite {folder} lists a terrain name twice.")
    return Suite(folder, terrains, course, key)


# --- command --------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> None:
    """`python -m epoet.eval.suite [key=value ...]`: generate the fixed evaluation suite into
    `out` (by default the shipped epoet/suite/, which these defaults produce bit for bit), or,
    with check=true, regenerate it and compare with `out`, writing nothing.

    Examples:

        python -m epoet.eval.suite check=true
        python -m epoet.eval.suite out=suites/seed7 seed=7
        python -m epoet.eval.suite out=suites/hard 'max_heights=[1.5,2.2]' children=16
    """
    cfg: SuiteConfig = COMMAND.parse(argv)
    try:
        folder = SHIPPED if cfg.out is None else Path(cfg.out)
        stored = len(load_suite(folder).terrains) if cfg.check else 0  # before a minute's work
        print(
            f"generating {len(cfg.max_heights)} rounds x {cfg.children} terrains (seed {cfg.seed})",
            flush=True,
        )
        terrains, entries = generate(cfg, progress=True)
        if cfg.check:
            found = differences(folder, terrains, entries)
            if stored != len(entries):
                found.append(f"{stored} terrains stored, {len(entries)} generated")
            if found:
                raise SuiteError(
                    f"suite {folder} differs from the regenerated one: {'; '.join(found[:5])}."
                )
            print(f"suite {folder} matches the regenerated suite bit for bit")
            return
        write_suite(folder, terrains, entries, Course.of(cfg.agent, cfg.episode_ratio))
        counts = load_suite(folder).level_counts()
        print(
            f"wrote {len(terrains)} terrains to {folder}/: "
            + ", ".join(f"{n} {level}" for level, n in counts.items())
        )
    except (ConfigError, MutationError, SuiteError, OSError) as err:
        fail(err)


COMMAND = KeyValueCommand("suite", main.__doc__, SuiteConfig)


if __name__ == "__main__":
    main()
