"""Fault soak: a smoke ePOET run killed again and again, resumed each time, against one that ran
straight through.

The soaked run (2 rollout workers, a checkpoint every iteration, reproduction and transfers on)
first loses a rollout worker (SIGKILL; the run must carry on), then its main process is killed
`--kills` times at random moments after a checkpoint, by SIGTERM, SIGINT or SIGKILL in turn, and
resumed with `resume=auto` after each kill. Printed per kill: the signal, the iteration reached,
the checkpoint it resumed from, and the processes of the run still alive 5 s later. At the end:
metric points logged twice, then the last line

    lost=N orphans=N equal=True|False

lost: iterations a resume had to redo beyond what the kill may cost (0 expected: SIGTERM and
SIGINT checkpoint what was reached before exiting; SIGKILL may lose only the iterations since the
last checkpoint written before it); orphans: processes left behind, summed over kills (0 expected);
equal: the final state equals the uninterrupted run's (every agent's parameters and scores).
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mlflow
import numpy as np

from epoet.core.checkpoint import load_checkpoint

# How the tests count a run's processes; a test helper, so it lives in tests/, not the package.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from processes import processes_with_env  # noqa: E402

OVERRIDES = ["budget=smoke", "workers.num=2", "algo.es.hidden=[8]", "terrain.grid=40",
             "checkpoint_every=1", "algo.iterations_before_transfer=1", "algo.adjust_interval=2",
             "algo.num_children=2", "algo.repro_threshold=-100000", "algo.mc_lower=-100000",
             "algo.mc_upper=100000"]
TAG = "EPOET_SOAK"


def launch(args: list[str], cwd: Path, tag: str) -> subprocess.Popen:
    env = {**os.environ, TAG: tag, "MLFLOW_TRACKING_URI": f"sqlite:///{cwd}/mlflow.db"}
    return subprocess.Popen([sys.executable, "-m", "epoet", *OVERRIDES, *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def iterations(proc: subprocess.Popen, until: int | None = None) -> int:
    """Read progress lines; return the last iteration completed (stop reading at `until`)."""
    done = 0
    for line in proc.stdout:
        if line.startswith("[epoet] it "):
            done = int(line.split()[2].split("/")[0])
            if until is not None and done >= until:
                break
    return done


def checkpoint_iteration(run_dir: Path) -> int:
    path = run_dir / "checkpoint.pkl"
    return load_checkpoint(path)["open_ended"]["iteration"] if path.exists() else 0


def worker_pids(tag: str, main: int) -> list[int]:
    """The run's rollout workers: its processes other than the main one and the fork server."""
    pids = [p for p in processes_with_env(TAG, tag) if p != main]
    return [p for p in pids if "forkserver" not in Path(f"/proc/{p}/cmdline").read_text()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iterations", type=int, default=16)
    parser.add_argument("--kills", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    total = [f"budget.iterations={args.iterations}"]

    with tempfile.TemporaryDirectory(prefix="fault_soak_") as tmp:
        tmp = Path(tmp)
        straight = launch([*total, f"hydra.run.dir={tmp / 'straight'}"], tmp, "straight")
        iterations(straight)
        assert straight.wait() == 0, "the uninterrupted run failed"

        run_dir = tmp / "soaked"
        run = [*total, f"hydra.run.dir={run_dir}", "resume=auto"]
        lost = orphans = 0
        proc = launch(run, tmp, "soak-0")
        iterations(proc, until=1)
        workers = worker_pids("soak-0", proc.pid)
        os.kill(workers[0], signal.SIGKILL)
        print(f"worker {workers[0]} killed at iteration >= 1: the run carries on", flush=True)
        signals = [signal.SIGTERM, signal.SIGINT, signal.SIGKILL]
        for kill in range(args.kills):
            tag = f"soak-{kill}"
            reached = iterations(proc, until=checkpoint_iteration(run_dir) + rng.randint(1, 2))
            if reached >= args.iterations:
                break
            time.sleep(rng.uniform(0.0, 0.3))  # somewhere inside the next iteration
            sig = signals[kill % len(signals)]
            saved = checkpoint_iteration(run_dir)
            proc.send_signal(sig)
            reached = max(reached, iterations(proc))  # a SIGTERM'd run finishes its iteration
            proc.wait()
            time.sleep(5.0)
            left = processes_with_env(TAG, tag)
            orphans += len(left)
            for pid in left:
                os.kill(pid, signal.SIGKILL)
            resumed_from = checkpoint_iteration(run_dir)
            # A checkpoint never goes back; SIGTERM and SIGINT also save what was reached.
            lost += max(0, (saved if sig == signal.SIGKILL else reached) - resumed_from)
            print(f"kill {kill + 1}: {sig.name} at iteration {reached}, exit {proc.returncode}, "
                  f"resuming from {resumed_from}, processes left {len(left)}", flush=True)
            proc = launch(run, tmp, f"soak-{kill + 1}")
        iterations(proc)
        assert proc.wait() == 0, "the soaked run did not finish"

        a = load_checkpoint(run_dir / "checkpoint.pkl")
        b = load_checkpoint(tmp / "straight" / "checkpoint.pkl")
        pools = [(s["open_ended"]["active"] + s["open_ended"]["archived"]) for s in (a, b)]
        equal = (a["open_ended"]["iteration"] == b["open_ended"]["iteration"]
                 and len(pools[0]) == len(pools[1])
                 and all(np.array_equal(p["es"]["theta"], q["es"]["theta"])
                         and p["scores"] == q["scores"] for p, q in zip(*pools)))
        history = mlflow.MlflowClient(f"sqlite:///{tmp}/mlflow.db").get_metric_history(
            a["run_id"], "best_score")
        steps = [m.step for m in history]
        print(f"metric points logged twice: {len(steps) - len(set(steps))} "
              f"(best_score has {len(set(steps))} of {args.iterations} iterations)")
        print(f"lost={lost} orphans={orphans} equal={equal}")


if __name__ == "__main__":
    main()
