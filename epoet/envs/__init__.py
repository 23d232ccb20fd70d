"""The hexapod terrain task, registered with gymnasium as `epoet/Hexapod-v0`
(`epoet.envs.hexapod_env.make_hexapod`, imported when gymnasium makes one: importing this
package, for its schemas say, stays light)."""

import gymnasium as gym

ENV_ID = "epoet/Hexapod-v0"

if ENV_ID not in gym.registry:
    # Episode length is enforced by the task itself (truncated at agent.max_episode_steps), so
    # no TimeLimit wrapper is stacked on top.
    gym.register(id=ENV_ID, entry_point="epoet.envs.hexapod_env:make_hexapod")
