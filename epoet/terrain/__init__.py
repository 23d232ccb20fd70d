"""Heightfield terrains: random bowls, CPPN-NEAT shapes, their mix, mutation, save/load, pictures.

The terrain knows nothing about the robot: it produces (grid, grid) heights in [0, 1] plus the
relief S in metres; the env writes them into MuJoCo's hfield.
"""

from epoet.terrain.bowl import random_bowl
from epoet.terrain.cppn import (
    CppnMutationError,
    check_inputs,
    evaluate,
    field_inputs,
    genome_config,
    mutate_genome,
    new_genome,
)
from epoet.terrain.generate import cppn_inputs, make_terrain, max_height_at, mix, mutate_terrain
from epoet.terrain.terrain import Terrain, TerrainFileError, normalize, plot_terrain

__all__ = [
    "CppnMutationError",
    "Terrain",
    "TerrainFileError",
    "check_inputs",
    "cppn_inputs",
    "evaluate",
    "field_inputs",
    "genome_config",
    "make_terrain",
    "max_height_at",
    "mix",
    "mutate_genome",
    "mutate_terrain",
    "new_genome",
    "normalize",
    "plot_terrain",
    "random_bowl",
]
