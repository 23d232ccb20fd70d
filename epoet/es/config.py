"""The OpenAI-ES settings of every ePOET pair (conf/algo/epoet.yaml `es`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from epoet.core.schema import check, non_negative, positive


@dataclass
class EsConfig:
    """OpenAI-ES of every pair (paper Table 4, docs/reference.md "ES and the ePOET loop")."""

    KEY: ClassVar[str] = "algo.es"

    hidden: list[int]
    lr: float
    lr_decay: float
    lr_floor: float
    sigma: float
    sigma_decay: float
    sigma_floor: float
    l2_coeff: float
    obs_norm_episodes: int  # 0: raw observations; k: standardised, stats from k per pair
    terrain_variants: int  # terrains an ES step spreads its mirrored pairs over (1: the niche's)

    def __post_init__(self) -> None:
        check(
            len(self.hidden) > 0 and all(h > 0 for h in self.hidden),
            f"algo.es.hidden must be a non-empty list of positive sizes, got {self.hidden}.",
        )
        positive(self, "lr", "lr_floor", "sigma", "sigma_floor", "terrain_variants")
        non_negative(self, "l2_coeff", "obs_norm_episodes")
        for name in ("lr_decay", "sigma_decay"):
            value = getattr(self, name)
            check(0.0 < value <= 1.0, f"algo.es.{name} must be in (0, 1], got {value}.")
        check(
            self.lr_floor <= self.lr and self.sigma_floor <= self.sigma,
            "algo.es floors must not exceed the initial lr / sigma.",
        )
