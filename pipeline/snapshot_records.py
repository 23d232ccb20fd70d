"""The Hydra callback with which `make paper` at a CPU-hour budget records each run as it ends.

When a training job of the multirun finishes (its folder holds DONE), its CPU-time snapshots are
evaluated on the suites and written as its record (`python -m pipeline.snapshots
--exported-only`, in a child process: the job's process is still inside Hydra, and the
evaluation takes the job's core, so the jobs at a time stay one per core). A job that stopped
early (a signal, an error) leaves no record; the next call resumes it and records it then. A
job found finished (`resume=auto` skips it) is recorded again, which evaluates only what its
record lacks, so a record interrupted by the session's end is completed by the next call.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from epoet.run_state import DONE


def record_command(run_dir: Path, out: Path, suites: str, episodes: int) -> list[str]:
    """The records command for one run folder (its store: the one its config names, else the
    default store of the folder `make paper` started in, the job's too)."""
    return [
        sys.executable,
        "-m",
        "pipeline.snapshots",
        "--runs",
        str(run_dir),
        "--out",
        str(out),
        "--suites",
        suites,
        "--episodes",
        str(episodes),
        "--exported-only",
    ]


class RecordSnapshots(Callback):
    """`hydra.callbacks.records`: each finished job's snapshots into the records folder `out`."""

    def __init__(self, out: str, suites: str, episodes: int) -> None:
        self.out, self.suites, self.episodes = Path(out), suites, episodes

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        run_dir = Path(config.hydra.runtime.output_dir)
        if not (run_dir / DONE).is_file():
            return
        command = record_command(run_dir, self.out, self.suites, self.episodes)
        print(f"[paper] recording {run_dir.name}: {' '.join(command[1:])}", flush=True)
        if (code := subprocess.run(command).returncode) != 0:
            print(
                f"[paper] recording {run_dir.name} stopped with exit code {code}; the next "
                f"call records it again",
                file=sys.stderr,
                flush=True,
            )
