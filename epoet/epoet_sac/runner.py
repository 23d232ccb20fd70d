"""`algo=epoet_sac`: ePOET's run of iterations (epoet.poet.runner.train_loop) over the ePOET-SAC
loop.

Imported only when a config names it: torch and TorchRL are heavy imports that ePOET runs never
need.
"""
from __future__ import annotations

from contextlib import closing
from pathlib import Path
from typing import Any

from epoet.config import Config
from epoet.epoet_sac.loop import EpoetSac
from epoet.poet.runner import layer_sizes, train_loop
from epoet.rollout.evaluators import evaluator_for
from epoet.tracking import Tracker


def train(cfg: Config, tracker: Tracker, run_dir: Path,
          resume: dict[str, Any] | None) -> EpoetSac:
    """Train ePOET-SAC for the budget's iterations (or hours); SAC's env closes at the end."""
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator, \
            closing(EpoetSac.from_config(cfg, evaluator)) as loop:
        train_loop(loop, cfg, tracker, run_dir, resume)
    return loop
