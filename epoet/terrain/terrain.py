"""The terrain value: a normalised height map, its physical relief, and where it came from.

Orientation: `heightmap[row, col]` is the height at y index `row` and x index `col`; row 0 is at
-y and column 0 at -x, matching MuJoCo's row-major hfield data, so `model.hfield_data[:] =
heightmap.ravel()` places it correctly. The terrain spans `size` metres per side, centred at
the origin; the robot walks towards +x (increasing column).

Heights are in [0, 1] and `max_height` (S) is the physical relief in metres: the env sets the
hfield elevation so that 1.0 maps to S. S is never applied twice (reference defect 2: the
reference scaled data already in [0, S] by S again, giving S^2).
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from epoet.core.errors import first_line
from epoet.core.files import atomic_write
from epoet.terrain.config import generator_for

_FORMAT = 1  # bump when the npz layout changes


class TerrainFileError(ValueError):
    """A terrain file that is missing or cannot be read; the message names the path."""


def normalize(a: np.ndarray) -> np.ndarray:
    """Rescale to [0, 1]; a constant (or numerically constant) map becomes all zeros: flat ground.

    The relative threshold keeps a nearly flat CPPN from blowing float rounding up into relief.
    """
    lo, hi = float(np.min(a)), float(np.max(a))
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError("cannot normalise a height map with non-finite values.")
    span = hi - lo
    if span <= 1e-12 * max(1.0, abs(lo), abs(hi)):
        return np.zeros(np.shape(a))
    return np.clip((a - lo) / span, 0.0, 1.0)


class TerrainLike(Protocol):
    """What the env and the rollout engine read of a terrain (a `Terrain`, a suite terrain, the
    plain arrays shipped to workers); read-only, so frozen dataclasses and named tuples qualify."""

    @property
    def heightmap(self) -> np.ndarray: ...

    @property
    def max_height(self) -> float: ...

    @property
    def size(self) -> float: ...


@dataclass(frozen=True, eq=False)
class Terrain:
    """One generated terrain. `id` is derived from the provenance, so equal inputs, equal ids."""

    heightmap: np.ndarray  # (grid, grid) float64 in [0, 1], read-only
    max_height: float  # S: metres of relief that height 1.0 stands for
    size: float  # metres per side the terrain was made for
    kind: str  # the generator that made it (terrain.kind)
    seed: int  # seed of this terrain's random parts (bowl; CPPN mutation)
    generation: int = 0  # mutations since the root
    parent_id: str | None = None
    genome: Any = None  # the generator's encoding (a CPPN's neat genome; none for the bowl)
    id: str = field(init=False)

    def __post_init__(self) -> None:
        hm = np.array(self.heightmap, dtype=np.float64)
        if hm.ndim != 2 or hm.shape[0] != hm.shape[1] or hm.shape[0] < 2:
            raise ValueError(
                f"Terrain.heightmap must be a square (n, n) array with n >= 2, "
                f"got shape {hm.shape}."
            )
        if not np.all(np.isfinite(hm)) or hm.min() < 0.0 or hm.max() > 1.0:
            raise ValueError("Terrain.heightmap values must be finite and within [0, 1].")
        hm.setflags(write=False)
        object.__setattr__(self, "heightmap", hm)
        if not (np.isfinite(self.max_height) and self.max_height >= 0):
            raise ValueError(f"Terrain.max_height must be >= 0 metres, got {self.max_height}.")
        if not (np.isfinite(self.size) and self.size > 0):
            raise ValueError(f"Terrain.size must be > 0 metres, got {self.size}.")
        generator = generator_for(self.kind, "Terrain.kind")
        for name in ("seed", "generation"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"Terrain.{name} must be an integer >= 0, got {value!r}.")
        generator.check(self.genome)
        object.__setattr__(self, "max_height", float(self.max_height))
        object.__setattr__(self, "size", float(self.size))
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "generation", int(self.generation))
        object.__setattr__(self, "id", self._make_id())

    @property
    def grid(self) -> int:
        return int(self.heightmap.shape[0])

    def _make_id(self) -> str:
        genes = generator_for(self.kind).describe(self.genome)
        prov = [
            self.kind,
            self.seed,
            self.generation,
            self.parent_id,
            repr(self.max_height),
            repr(self.size),
            self.grid,
            genes,
        ]
        digest = hashlib.sha1(json.dumps(prov).encode()).hexdigest()[:8]
        return f"{self.kind}-g{self.generation}-s{self.seed}-{digest}"

    def _meta(self) -> dict[str, Any]:
        return {
            "format": _FORMAT,
            "id": self.id,
            "kind": self.kind,
            "seed": self.seed,
            "generation": self.generation,
            "parent_id": self.parent_id,
            "max_height": self.max_height,
            "size": self.size,
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write an npz atomically (`atomic_write`): a crash never leaves half a file.

        The genome is stored pickled (a CPPN's neat genome is a plain Python object, and
        evaluating it needs no neat config: cppn.evaluate), so it is stored alone.
        """
        path = Path(path)
        genome = (
            np.frombuffer(pickle.dumps(self.genome), dtype=np.uint8)
            if self.genome is not None
            else np.zeros(0, dtype=np.uint8)
        )
        with atomic_write(path) as f:
            np.savez(
                f, heightmap=self.heightmap, meta=np.array(json.dumps(self._meta())), genome=genome
            )
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> Terrain:
        """Read a file written by `save`, exactly (same array, same genome, same id).

        Only load files you trust: the genome is unpickled.
        """
        path = Path(path)
        if not path.is_file():
            raise TerrainFileError(f"terrain file {path} does not exist.")
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"][()]))
                heightmap = data["heightmap"]
                raw = data["genome"].tobytes()
            if meta.get("format") != _FORMAT:
                raise ValueError(f"format {meta.get('format')!r} is not {_FORMAT}")
            stored_id = meta["id"]
            terrain = cls(
                heightmap=heightmap,
                max_height=meta["max_height"],
                size=meta["size"],
                kind=meta["kind"],
                seed=meta["seed"],
                generation=meta["generation"],
                parent_id=meta["parent_id"],
                genome=pickle.loads(raw) if raw else None,
            )
        except Exception as err:  # a damaged file can fail in zip, json, pickle or our checks
            raise TerrainFileError(
                f"terrain file {path} is corrupt or not a terrain file "
                f"({first_line(err).rstrip('.')})."
            ) from err
        if terrain.id != stored_id:
            raise TerrainFileError(
                f"terrain file {path} is corrupt: its contents do not match "
                f"its stored id {stored_id}."
            )
        return terrain

    def to_png(self, path: str | os.PathLike) -> Path:
        """Render a shaded 3D view of the terrain to a PNG (matplotlib, no display needed)."""
        from matplotlib.figure import Figure  # on demand: a second of imports runs seldom need

        fig = Figure(figsize=(6, 5), dpi=110)
        plot_terrain(fig.add_subplot(projection="3d"), self)
        fig.savefig(path)
        return Path(path)


def plot_terrain(
    ax: Any, terrain: Terrain, zmax: float | None = None, max_facets: int = 100
) -> None:
    """Draw the terrain as a hill-shaded 3D surface on a matplotlib 3D axis.

    The z axis is in metres, from 0 to `zmax` (default: the terrain's own S), so panels sharing
    a zmax show relief growing with S. The box keeps a fixed 1:1:0.3 aspect (a vertical
    exaggeration of 0.3 * size / zmax); the z ticks give the true scale.
    """
    n = terrain.grid
    axis = np.linspace(-terrain.size / 2, terrain.size / 2, n)
    x, y = np.meshgrid(axis, axis, indexing="xy")  # rows follow y, columns x: as the heightmap
    z = terrain.heightmap * terrain.max_height
    from matplotlib import colormaps
    from matplotlib.colors import LightSource

    light = LightSource(azdeg=315, altdeg=40)
    # Shade on the normalised map so even low terrains show their shape; exaggerate for relief.
    rgb = light.shade(
        terrain.heightmap, cmap=colormaps["gist_earth"], vert_exag=n / 8, blend_mode="soft"
    )
    count = min(n, max_facets)
    ax.plot_surface(
        x,
        y,
        z,
        facecolors=rgb,
        rcount=count,
        ccount=count,
        linewidth=0,
        antialiased=False,
        shade=False,
    )
    top = max(zmax if zmax is not None else terrain.max_height, 1e-3)
    ax.set_zlim(0.0, top)
    ax.set_zticks([0.0, top], ["0", f"{top:.2f} m"])
    ax.set_box_aspect((1.0, 1.0, 0.3), zoom=1.2)
    ax.view_init(elev=38, azim=-65)
    ax.set_xlabel("x (m)", labelpad=-8, fontsize=7)
    ax.set_ylabel("y (m)", labelpad=-8, fontsize=7)
    ax.tick_params(labelsize=6, pad=-2)
    ax.set_title(
        f"{terrain.id}\ngeneration {terrain.generation}, S = {terrain.max_height:.2f} m", fontsize=8
    )
