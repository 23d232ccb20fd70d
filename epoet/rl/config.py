"""The RL baselines' settings (conf/algo/{ppo,sac,vmpo}.yaml, conf/learner/sac.yaml)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from epoet.core.algorithm import Algorithm, AlgoSettings, Family
from epoet.core.schema import check, config_key, non_negative, positive
from epoet.rollout.config import RL_ACTIVATIONS

# --- RL baselines: PPO, SAC and VMPO (paper Tables 2-3, docs/reference.md) -----------------
# Sizes are per collector batch of `frames_per_batch` frames; budget.frames is the total
# (`BaselineBudgetConfig`). A budget smaller than one batch shrinks the batch and keeps the ratios
# (epochs per batch, SAC updates and random frames per collected frame): see `BatchPlan` in
# epoet/rl/.


def _check_network(obj: Any) -> None:
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
        _check_network(self)
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


@dataclass
class VmpoConfig(OnPolicyConfig):
    """V-MPO (Song et al. 2019; docs/reference.md); see epoet/rl/vmpo.py."""

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
        _check_network(self)
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


PPO = Algorithm(
    name="ppo",
    family=Family.BASELINE,
    schema=PpoConfig,
    runner="epoet.rl.ppo.train",
    label="PPO",
    colour="tab:blue",
)
SAC = Algorithm(
    name="sac",
    family=Family.BASELINE,
    schema=SacConfig,
    runner="epoet.rl.sac.train",
    label="SAC",
    colour="tab:orange",
    beats="ppo",
)
VMPO = Algorithm(
    name="vmpo",
    family=Family.BASELINE,
    schema=VmpoConfig,
    runner="epoet.rl.vmpo.train",
    label="VMPO",
    colour="tab:green",
)
