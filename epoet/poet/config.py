"""ePOET's settings (conf/algo/epoet.yaml)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from epoet.core.schema import check, positive
from epoet.es.config import EsConfig


@dataclass
class PoetConfig:
    """ePOET (paper Table 4); score thresholds are for 2000-step episodes (see BudgetConfig)."""

    KEY: ClassVar[str] = "algo"

    _target_: str                    # the runner epoet.run calls (conf/algo/*.yaml names it)
    name: str
    es: EsConfig
    iterations_before_transfer: int
    adjust_interval: int             # reproduction every adjust_interval transfer intervals
    later_reproduce_interval: Optional[int]  # after the first reproduction (null: the same)
    transfer_bar_window: int         # a transfer must beat the best of this many evaluations
    proposal_step: str               # sgd | adam: the fine-tuning step of transfer and admission
    max_num_envs: int
    num_children: int
    max_admitted: int
    mc_lower: float
    mc_upper: float
    repro_threshold: float
    novelty_k: int

    def __post_init__(self) -> None:
        positive(self, "iterations_before_transfer", "adjust_interval", "max_num_envs",
                 "num_children", "max_admitted", "novelty_k", "transfer_bar_window")
        check(self.later_reproduce_interval is None or self.later_reproduce_interval > 0,
              f"algo.later_reproduce_interval must be > 0 or null, got "
              f"{self.later_reproduce_interval}.")
        check(self.proposal_step in ("sgd", "adam"),
              f"algo.proposal_step must be 'sgd' or 'adam', got {self.proposal_step!r}.")
        check(self.mc_lower < self.mc_upper,
              f"algo.mc_lower ({self.mc_lower}) must be below algo.mc_upper ({self.mc_upper}).")

    def check_run(self, cfg: Any) -> None:
        """What ePOET needs of the run's other settings (`cfg`: the root Config)."""
        check(cfg.terrain.kind == "cppn",
              f"algo={self.name} evolves CPPN terrains, so it needs terrain=cppn "
              f"(got terrain={cfg.terrain.kind}).")

    def unused_keys(self) -> list[str]:
        """Settings of the budget an ES run never reads: its budget is iterations."""
        return ["budget.frames", "budget.eval_every", "budget.sac_frames_per_iteration"]
