"""Heightfield terrains: the kinds `terrain.kind` names (the bowl, CPPN-NEAT), each a generator
that encodes, mutates and renders environments (config.py `TerrainGenerator`), the height
schedule, save/load, pictures.

The terrain knows nothing about the robot: it produces (grid, grid) heights in [0, 1] plus the
relief S in metres; the env writes them into MuJoCo's hfield. Importing the package registers
the built-in kinds (bowl.py, cppn.py).
"""

from epoet.terrain.bowl import random_bowl
from epoet.terrain.config import MutationError, TerrainGenerator, generator_for, register
from epoet.terrain.cppn import (
    CppnMutationError,
    check_inputs,
    cppn_inputs,
    evaluate,
    field_inputs,
    genome_config,
    mix,
    mutate_genome,
    new_genome,
)
from epoet.terrain.generate import make_terrain, max_height_at, mutate_terrain
from epoet.terrain.terrain import Terrain, TerrainFileError, normalize, plot_terrain

__all__ = [
    "CppnMutationError",
    "MutationError",
    "Terrain",
    "TerrainFileError",
    "TerrainGenerator",
    "check_inputs",
    "cppn_inputs",
    "evaluate",
    "field_inputs",
    "generator_for",
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
    "register",
]
