"""Terrains from the config: the height schedule, bowl + CPPN mixing, roots and mutated children.

The ePOET loop keeps each environment's CPPN genome and calls `make_terrain` with a new seed
every iteration: the bowl part is regenerated and S follows the schedule (paper Appendix A.2);
`mutate_terrain` makes a child environment when reproduction runs.
"""

from __future__ import annotations

import neat
import numpy as np

from epoet.terrain.bowl import random_bowl
from epoet.terrain.config import TerrainConfig
from epoet.terrain.cppn import evaluate, field_inputs, mutate_genome, new_genome
from epoet.terrain.terrain import KINDS, Terrain, normalize


def max_height_at(cfg: TerrainConfig, iteration: int) -> float:
    """S_t = min(max_height + t * max_height_step, max_height_limit): +0.01 m per iteration.

    (The paper's rate; the reference code grew 0.001 per reset, with the same 2.2 cap.)
    """
    if iteration < 0:
        raise ValueError(f"iteration must be >= 0, got {iteration}.")
    return min(cfg.max_height + iteration * cfg.max_height_step, cfg.max_height_limit)


def cppn_inputs(cfg: TerrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """The CPPN's (x, y) inputs at the terrain's samples (the reference's metres per unit)."""
    return field_inputs(cfg.grid, cfg.size, cfg.cppn_origin, cfg.cppn_scale)


def mix(bowl: np.ndarray, cppn: np.ndarray, bowl_weight: float) -> np.ndarray:
    """normalize(w * normalize(bowl) + (1 - w) * normalize(cppn)), in [0, 1] (paper: w = 0.3)."""
    if not 0.0 <= bowl_weight <= 1.0:
        raise ValueError(f"bowl_weight must be in [0, 1], got {bowl_weight}.")
    return normalize(bowl_weight * normalize(bowl) + (1.0 - bowl_weight) * normalize(cppn))


def _check_seed(seed: int) -> None:
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"terrain seed must be an integer >= 0, got {seed!r}.")


def make_terrain(
    cfg: TerrainConfig,
    seed: int,
    iteration: int = 0,
    genome: neat.DefaultGenome | None = None,
    *,
    generation: int = 0,
    parent_id: str | None = None,
) -> Terrain:
    """The terrain for `iteration` (S from the schedule), its bowl part drawn from `seed`.

    kind 'bowl': the bowl alone (no genome). kind 'cppn': the bowl mixed with the CPPN `genome`;
    without one, a root genome is made from `seed` (a new environment lineage). `generation`
    and `parent_id` carry the genome's lineage into the terrain's provenance.
    """
    _check_seed(seed)
    if cfg.kind not in KINDS:
        raise ValueError(f"terrain.kind must be 'bowl' or 'cppn', got {cfg.kind!r}.")
    if cfg.kind == "bowl" and genome is not None:
        raise ValueError("a 'bowl' terrain takes no CPPN genome; use terrain.kind='cppn'.")
    height = max_height_at(cfg, iteration)
    bowl = random_bowl(
        np.random.default_rng(seed), cfg.grid, height, cfg.bump_grid, cfg.bump_low, cfg.bump_high
    )
    if cfg.kind == "bowl":
        return Terrain(bowl, height, cfg.size, "bowl", seed, generation, parent_id)
    if genome is None:
        genome = new_genome(cfg.cppn, seed)
    cppn = evaluate(genome, *cppn_inputs(cfg))
    if not np.all(np.isfinite(cppn)):
        raise ValueError(
            f"the CPPN genome gives non-finite heights on the {cfg.grid} x {cfg.grid} grid."
        )
    return Terrain(
        mix(bowl, cppn, cfg.bowl_weight),
        height,
        cfg.size,
        "cppn",
        seed,
        generation,
        parent_id,
        genome,
    )


def mutate_terrain(parent: Terrain, cfg: TerrainConfig, seed: int, iteration: int = 0) -> Terrain:
    """A child environment: a valid mutation of the parent's CPPN, with a fresh bowl from `seed`.

    Raises CppnMutationError when no valid child turns up within `mutation.max_tries`.
    """
    _check_seed(seed)
    if parent.kind != "cppn" or cfg.kind != "cppn":
        raise ValueError(
            f"only CPPN terrains mutate; got a {parent.kind!r} parent and "
            f"terrain.kind={cfg.kind!r}."
        )
    child = mutate_genome(parent.genome, cfg.cppn, cfg.mutation, seed, cppn_inputs(cfg))
    return make_terrain(
        cfg, seed, iteration, child, generation=parent.generation + 1, parent_id=parent.id
    )
