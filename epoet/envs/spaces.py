"""The task's observation and action sizes (epoet.envs.task builds the vectors), in a module
that imports nothing: agent files are checked against them before rendering lets MuJoCo pick
its OpenGL backend (epoet.eval.render.open_gl)."""

OBS_DIM = 53
ACT_DIM = 18
