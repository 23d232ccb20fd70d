"""`algo=epoet_sac`: ePOET's runner (epoet.poet.runner) driving the ePOET-SAC loop.

Imported only when a config names it: torch and TorchRL take seconds to import, which ePOET
runs never need.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from epoet.config import Config
from epoet.epoet_sac.loop import EpoetSac, make_epoet_sac
from epoet.poet import runner
from epoet.tracking import Tracker


def train(cfg: Config, tracker: Tracker, run_dir: Path,
          resume: dict[str, Any] | None) -> EpoetSac:
    return runner.train(cfg, tracker, run_dir, resume, make_epoet_sac)
