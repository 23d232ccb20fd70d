"""SAC's settings: its learner's (conf/learner/sac.yaml, which ePOET-SAC reads as `algo.sac`)
and `algo=sac`'s collection (conf/algo/sac.yaml); and its record."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from epoet.core.algorithm import Algorithm, Family, Runner
from epoet.core.schema import check, config_key, non_negative, positive
from epoet.rl.config import BaselineConfig, check_network


@dataclass
class SacLearnerConfig:
    """SAC's networks, losses and replay (paper Table 3: conf/learner/sac.yaml), shared by
    `algo=sac` and `algo=epoet_sac` (as `algo.sac`)."""

    KEY: ClassVar[str] = "algo.sac"

    hidden: list[int]
    activation: str
    lr: float  # actor, critics and the entropy temperature
    gamma: float
    batch_size: int
    tau: float  # soft target update rate
    alpha_init: float
    target_entropy: Optional[float]  # None: -(action dimensions), the usual heuristic
    reward_scale: float
    init_random_frames: int  # Table 3 pretrain_epoch 1: the first frames act uniformly
    buffer_size: int

    def __post_init__(self) -> None:
        check_network(self)
        positive(self, "batch_size", "alpha_init", "reward_scale", "buffer_size")
        non_negative(self, "init_random_frames")
        check(
            0.0 < self.tau <= 1.0, f"{config_key(self, 'tau')} must be in (0, 1], got {self.tau}."
        )
        check(
            self.buffer_size >= self.batch_size,
            f"{config_key(self, 'buffer_size')} ({self.buffer_size}) must hold at least one batch "
            f"({config_key(self, 'batch_size')}={self.batch_size}).",
        )


@dataclass
class SacConfig(SacLearnerConfig, BaselineConfig):
    """`algo=sac`: the learner on its own TorchRL collector (paper Table 3)."""

    KEY: ClassVar[str] = "algo"

    frames_per_batch: int  # the paper's trajectory_length
    obs_norm: bool  # false: the paper normalises for PPO and VMPO only
    updates_per_batch: int  # gradient updates per collector batch

    def __post_init__(self) -> None:
        super().__post_init__()
        positive(self, "frames_per_batch", "updates_per_batch")

    def check_run(self, cfg: Any) -> None:
        super().check_run(cfg)
        check(
            cfg.budget.frames >= self.batch_size,
            f"budget.frames ({cfg.budget.frames}) must be at least algo.batch_size "
            f"({self.batch_size}), or SAC never updates.",
        )


def _runner() -> Runner:
    from epoet.sac.train import train  # torch: imported when a run starts, not at composition

    return train


SAC = Algorithm(
    name="sac",
    family=Family.BASELINE,
    schema=SacConfig,
    runner=_runner,
    label="SAC",
    colour="tab:orange",
    beats="ppo",
)
