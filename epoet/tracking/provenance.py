"""What a run records about where it comes from: its config as params, the code's git commit,
and the sweep it belongs to.

A sweep's parent run id reaches each job through env EPOET_PARENT_RUN_ID (set by
`epoet.sweep.MlflowSweepCallback`).
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Mapping
from typing import Any

from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH

from epoet.tracking.store import PROJECT_ROOT

PARENT_RUN_ENV = "EPOET_PARENT_RUN_ID"


def flatten(cfg: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Flatten a nested config (e.g. `OmegaConf.to_container(cfg, resolve=True)`) into params.

    Keys are dotted paths; values are str()'d and cut to MLflow's param value limit. Lists stay
    one param (their str()), which keeps long option lists from flooding the params table.
    """
    flat: dict[str, str] = {}
    for key, value in cfg.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            flat.update(flatten(value, prefix=f"{name}."))
        else:
            flat[name] = str(value)[:MAX_PARAM_VAL_LENGTH]
    return flat


def git_commit() -> str:
    """The project's HEAD commit for the run's tags; "unknown" outside a repository."""
    try:
        result = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=PROJECT_ROOT,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    commit = result.stdout.strip()
    return commit if result.returncode == 0 and commit else "unknown"


def parent_run_id() -> str | None:
    """The sweep's parent run id when this job runs inside a Hydra multirun, else None."""
    return os.environ.get(PARENT_RUN_ENV) or None
