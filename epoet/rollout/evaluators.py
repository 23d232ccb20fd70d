"""The evaluator a run asks for: in-process, a local process pool, or a Ray cluster."""

from __future__ import annotations

from collections.abc import Sequence

from epoet.core.cores import default_workers
from epoet.envs.config import AgentConfig
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.backends.pool import PoolEvaluator
from epoet.rollout.backends.serial import SerialEvaluator
from epoet.rollout.config import WorkersConfig
from epoet.terrain.config import TerrainConfig


def make_evaluator(
    agent: AgentConfig,
    terrain_cfg: TerrainConfig,
    workers: int | str,
    batch: int,
    layer_sizes: Sequence[int],
) -> Evaluator:
    """workers: 'local' (a pool with one process per core) or a count; 1 runs in-process."""
    if workers == "local":
        workers = default_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be 'local' or an integer >= 1, got {workers!r}.")
    if workers == 1:
        return SerialEvaluator(agent, terrain_cfg, batch, layer_sizes)
    return PoolEvaluator(agent, terrain_cfg, workers, batch, layer_sizes)


def evaluator_for(
    workers: WorkersConfig,
    agent: AgentConfig,
    terrain_cfg: TerrainConfig,
    layer_sizes: Sequence[int],
) -> Evaluator:
    """The evaluator a run's `workers` config asks for."""
    if workers.backend == "ray":
        # the optional extra, imported on demand
        from epoet.rollout.backends.ray_host import RayEvaluator

        return RayEvaluator(
            agent, terrain_cfg, workers.num, workers.batch, layer_sizes, workers.address
        )
    return make_evaluator(agent, terrain_cfg, workers.num or "local", workers.batch, layer_sizes)
