"""One Hydra job: validate the config, open the tracker, run the algorithm's runner.

Data flow is one way: config -> components -> runner -> tracker. Everything that can fail on bad
input (config ranges, an unsupported combination, the tracking store, the checkpoint to resume)
fails here, in one sentence, before any long work starts.
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Callable

from omegaconf import DictConfig, OmegaConf

from epoet.checkpoint import CheckpointError, find_checkpoint, load_checkpoint
from epoet.config import Config, validate
from epoet.tracking import MlflowTracker, Tracker, flatten, parent_run_id

# algo.name -> "module:function" with the runner shape
#   train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict | None) -> Any
RUNNERS: dict[str, str] = {
    "epoet": "epoet.poet.runner:train",
    "ppo": "epoet.rl.ppo:train",
    "sac": "epoet.rl.sac:train",
    "vmpo": "epoet.rl.vmpo_runner:train",
}

Runner = Callable[[Config, Tracker, Path, "dict[str, Any] | None"], Any]


def runner_for(name: str) -> Runner:
    module, func = RUNNERS[name].split(":")
    return getattr(importlib.import_module(module), func)


def run(raw: DictConfig, run_dir: Path) -> Any:
    """Train the configured algorithm; returns the runner's final state."""
    cfg: Config = validate(raw)
    resume = None
    if cfg.resume:
        path = find_checkpoint(cfg.resume)
        resume = load_checkpoint(path)
        if resume.get("algo") != cfg.algo.name:
            raise CheckpointError(f"checkpoint {path} is from algo={resume.get('algo')}, so it "
                                  f"cannot resume algo={cfg.algo.name}.")
    run_dir.mkdir(parents=True, exist_ok=True)
    resolved = OmegaConf.to_container(raw, resolve=True)
    tags = {"algo": cfg.algo.name, "terrain": cfg.terrain.kind, "agent": cfg.agent.name,
            "seed": str(cfg.seed), "budget": cfg.budget.name}
    with MlflowTracker(cfg.tracking.uri, cfg.tracking.experiment) as tracker:
        tracker.start(run_name=f"{cfg.algo.name}-s{cfg.seed}", params=flatten(resolved),
                      tags=tags, parent_run_id=parent_run_id(),
                      resume_run_id=resume["run_id"] if resume else None)
        if resume is None:
            tracker.log_dict(resolved, "config.yaml")
        print(f"[epoet] {cfg.algo.name} seed={cfg.seed} budget={cfg.budget.name} "
              f"run_id={tracker.run_id} dir={run_dir}", flush=True)
        return runner_for(cfg.algo.name)(cfg, tracker, run_dir, resume)

