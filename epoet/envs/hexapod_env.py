"""The hexapod's terrain env under the names its tests, benches and notebooks use."""

from epoet.envs.terrain_env import TerrainEnv, make_terrain_env

HexapodEnv = TerrainEnv
make_hexapod = make_terrain_env  # the robot defaults to the hexapod
