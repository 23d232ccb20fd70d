"""Learning with RK4 against implicitfast: evaluation score per iteration and per second.

Runs the laptop budget's root pair alone (no reproduction) for both integrators and three seeds
as one Hydra multirun into its own MLflow store, then prints, per integrator, the mean over seeds
of the root pair's population return and evaluation score over the last `--window` iterations
(the same iterations: learning per iteration), the wall time, and the score reached per
wall-clock second of training:

    python bench/integrator_learning.py --iterations 40 --store /tmp/integrators

With --skip-runs it only reads an existing store. The last line is
`implicitfast/rk4 score per second = X`.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from mlflow import MlflowClient


def sweep(store: Path, iterations: int, seeds: str) -> None:
    store.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{store / 'mlflow.db'}"}
    subprocess.run([sys.executable, "-m", "epoet", "-m", "budget=laptop",
                    f"budget.iterations={iterations}", "algo.adjust_interval=100000",
                    "agent.integrator=rk4,implicitfast", f"seed={seeds}",
                    f"hydra.sweep.dir={store / 'multirun'}"], env=env, check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--store", type=Path, default=Path("/tmp/integrator_learning"))
    parser.add_argument("--iterations", type=int, default=40)
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--window", type=int, default=10, help="last iterations averaged")
    parser.add_argument("--skip-runs", action="store_true")
    args = parser.parse_args()
    if not args.skip_runs:
        sweep(args.store, args.iterations, args.seeds)

    client = MlflowClient(f"sqlite:///{args.store / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("epoet")
    rows: dict[str, list[tuple[float, float, float]]] = {}
    for run in client.search_runs([experiment.experiment_id]):
        integrator = run.data.params.get("agent.integrator")
        if integrator is None or run.data.tags.get("mlflow.parentRunId") is None:
            continue
        def history(key: str) -> list[float]:
            points = client.get_metric_history(run.info.run_id, key)
            return [m.value for m in sorted(points, key=lambda m: m.step)]

        scores, returns = history("pair0/score"), history("pair0/return_mean")
        wall = history("elapsed")[-1]  # training seconds, summed over resumes
        rows.setdefault(integrator, []).append((float(np.mean(returns[-args.window:])),
                                                float(np.mean(scores[-args.window:])), wall))
    print(f"last {args.window} iterations, mean ± std over seeds:")
    print(f"{'integrator':12s} {'seeds':>5s} {'pop. return':>14s} {'eval score':>14s} "
          f"{'wall s':>7s} {'score/s':>8s}")
    per_second = {}
    for integrator, values in sorted(rows.items()):
        returns, scores, wall = (np.array(v) for v in zip(*values))
        per_second[integrator] = float(np.mean(scores / wall))
        print(f"{integrator:12s} {len(values):5d} {returns.mean():7.1f} ± {returns.std():5.1f} "
              f"{scores.mean():7.1f} ± {scores.std():5.1f} {wall.mean():7.0f} "
              f"{per_second[integrator]:8.3f}")
    print(f"implicitfast/rk4 score per second = "
          f"{per_second['implicitfast'] / per_second['rk4']:.2f}")


if __name__ == "__main__":
    main()
