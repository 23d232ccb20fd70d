"""ePOET's settings (conf/algo/epoet.yaml)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from epoet.core.algorithm import Algorithm, AlgoSettings, Family, Runner
from epoet.core.schema import check, positive
from epoet.es.config import EsConfig
from epoet.terrain.config import evolving_kinds, generator_for


@dataclass
class EpoetConfig(AlgoSettings):
    """ePOET (paper Table 4); score thresholds are for 2000-step episodes (see BudgetConfig).
    Its compute (iterations, ES pairs) is the budget's (`OpenEndedBudgetConfig`)."""

    es: EsConfig
    iterations_before_transfer: int  # the transfer interval
    adjust_interval: int  # reproduction every adjust_interval transfer intervals
    later_adjust_interval: int  # after the first reproduction, every this many
    transfer_bar_window: int  # a transfer must beat the best of this many evaluations
    proposal_step: str  # sgd | adam: the fine-tuning step of transfer and admission
    max_num_envs: int
    num_children: int
    max_admitted: int
    mc_lower: float
    mc_upper: float
    repro_threshold: float
    novelty_k: int

    def __post_init__(self) -> None:
        positive(
            self,
            "iterations_before_transfer",
            "adjust_interval",
            "later_adjust_interval",
            "max_num_envs",
            "num_children",
            "max_admitted",
            "novelty_k",
            "transfer_bar_window",
        )
        check(
            self.proposal_step in ("sgd", "adam"),
            f"algo.proposal_step must be 'sgd' or 'adam', got {self.proposal_step!r}.",
        )
        check(
            self.mc_lower < self.mc_upper,
            f"algo.mc_lower ({self.mc_lower}) must be below algo.mc_upper ({self.mc_upper}).",
        )

    def check_run(self, cfg: Any) -> None:
        """What ePOET needs of the run's other settings (`cfg`: the root Config)."""
        kind = cfg.terrain.kind
        check(
            generator_for(kind).evolves,
            f"algo={self.name} evolves its environments, so it needs "
            f"{' or '.join(f'terrain={k}' for k in evolving_kinds())} "
            f"(got terrain={kind}, whose terrains do not mutate).",
        )


def _runner() -> Runner:
    from epoet.open_ended.runner import train  # imported when a run starts, not at composition

    return train


EPOET = Algorithm(
    name="epoet",
    family=Family.OPEN_ENDED,
    schema=EpoetConfig,
    runner=_runner,
    label="ePOET",
    colour="tab:red",
    beats="sac",
)
