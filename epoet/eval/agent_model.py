"""A trained agent as an MLflow pyfunc model, so `mlflow.pyfunc.load_model("runs:/<id>/agent")`
gives its actions without this package's commands.

Logged by `MlflowTracker.log_agent` with this module as the pyfunc loader: MLflow stores the
policy file (ES `.npz` or exported `policy.pt`) as the model's data and calls `_load_pyfunc`
with its local copy.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from epoet.eval.agents import file_source
from epoet.eval.trained_run import Policy


class PolicyModel:
    """pyfunc's `predict`: a batch of observations (n, obs) to actions (n, act) float64 (the
    hexapod's 53 and 18; the model's signature says its robot's). MLflow
    hands it the observations as a DataFrame of the signature's double columns (the caller's
    array, float32 or float64, converted)."""

    def __init__(self, policy: Policy) -> None:
        self.policy = policy

    def predict(self, model_input: Any, params: dict[str, Any] | None = None) -> np.ndarray:
        # a copy: MLflow's DataFrame may hand a read-only array, which torch warns about
        observations = np.atleast_2d(np.array(model_input, dtype=np.float64))
        return np.stack([np.asarray(self.policy(obs), dtype=np.float64) for obs in observations])


def _load_pyfunc(data_path: str) -> PolicyModel:
    """MLflow's hook for a pyfunc `loader_module`."""
    return PolicyModel(file_source(Path(data_path)).load())
