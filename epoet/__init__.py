"""epoet: open-ended locomotion learning.

Importing the package registers its gymnasium ids by name only: the env's module
(epoet.env_factory: MuJoCo, Hydra's composition) is imported when `gym.make` first makes one,
so `import epoet` stays light, and gymnasium's `gym.make("epoet:epoet/Hexapod-v0")` form, which
imports `epoet` before it looks the id up, finds them too.
"""

from importlib.metadata import version

import gymnasium as gym

# The version lives in pyproject.toml only; the installed package's metadata carries it here.
__version__ = version("epoet")

ENV_IDS = {"hexapod": "epoet/Hexapod-v0", "ant": "epoet/Ant-v0"}  # conf/agent/<robot>.yaml

for _robot, _id in ENV_IDS.items():
    if _id not in gym.registry:
        # Episode length is enforced by the task itself (truncated at agent.max_episode_steps),
        # so no TimeLimit wrapper is stacked on top.
        gym.register(
            id=_id, entry_point="epoet.env_factory:make_terrain_env", kwargs={"robot": _robot}
        )
