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
from epoet.registry import register as register_record
from epoet.rollout.agent_files import ES_POLICIES, write_es_policy
from epoet.rollout.evaluators import evaluator_for
from epoet.rollout.policy import num_params, policy_sizes
from epoet.rollout.populations import Mirrored, Request
from epoet.run_state import save_run_state
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
    runner=f"{__name__}.train",
    label="Toy",
    colour="tab:brown",
)

# conf/algo/toy.yaml, as a node: its schema first (the record's runner and name), then its values
YAML = {"defaults": ["toy_schema", "_self_"], "hidden": [8], "sigma": 0.1}


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None) -> float:
    """Random search for the budget's frames, each step on a fresh terrain; exports the best
    parameters as the ES policy file evaluation reads, then checkpoints (its last state). Logs
    its family's metrics (`Family.BASELINE.metrics`) at step = frames, so it gets its curves."""
    algo = ToyConfig.of(cfg)
    frames_budget = cast(BaselineBudgetConfig, cfg.budget).frames  # its family's unit
    sizes = policy_sizes(cfg.agent, algo.hidden)
    state = (resume or {}).get("toy") or {
        "theta": np.zeros(num_params(sizes)),
        "best": -np.inf,
        "frames": 0,
        "elapsed": 0.0,
        "cpu_time": 0.0,
        "rng": np.random.default_rng(cfg.seed).bit_generator.state,
    }
    rng = np.random.default_rng()
    rng.bit_generator.state = state["rng"]
    cpu, started = CpuMeter(), time.perf_counter()
    with evaluator_for(cfg.workers, cfg.agent, cfg.terrain, sizes) as evaluator:
        while state["frames"] < frames_budget:
            noise_seed, spawn_seed = rng.integers(2**31, size=(2, 1))
            population = Mirrored.of(state["theta"], noise_seed, algo.sigma, spawn_seed)
            terrain = make_terrain(cfg.terrain, int(spawn_seed[0]))
            (episodes,) = evaluator.run([Request(terrain, population)])
            e = int(np.argmax(episodes.returns))
            if episodes.returns[e] > state["best"]:
                state["best"], state["theta"] = float(episodes.returns[e]), population.job(e)[0]
            state["frames"] += int(episodes.lengths.sum())
            state["cpu_time"] += cpu.lap()
            state["elapsed"] += time.perf_counter() - started
            started = time.perf_counter()
            tracker.log_metrics(
                state["frames"],
                {
                    "score": float(episodes.returns[e]),  # the step's better perturbation
                    "best_score": state["best"],
                    "eval/return_mean": float(episodes.returns.mean()),  # the step's episodes
                    "env_steps": state["frames"],
                    "elapsed": state["elapsed"],
                    "cpu_time": state["cpu_time"],
                    "frames": state["frames"],
                },
            )
    policy = run_dir / ES_POLICIES / "env0.npz"
    write_es_policy(policy, state["theta"], state["best"], sizes, cfg.agent)
    state["rng"] = rng.bit_generator.state
    save_run_state(run_dir, tracker, cfg, {"toy": state})
    return state["best"]


def register() -> None:
    """The toy's record and its YAML node, before anything composes a config."""
    register_record(TOY)
    ConfigStore.instance().store(group="algo", name=TOY.name, node=YAML)


if __name__ == "__main__":
    from toy_algorithm import register as register_toy  # the module, not this __main__ copy

    register_toy()
    sys.argv = sys.argv[1:]
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
