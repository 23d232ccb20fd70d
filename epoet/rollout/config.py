"""The rollout folder's settings (conf/workers/*.yaml) and the activations a policy may use.

They live here, beside the code that reads them, so that rollouts import nothing above their
folder; epoet/config.py composes them into the run's config, and epoet/rl/config.py checks a
baseline's `activation` against the names a torch policy file may record.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import ClassVar, Optional

from epoet.core.schema import check, positive

# What a torch policy's hidden layers may apply (`activation` of the baselines and of their
# policy files, epoet.rollout.agent_files); epoet.rollout.torch_policy maps them to torch.
RL_ACTIVATIONS = ("tanh", "relu", "elu")


@dataclass
class WorkersConfig:
    """Where ES rollouts run: `local` is a process pool on this machine, `ray` a Ray cluster."""

    KEY: ClassVar[str] = "workers"

    backend: str
    num: Optional[int]  # None: one worker per available core (Ray: per cluster CPU)
    batch: int  # robots per process (fits the cache: bench/rollout_throughput)
    address: Optional[str] = None  # ray: a running cluster's address; None starts a local Ray

    def __post_init__(self) -> None:
        check(
            self.backend in ("local", "ray"),
            f"workers.backend must be 'local' or 'ray', got {self.backend!r}.",
        )
        check(self.num is None or self.num > 0, f"workers.num must be > 0, got {self.num}.")
        positive(self, "batch")
        check(
            self.address is None or self.backend == "ray",
            "workers.address is the Ray cluster to join, so it needs workers=ray.",
        )
        check(
            self.backend != "ray" or importlib.util.find_spec("ray") is not None,
            "workers=ray needs Ray, the 'distributed' extra: "
            "pip install -c constraints.txt -e '.[distributed]'.",
        )
