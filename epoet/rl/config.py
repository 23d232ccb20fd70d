"""What the RL baselines' settings share: the baselines' run rules, the networks' checks and
PPO's and V-MPO's on-policy update (each algorithm's own schema: epoet/{ppo,sac,vmpo}/config.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Protocol

from epoet.core.algorithm import AlgoSettings
from epoet.core.schema import check, config_key, positive
from epoet.rollout.config import RL_ACTIVATIONS

# --- RL baselines: PPO, SAC and VMPO (paper Tables 2-3, docs/reference.md) -----------------
# Sizes are per collector batch of `frames_per_batch` frames; budget.frames is the total
# (`BaselineBudgetConfig`). A budget smaller than one batch shrinks the batch and keeps the ratios
# (epochs per batch, SAC updates and random frames per collected frame): see `BatchPlan` in
# epoet/rl/.


def check_network(obj: Any) -> None:
    """The checks of an RL network config (hidden sizes, activation, lr, discount)."""
    check(
        len(obj.hidden) > 0 and all(h > 0 for h in obj.hidden),
        f"{config_key(obj, 'hidden')} must be a non-empty list of positive sizes, got "
        f"{obj.hidden}.",
    )
    check(
        obj.activation in RL_ACTIVATIONS,
        f"{config_key(obj, 'activation')} must be one of {list(RL_ACTIVATIONS)}, got "
        f"{obj.activation!r}.",
    )
    positive(obj, "lr")
    check(0.0 < obj.gamma <= 1.0, f"{config_key(obj, 'gamma')} must be in (0, 1], got {obj.gamma}.")


class BaselineSettings(Protocol):
    """What the baseline run (baseline_run.py) reads of every baseline's settings; each schema
    has these fields (PPO's and V-MPO's through `RlConfig`, SAC's its own)."""

    name: str
    hidden: list[int]
    activation: str
    frames_per_batch: int
    obs_norm: bool


@dataclass
class BaselineConfig(AlgoSettings):
    """What the RL baselines ask of a run: they collect in-process and count frames."""

    def check_run(self, cfg: Any) -> None:
        """What a baseline needs of the run's other settings (`cfg`: the root Config)."""
        check(
            cfg.workers.backend == "local",
            f"workers={cfg.workers.backend} runs ES rollouts, and algo={self.name} "
            f"has none (it collects in-process): use workers=local.",
        )

    def unused_keys(self) -> list[str]:
        """Settings an RL run never reads: it has no ES workers."""
        return ["workers.batch", "workers.address"]


@dataclass
class RlConfig(BaselineConfig):
    """What PPO and VMPO share: the networks, the optimiser and the collector batch."""

    hidden: list[int]
    activation: str
    lr: float  # one Adam over all parameters (Table 2: policy = value lr)
    gamma: float
    frames_per_batch: int  # the paper's trajectory_length
    obs_norm: bool  # running observation normalisation (PPO and VMPO in the paper)

    def __post_init__(self) -> None:
        check_network(self)
        positive(self, "frames_per_batch")


@dataclass
class OnPolicyConfig(RlConfig):
    """PPO and VMPO: GAE on each batch, then `epochs` passes of shuffled minibatches."""

    gae_lambda: float  # Table 2 calls it "tau"
    epochs: int
    minibatch: int
    critic_coeff: float
    max_grad_norm: Optional[float]  # not in the paper; None disables clipping

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            0.0 <= self.gae_lambda <= 1.0,
            f"algo.gae_lambda must be in [0, 1], got {self.gae_lambda}.",
        )
        positive(self, "epochs", "minibatch", "critic_coeff")
        check(
            self.max_grad_norm is None or self.max_grad_norm > 0,
            f"algo.max_grad_norm must be > 0 or null, got {self.max_grad_norm}.",
        )
