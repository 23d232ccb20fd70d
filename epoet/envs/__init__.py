"""A robot's terrain task: the MuJoCo model, the task's kernels and the gymnasium env, on
validated configs (the env from the YAML defaults, and gymnasium's ids: epoet.env_factory)."""
