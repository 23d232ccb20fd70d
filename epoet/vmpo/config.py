"""V-MPO's settings (conf/algo/vmpo.yaml) and its record."""

from __future__ import annotations

from dataclasses import dataclass

from epoet.core.algorithm import Algorithm, Family, Runner
from epoet.core.schema import check, positive
from epoet.rl.config import OnPolicyConfig


@dataclass
class VmpoConfig(OnPolicyConfig):
    """V-MPO (Song et al. 2019; docs/reference.md); see train.py and loss.py."""

    top_fraction: float
    eta_init: float
    eps_eta: float
    alpha_init: float
    eps_alpha: float

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            0.0 < self.top_fraction <= 1.0,
            f"algo.top_fraction must be in (0, 1], got {self.top_fraction}.",
        )
        positive(self, "eta_init", "eps_eta", "alpha_init", "eps_alpha")


def _runner() -> Runner:
    from epoet.vmpo.train import train  # torch: imported when a run starts, not at composition

    return train


VMPO = Algorithm(
    name="vmpo",
    family=Family.BASELINE,
    schema=VmpoConfig,
    runner=_runner,
    label="VMPO",
    colour="tab:green",
)
