"""The robots' terrain task, registered with gymnasium as `epoet/Hexapod-v0` and `epoet/Ant-v0`
(`epoet.envs.terrain_env.make_terrain_env`, imported when gymnasium makes one: importing this
package, for its schemas say, stays light)."""

import gymnasium as gym

ENV_ID = "epoet/Hexapod-v0"
ROBOT_ENV_IDS = {"hexapod": ENV_ID, "ant": "epoet/Ant-v0"}  # conf/agent/<robot>.yaml

for _robot, _id in ROBOT_ENV_IDS.items():
    if _id not in gym.registry:
        # Episode length is enforced by the task itself (truncated at agent.max_episode_steps),
        # so no TimeLimit wrapper is stacked on top.
        gym.register(
            id=_id, entry_point="epoet.envs.terrain_env:make_terrain_env", kwargs={"robot": _robot}
        )
