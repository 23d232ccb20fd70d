"""Terrains from the config: the height schedule, and the terrain of an encoding at an iteration
or of a mutated child, whatever generator `terrain.kind` names (config.py `generator_for`).

The ePOET loop keeps each environment's encoding and calls `make_terrain` with a new seed every
iteration: the random parts (the bowl) are regenerated and S follows the schedule (paper
Appendix A.2); `mutate_terrain` makes a child environment, as reproduction does.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from epoet.terrain.config import TerrainConfig, evolving_kinds, generator_for
from epoet.terrain.terrain import Terrain


def max_height_at(cfg: TerrainConfig, iteration: int) -> float:
    """S_t = min(max_height + t * max_height_step, max_height_limit): +0.01 m per iteration.

    (The paper's rate; the reference code grew 0.001 per reset, with the same 2.2 cap.)
    """
    if iteration < 0:
        raise ValueError(f"iteration must be >= 0, got {iteration}.")
    return min(cfg.max_height + iteration * cfg.max_height_step, cfg.max_height_limit)


def _check_seed(seed: int) -> None:
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"terrain seed must be an integer >= 0, got {seed!r}.")


def make_terrain(
    cfg: TerrainConfig,
    seed: int,
    iteration: int = 0,
    genome: Any = None,
    *,
    generation: int = 0,
    parent_id: str | None = None,
) -> Terrain:
    """The terrain of `genome` for `iteration` (S from the schedule), its random parts (the
    bowl) drawn from `seed`; without a genome, the root of a new lineage made from `seed` (the
    bowl has none). `generation` and `parent_id` carry the lineage into the terrain's
    provenance.
    """
    _check_seed(seed)
    generator = generator_for(cfg.kind)
    if genome is None:
        genome = generator.encode(cfg, seed)
    generator.check(genome)
    height = max_height_at(cfg, iteration)
    heightmap = generator.render(cfg, genome, seed, height)
    return Terrain(heightmap, height, cfg.size, cfg.kind, seed, generation, parent_id, genome)


def mutate_terrain(parent: Terrain, cfg: TerrainConfig, seed: int, iteration: int = 0) -> Terrain:
    """A child environment: a valid mutation of the parent's encoding, its random parts drawn
    from `seed`. MutationError when the generator finds no valid child."""
    _check_seed(seed)
    generator = generator_for(cfg.kind)
    if parent.kind != cfg.kind or not generator.evolves:
        raise ValueError(
            f"a {parent.kind!r} terrain has no child of terrain.kind={cfg.kind!r}: only "
            f"{' and '.join(map(repr, evolving_kinds()))} terrains mutate."
        )
    child = generator.mutate(cfg, parent.genome, seed)
    return make_terrain(
        cfg, seed, iteration, child, generation=parent.generation + 1, parent_id=parent.id
    )
