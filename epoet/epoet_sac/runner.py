"""`algo=epoet_sac`: the ePOET-SAC loop, run by the driver as ePOET's is
(epoet.open_ended.runner.EpoetRun).

Imported only when a config names it: torch and TorchRL are heavy imports that ePOET runs never
need.
"""

from __future__ import annotations

from contextlib import closing
from pathlib import Path
from typing import Any

from epoet.config import Config
from epoet.driver import drive
from epoet.epoet_sac.config import EpoetSacConfig
from epoet.epoet_sac.loop import EpoetSac
from epoet.epoet_sac.warm_start import WarmStart, load_warm_start
from epoet.open_ended.runner import EpoetRun, layer_sizes
from epoet.rollout.evaluators import evaluator_for
from epoet.tracking import Tracker


def warm_start_of(cfg: Config) -> WarmStart | None:
    """The SAC weights `algo.sac_init` names (None: a cold start); ConfigError in one sentence
    if they cannot start this learner."""
    algo = EpoetSacConfig.of(cfg)
    return (
        None
        if algo.sac_init is None
        else load_warm_start(algo.sac_init, algo.sac, cfg.agent, cfg.tracking.uri)
    )


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None) -> EpoetSac:
    """Train ePOET-SAC for the budget's iterations (or hours); SAC's env closes at the end. A
    resumed run's learner comes from its checkpoint, so its warm start is not read again."""
    warm_start = warm_start_of(cfg) if resume is None else None
    with (
        evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator,
        closing(EpoetSac.from_config(cfg, evaluator, warm_start)) as loop,
    ):
        drive(EpoetRun(loop, cfg, resume), cfg, tracker, run_dir, resumed=resume is not None)
    return loop
