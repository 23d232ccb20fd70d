"""workers=1: one engine in this process; no start-up cost, nothing to pickle."""

from __future__ import annotations

from collections.abc import Sequence

from epoet.envs.config import AgentConfig
from epoet.rollout.backends.base import Backend, engine_jobs, split_results
from epoet.rollout.engine import Episodes, RolloutEngine
from epoet.rollout.populations import Request
from epoet.terrain.config import TerrainConfig


class SerialEvaluator(Backend):
    """workers=1: one engine in this process; no start-up cost, nothing to pickle."""

    workers = 1

    def __init__(
        self, agent: AgentConfig, terrain_cfg: TerrainConfig, batch: int, layer_sizes: Sequence[int]
    ) -> None:
        super().__init__(agent, layer_sizes)
        self.engine = RolloutEngine(agent, terrain_cfg, batch, layer_sizes)

    def _run(self, requests: Sequence[Request]) -> list[Episodes]:
        self.engine.set_terrains([r.terrain for r in requests])
        items = [(k, e) for k, r in enumerate(requests) for e in range(len(r.population))]
        jobs = engine_jobs(
            iter(items), [r.population for r in requests], [r.record for r in requests]
        )
        part = self.engine.run_jobs(jobs)
        return split_results([part], [len(r.population) for r in requests])
