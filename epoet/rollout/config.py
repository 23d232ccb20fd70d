"""The rollout folder's settings (conf/workers/*.yaml, the `selection` of conf/config.yaml)
and the activations a policy may use.

They live here, in the folder whose code reads them, so that rollouts import nothing above their
folder, and apart from that code, so that composing a config (epoet/config.py, which every
command imports) does not import the rollout engine and MuJoCo; epoet/rl/config.py checks a
baseline's `activation` against the names a torch policy file may record.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import ClassVar, Optional

from epoet.core.schema import check, non_negative, positive
from epoet.terrain.config import RENDERINGS

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

    @property
    def may_be_lost(self) -> bool:
        """Whether the workers can go for good mid-step (a Ray cluster's nodes can; a local
        pool's processes are restarted by the pool), so a run keeps each step's starting state."""
        return self.backend == "ray"


RULES = ("validation", "own")  # how a run chooses the agent it exports (epoet/rollout/selection.py)


@dataclass
class SelectionConfig:
    """Which agent a run exports (conf/config.yaml `selection`)."""

    KEY: ClassVar[str] = "selection"

    rule: str  # validation: most held-out terrains solved | own: the run's own rule
    terrains: int  # held-out terrains (0: none, and `rule` must be own)
    generations: int  # mutations from a root genome to a held-out terrain
    max_height: float  # S of the held-out terrains, metres
    rendering: str  # clean | reference: how the held-out terrains are rendered
    episodes: int  # episodes per candidate and terrain
    episode_ratio: float  # episodes may last this x the training's (the suites')

    def __post_init__(self) -> None:
        check(
            self.rule in RULES,
            f"selection.rule must be {' or '.join(map(repr, RULES))}, got {self.rule!r}.",
        )
        check(
            self.rendering in RENDERINGS,
            f"selection.rendering must be {' or '.join(map(repr, RENDERINGS))}, "
            f"got {self.rendering!r}.",
        )
        non_negative(self, "terrains", "generations")
        positive(self, "max_height", "episodes", "episode_ratio")
        check(
            self.terrains > 0 or self.rule == "own",
            "selection.rule=validation needs held-out terrains (selection.terrains > 0).",
        )
