"""What `run=<spec>` resolves to (epoet.eval.agents `resolve_run`, the shipped reference agents
epoet.eval.reference): a policy file in one of the two formats (`AgentSource`), and what is
known of the run that trained it (`TrainedRun`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from omegaconf import OmegaConf

from epoet.envs.config import AgentConfig
from epoet.rollout.agent_files import (
    check_robot,
    read_es_policy,
    read_torch_policy,
    recorded_integrator,
)
from epoet.rollout.policy import forward

if TYPE_CHECKING:
    from epoet.tracking import StoredRun

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class AgentSource:
    """A policy file and its format; picklable, so worker processes load it themselves."""

    kind: str  # "es" | "torch"
    path: Path

    def check(self) -> None:
        """AgentError unless the file is a usable policy; cheap, and imports no MuJoCo, so
        commands check it before any other work."""
        if self.kind == "es":
            read_es_policy(self.path)
        else:
            read_torch_policy(self.path)

    def load(self) -> Policy:
        """The checked policy (AgentError for a bad file)."""
        if self.kind == "es":
            theta, sizes = read_es_policy(self.path)
            return lambda obs: forward(theta, obs, sizes)
        from epoet.rollout.torch_policy import load_policy  # torch only when a torch policy is used

        return load_policy(self.path)


@dataclass(frozen=True)
class TrainedRun:
    """What `run=<spec>` resolved to."""

    agent: AgentSource
    label: str  # e.g. "epoet-s1 env3" or a file's stem
    stored: StoredRun | None  # the MLflow run to log results to, when known
    algo: str | None
    seed: str | None
    config: dict[str, Any] | None  # the run's resolved config, when known
    folder: Path | None  # the run folder, when given one

    @property
    def run_id(self) -> str | None:
        return None if self.stored is None else self.stored.run_id

    def agent_config(self, default: AgentConfig) -> AgentConfig:
        """The robot and episode rules the agent was trained with (a bare policy file:
        `default`, with the integrator the file records); AgentError unless its file was
        trained on that robot (cheap, no MuJoCo)."""
        if self.config is None:
            integrator = recorded_integrator(self.agent.path, self.agent.kind)
            agent = default if integrator is None else replace(default, integrator=integrator)
        else:
            from epoet.config import saved_agent  # Hydra: not for the MLflow model's loader

            merged = OmegaConf.merge(
                OmegaConf.structured(AgentConfig), saved_agent(self.config["agent"])
            )
            agent = cast(AgentConfig, OmegaConf.to_object(merged))  # the schema's type
        check_robot(self.agent.path, self.agent.kind, agent)
        return agent

    @property
    def score_scale(self) -> float:
        """The run's budget scales the paper's score thresholds (docs/configs.md)."""
        if self.config is None:
            return 1.0
        return float(self.config["budget"]["score_scale"])
