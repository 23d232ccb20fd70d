"""ePOET-SAC's settings (conf/algo/epoet_sac.yaml): ePOET's plus the SAC learner's and the join's."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Optional

from epoet.core.algorithm import Algorithm, Family, Runner
from epoet.core.schema import check, non_negative, positive
from epoet.open_ended.config import EpoetConfig
from epoet.sac.config import SacLearnerConfig

# --- ePOET-SAC (paper Section 3, Algorithms 1-3; docs/reference.md) ---------------------------

SAC_TERRAINS = ("pool", "bowl")
JOIN_MAPPINGS = ("dagger", "distill", "random")


@dataclass
class DistillConfig:
    """Behaviour cloning between the SAC actor and ES agents (epoet/epoet_sac/bridge.py)."""

    KEY: ClassVar[str] = "algo.distill"

    states: int  # replay states per distillation
    epochs: int
    batch: int
    lr: float

    def __post_init__(self) -> None:
        positive(self, "states", "epochs", "batch", "lr")


@dataclass
class DaggerConfig:
    """DAgger from the SAC actor into the ES network at the join (epoet/epoet_sac/dagger.py)."""

    KEY: ClassVar[str] = "algo.dagger"

    rounds: int  # student rollouts after the teacher's
    episodes: int  # episodes per round (the teacher's and the student's)
    epochs: int  # passes over the aggregated states per round
    batch: int
    lr: float

    def __post_init__(self) -> None:
        positive(self, "rounds", "episodes", "epochs", "batch", "lr")


@dataclass
class WarmConfig:
    """How a warm-started learner resumes its trained actor (`algo.sac_init` set; a cold start
    ignores these). Defaults measured in docs/results/epoet-sac-warm-start/."""

    KEY: ClassVar[str] = "algo.warm"

    alpha: Optional[float]  # the temperature; None: the source's final one (warm_start.py)
    critic_updates: int  # critic-only updates on the first Train_SAC's replay
    actor_lr: Optional[float]  # the actor's learning rate; None: algo.sac.lr
    anchor: float  # weight of the actor's pull towards the actor it was given (0: plain SAC)

    def __post_init__(self) -> None:
        non_negative(self, "critic_updates", "anchor")
        for name in ("alpha", "actor_lr"):
            value = getattr(self, name)
            check(
                value is None or value > 0,
                f"{self.KEY}.{name} must be > 0 or null, got {value}.",
            )


@dataclass
class EpoetSacConfig(EpoetConfig):
    """ePOET plus a SAC learner trained every iteration (Algorithm 1's red steps)."""

    sac: SacLearnerConfig
    warm: WarmConfig
    distill: DistillConfig
    dagger: DaggerConfig
    frames_per_iteration: int  # SAC's own environment steps per ePOET iteration (Train_SAC;
    # a budget's: conf/algo_budget/epoet_sac/<budget>.yaml)
    updates_per_frame: float  # gradient updates per SAC frame (paper: 1)
    es_episodes_per_pair: int  # ES-step episodes per active pair recorded into the replay
    sac_terrain: str  # pool: a sampled active environment; bowl: the reference's
    mapping: str  # the join's SAC actor -> ES mapping: dagger | distill | random
    join_every_transfers: int  # the join at t mod (k N_transfer) = k N_transfer - 2
    pretrain_iterations: int  # Train_SAC iterations before iteration 0 (reference: 500)
    sac_init: Optional[str]  # None: cold; a SAC run (folder or MLflow run id) or
    # reference:sac/42: its actor and critics (warm_start.py)
    sac_threads: Optional[int]  # torch threads of the SAC learner; None: workers.num

    def __post_init__(self) -> None:
        super().__post_init__()
        positive(self, "frames_per_iteration", "join_every_transfers")
        non_negative(self, "updates_per_frame", "es_episodes_per_pair", "pretrain_iterations")
        check(
            self.sac_terrain in SAC_TERRAINS,
            f"algo.sac_terrain must be one of {list(SAC_TERRAINS)}, got {self.sac_terrain!r}.",
        )
        check(
            self.mapping in JOIN_MAPPINGS,
            f"algo.mapping must be one of {list(JOIN_MAPPINGS)}, got {self.mapping!r}.",
        )
        check(
            self.sac_threads is None or self.sac_threads > 0,
            f"algo.sac_threads must be > 0 or null, got {self.sac_threads}.",
        )
        check(
            self.sac_init is None or bool(str(self.sac_init).strip()),
            "algo.sac_init must be null (a cold start), a SAC run folder or MLflow run id, or "
            "reference:sac/42.",
        )

    def check_inputs(self, cfg: Any) -> None:
        """The warm start `sac_init` names can start this learner (it reads the file: torch)."""
        from epoet.epoet_sac.runner import warm_start_of

        warm_start_of(cfg)

    def unused_keys(self) -> list[str]:
        """The mappings' settings other than the join's, and a cold start's warm-start ones."""
        unused = [f"algo.{m}" for m in ("distill", "dagger") if m != self.mapping]
        return unused + (["algo.warm"] if self.sac_init is None else [])


def _runner() -> Runner:
    # torch: imported when a run starts, not at composition
    from epoet.epoet_sac.runner import train

    return train


EPOET_SAC = Algorithm(
    name="epoet_sac",
    family=Family.OPEN_ENDED,
    schema=EpoetSacConfig,
    runner=_runner,
    label="ePOET-SAC",
    colour="tab:purple",
    beats="epoet",
)
