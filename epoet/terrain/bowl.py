"""The random bowl: dm_control's quadruped-escape terrain with a variable level (docs/reference.md).

Regenerated from a new seed every iteration, it keeps the agent on changing ground even while
the CPPN part of its environment stays the same (paper, Appendix "Generated Environments").
Alone it is the kind `terrain=bowl` (the baselines' terrain): drawn from its seed, no genome,
nothing to evolve.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from epoet.terrain.config import TerrainConfig, register
from epoet.terrain.terrain import normalize


def random_bowl(
    rng: np.random.Generator,
    grid: int,
    max_height: float,
    bump_grid: int = 20,
    bump_low: float = 0.15,
    bump_high: float = 1.0,
) -> np.ndarray:
    """A (grid, grid) bowl with smooth random bumps, normalised to [0, 1].

    bowl = level - cos(2 pi radius) / 2 on r, c in [-1, 1] with radius clipped to [0.04, 1] and
    level ~ U(0.5, S + 0.5), S = `max_height` (metres, the current schedule value): a higher S
    lifts the level, so the multiplicative bumps weigh more against the ring shape. The bumps are
    a bump_grid x bump_grid field of U(bump_low, bump_high), upsampled by cubic splines.
    """
    if grid < 2 or bump_grid < 1:
        raise ValueError(
            f"random_bowl needs grid >= 2 and bump_grid >= 1, got {grid} and {bump_grid}."
        )
    if not 0.0 < bump_low <= bump_high:
        raise ValueError(
            f"random_bowl needs 0 < bump_low <= bump_high, got {bump_low} and {bump_high}."
        )
    axis = np.linspace(-1.0, 1.0, grid)
    r, c = np.meshgrid(axis, axis, indexing="ij")
    radius = np.clip(np.sqrt(r**2 + c**2), 0.04, 1.0)
    level = rng.uniform(0.5, max_height + 0.5)
    bowl = level - np.cos(2.0 * np.pi * radius) / 2.0
    bumps = rng.uniform(bump_low, bump_high, size=(bump_grid, bump_grid))
    # scipy.ndimage is imported on first use, not with the module: composing a config imports
    # this module (TerrainConfig checks `terrain.kind` by its generator), and composing never
    # renders (docs/architecture.md).
    from scipy import ndimage

    # Corner-aligned cubic upsampling (what ndimage.zoom does), with the output shape exact.
    at = np.linspace(0.0, bump_grid - 1.0, grid)
    rows, cols = np.meshgrid(at, at, indexing="ij")
    smooth = ndimage.map_coordinates(bumps, [rows, cols], order=3, mode="nearest")
    return normalize(bowl * smooth)


def bowl_of(cfg: TerrainConfig, seed: int, max_height: float) -> np.ndarray:
    """The terrain's bowl at relief S = `max_height`, drawn from `seed`."""
    return random_bowl(
        np.random.default_rng(seed),
        cfg.grid,
        max_height,
        cfg.bump_grid,
        cfg.bump_low,
        cfg.bump_high,
    )


class BowlGenerator:
    """`terrain.kind=bowl`: a fresh bowl from each seed, and no genome."""

    kind = "bowl"
    evolves = False
    unused_keys: tuple[str, ...] = (
        "terrain.cppn",
        "terrain.mutation",
        "terrain.cppn_scale",
        "terrain.cppn_origin",
        "terrain.rendering",
    )

    def encode(self, cfg: TerrainConfig, seed: int) -> None:
        return None

    def mutate(self, cfg: TerrainConfig, parent: Any, seed: int) -> Any:
        raise ValueError("bowl terrains do not mutate: a bowl is drawn from its seed alone.")

    def render(self, cfg: TerrainConfig, genome: Any, seed: int, max_height: float) -> np.ndarray:
        return bowl_of(cfg, seed, max_height)

    def describe(self, genome: Any) -> str:
        return ""

    def check(self, genome: Any) -> None:
        if genome is not None:
            raise ValueError("a 'bowl' terrain takes no genome (a CPPN's is terrain.kind='cppn').")


register(BowlGenerator())
