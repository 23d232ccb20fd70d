"""PPO's settings (conf/algo/ppo.yaml) and its record."""

from __future__ import annotations

from dataclasses import dataclass

from epoet.core.algorithm import Algorithm, Family, Runner
from epoet.core.schema import non_negative, positive
from epoet.rl.config import OnPolicyConfig


@dataclass
class PpoConfig(OnPolicyConfig):
    """PPO with the clipped objective (paper Table 2)."""

    clip: float
    entropy_coeff: float
    normalize_advantage: bool  # not in the paper; the common PPO implementation detail

    def __post_init__(self) -> None:
        super().__post_init__()
        positive(self, "clip")
        non_negative(self, "entropy_coeff")


def _runner() -> Runner:
    from epoet.ppo.train import train  # torch: imported when a run starts, not at composition

    return train


PPO = Algorithm(
    name="ppo",
    family=Family.BASELINE,
    schema=PpoConfig,
    runner=_runner,
    label="PPO",
    colour="tab:blue",
)
