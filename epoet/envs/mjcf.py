"""A robot's MJCF made into the task's model: checked against the robot's config, its floor
replaced by the terrain, and the sensors the task reads added.

A robot's MJCF brings the robot only (and whatever floor it stood on elsewhere); what the task
needs of the world is added here, the same for every robot:
- the terrain: the heightfield `terrain` sized by the terrain config, its geom in the robot's
  default geom class (as the floor it replaces, whose plane geoms are removed), and a checker
  material that rendering repaints by height (epoet.eval.film);
- a contact sensor per foot (`agent.feet`: 1 while the geom touches the terrain) and an
  actuator-force sensor per joint (`agent.joints`' order), the foot flags of the observation and
  the forces the reward penalises. Contact sensors are position-stage sensors, so
  `epoet.envs.model.stepper` refreshes them for the state after a step at little cost.

The robot must have a free root joint, the config's joints after it in the MJCF's order, and
one actuator with a ctrlrange per joint (the action in [-1, 1] spans it); anything else is one
ConfigError sentence naming the robot's key.
"""

from __future__ import annotations

import mujoco

from epoet.core.schema import ConfigError, check
from epoet.envs.config import AgentConfig, mjcf_file
from epoet.terrain.config import TerrainConfig

TERRAIN = "terrain"  # the heightfield's, its geom's name
# The contact sensor's data field `found` (bit 0 of mjtConDataField), one contact considered.
_FOUND, _REDUCE_NONE, _NUM = 1, 0, 1
_FREE = mujoco.mjtJoint.mjJNT_FREE


def robot_spec(agent: AgentConfig) -> mujoco.MjSpec:
    """The robot's MJCF as a spec, checked against `agent` (ConfigError otherwise)."""
    path = mjcf_file(agent.mjcf)
    if path is None:  # the schema checked it; the file may have gone since
        raise ConfigError(f"agent.mjcf names no file: {agent.mjcf!r}.")
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as err:
        raise ConfigError(f"agent.mjcf {path} is not a MuJoCo model: {err}.") from None
    joints = list(spec.joints)
    check(
        bool(joints) and joints[0].type == _FREE and joints[0].parent.parent.name == "world",
        f"agent.mjcf {path.name}: the robot's root body needs a free joint, its first joint.",
    )
    found = [joint.name for joint in joints[1:]]
    check(
        found == list(agent.joints) and all(joint.type != _FREE for joint in joints[1:]),
        f"agent.joints must be the MJCF's joints after the root, in its order: {found}.",
    )
    for foot in agent.feet:
        check(spec.geom(foot) is not None, f"agent.feet: {path.name} has no geom {foot!r}.")
    targets = [a.target for a in spec.actuators]
    for actuator in spec.actuators:
        low, high = actuator.ctrlrange
        check(
            actuator.trntype == mujoco.mjtTrn.mjTRN_JOINT and low < high,
            f"agent.mjcf {path.name}: every actuator must drive a joint within a ctrlrange "
            f"(the action's [-1, 1] spans it), but the one on {actuator.target!r} does not.",
        )
    check(
        sorted(targets) == sorted(agent.joints),
        f"agent.mjcf {path.name} must drive each of agent.joints with one actuator; its "
        f"actuators drive {targets}.",
    )
    # The task writes the action into ctrl and reads forces by the joint each actuator drives.
    if not 1 <= len(targets) <= 128:
        raise ConfigError(f"agent.joints: the reward supports 1 to 128 joints, got {len(targets)}.")
    return spec


def add_terrain(spec: mujoco.MjSpec, terrain: TerrainConfig) -> None:
    """The terrain's heightfield in place of the robot's floor. Its elevation is fixed at
    `max_height_limit`: each terrain's data are scaled by S / limit, so the physical relief is
    exactly S (the reference scaled by S twice: defect 2)."""
    for geom in list(spec.worldbody.geoms):
        if geom.type == mujoco.mjtGeom.mjGEOM_PLANE:
            spec.delete(geom)
    spec.add_texture(
        name="grid",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.35, 0.45, 0.35],
        rgb2=[0.3, 0.4, 0.3],
        width=300,
        height=300,
    )
    material = spec.add_material(name="ground", texrepeat=[40, 40], texuniform=False)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    half = terrain.size / 2
    spec.add_hfield(
        name=TERRAIN,
        nrow=terrain.grid,
        ncol=terrain.grid,
        size=[half, half, terrain.max_height_limit, terrain.base],
        userdata=[0.0] * (terrain.grid * terrain.grid),
    )
    geom = spec.worldbody.add_geom(
        name=TERRAIN,
        type=mujoco.mjtGeom.mjGEOM_HFIELD,
        material="ground",
        conaffinity=1,  # robot geoms (conaffinity 0) collide with it, never with each other
        rgba=[1, 1, 1, 1],
    )
    geom.hfieldname = TERRAIN


def add_sensors(spec: mujoco.MjSpec, agent: AgentConfig) -> None:
    """The foot contacts, then the actuator forces in the joints' order (unnamed actuators are
    named after their joint)."""
    for foot in agent.feet:
        spec.add_sensor(
            name=f"{foot}_contact",
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_GEOM,
            objname=foot,
            reftype=mujoco.mjtObj.mjOBJ_GEOM,
            refname=TERRAIN,
            intprm=[_FOUND, _REDUCE_NONE, _NUM],
        )
    by_joint = {actuator.target: actuator for actuator in spec.actuators}
    for joint in agent.joints:
        actuator = by_joint[joint]
        actuator.name = actuator.name or joint
        spec.add_sensor(
            name=f"{actuator.name}_force",
            type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
            objtype=mujoco.mjtObj.mjOBJ_ACTUATOR,
            objname=actuator.name,
        )
