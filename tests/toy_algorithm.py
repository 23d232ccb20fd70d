"""A sixth algorithm in one module, from outside epoet/ (tests/test_algorithms.py): random search
over the ES policy. Its record, schema, runner and YAML (a ConfigStore node in the `algo` group)
are all here; `register` adds them, and nothing else in the repository names it.

`python tests/toy_algorithm.py <module> [args]` registers it and runs `python -m <module> [args]`,
e.g. `epoet algo=toy budget=smoke` or `analysis.tables`.
"""

from __future__ import annotations

import runpy
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from hydra.core.config_store import ConfigStore

from epoet.config import BaselineBudgetConfig, Config
from epoet.core.algorithm import Algorithm, AlgoSettings, Family
from epoet.core.clock import CpuMeter
from epoet.core.schema import positive
from epoet.driver import Counters, Logged, drive
from epoet.registry import register as register_record
from epoet.rollout.agent_files import ES_POLICIES, write_es_policy
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.evaluators import evaluator_for
from epoet.rollout.policy import num_params, policy_sizes
from epoet.rollout.populations import Mirrored, Request
from epoet.terrain import make_terrain
from epoet.tracking import Tracker


@dataclass
class ToyConfig(AlgoSettings):
    """Random search: each step tries a mirrored pair of perturbations of the best parameters."""

    hidden: list[int]  # the ES policy's hidden layers
    sigma: float  # the perturbations' scale

    def __post_init__(self) -> None:
        positive(self, "sigma")


TOY = Algorithm(
    name="toy",
    family=Family.BASELINE,  # one agent; its budget counts frames (algo_budget/baselines/)
    schema=ToyConfig,
    runner=lambda: train,  # defined below; the record is read only when a run starts
    label="Toy",
    colour="tab:brown",
)

# conf/algo/toy.yaml, as a node: its schema first (with the record's name), then its values
YAML = {"defaults": ["toy_schema", "_self_"], "hidden": [8], "sigma": 0.1}


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None) -> float:
    """Random search for the budget's frames; the driver checkpoints, resumes, stops on a
    signal, snapshots, exports and logs the metrics every algorithm logs. Returns the best return."""
    sizes = policy_sizes(cfg.agent, ToyConfig.of(cfg).hidden)
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, sizes) as evaluator:
        search = RandomSearch(cfg, evaluator, sizes, resume)
        drive(search, cfg, tracker, run_dir, resumed=resume is not None)
    return search.state["best"]


class RandomSearch:
    """The driver's `Trainable` (epoet/driver.py): a step tries a mirrored pair of perturbations
    of the best parameters on a fresh terrain; its state is a dict of numbers and arrays."""

    unit = "frames"  # its family's: the budget counts frames

    def __init__(
        self, cfg: Config, evaluator: Evaluator, sizes: tuple[int, ...], resume: dict | None
    ) -> None:
        self.cfg, self.evaluator, self.sizes = cfg, evaluator, sizes
        self.name, self.sigma = cfg.algo.name, ToyConfig.of(cfg).sigma
        self.total = cast(BaselineBudgetConfig, cfg.budget).frames
        self.cpu_meter = CpuMeter()
        self.state = (resume or {}).get("toy") or {
            "theta": np.zeros(num_params(sizes)),
            "best": -np.inf,
            "steps": 0,
            "frames": 0,
            "elapsed": 0.0,
            "cpu_time": 0.0,
            "rng": np.random.default_rng(cfg.seed).bit_generator.state,
        }
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = self.state["rng"]

    def step(self) -> Logged:
        state, started = self.state, time.perf_counter()
        noise_seed, spawn_seed = self.rng.integers(2**31, size=(2, 1))
        population = Mirrored.of(state["theta"], noise_seed, self.sigma, spawn_seed)
        terrain = make_terrain(self.cfg.terrain, int(spawn_seed[0]))
        (episodes,) = self.evaluator.run([Request(terrain, population)])
        e = int(np.argmax(episodes.returns))
        if episodes.returns[e] > state["best"]:
            state["best"], state["theta"] = float(episodes.returns[e]), population.job(e)[0]
        state["steps"] += 1
        state["frames"] += int(episodes.lengths.sum())
        state["elapsed"] += time.perf_counter() - started
        state["cpu_time"] += self.cpu_meter.lap()
        return Logged(state["frames"], {}, score=float(episodes.returns[e]))

    def counters(self) -> Counters:
        s = self.state
        return Counters(
            s["steps"], s["frames"], s["frames"], s["elapsed"], s["cpu_time"], s["best"]
        )

    def state_dict(self) -> dict[str, Any]:
        return {"toy": {**self.state, "rng": self.rng.bit_generator.state}}

    def save_agents(self, folder: Path) -> None:
        """The best parameters as the ES policy file evaluation reads."""
        policy = folder / ES_POLICIES / "env0.npz"
        write_es_policy(policy, self.state["theta"], self.state["best"], self.sizes, self.cfg.agent)

    def export(self, folder: Path) -> dict[str, Any]:
        self.save_agents(folder)
        return {"exported": "env0", "cpu_s": 0.0}

    def artifacts(self, run_dir: Path) -> list[tuple[Path, str | None]]:
        return [(run_dir / ES_POLICIES, ES_POLICIES)]

    def add_cpu_time(self, seconds: float) -> None:
        self.state["cpu_time"] += seconds

    def snapshot_info(self) -> dict[str, float]:
        return {"frames": float(self.state["frames"])}

    def say(self, line: str) -> None:
        print(f"[{self.name}] {line}", flush=True)

    def begin(self) -> Logged | None:
        return None

    def end(self) -> Logged | None:
        return None

    def after_checkpoint(self) -> None:
        pass


def register() -> None:
    """The toy's record and its YAML node, before anything composes a config."""
    register_record(TOY)
    ConfigStore.instance().store(group="algo", name=TOY.name, node=YAML)


if __name__ == "__main__":
    from toy_algorithm import register as register_toy  # the module, not this __main__ copy

    register_toy()
    sys.argv = sys.argv[1:]
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
