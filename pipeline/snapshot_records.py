"""The Hydra callback with which `make paper` at a CPU-hour budget records each run as it ends.

When a training job of the multirun finishes (its folder holds DONE), its CPU-time snapshots are
evaluated on the suites and written as its record (`python -m pipeline.snapshots
--exported-only`, in a child process: the job's process is still inside Hydra, and the
evaluation takes the job's core, so the jobs at a time stay one per core). A job that stopped
early (a signal, an error) leaves no record; the next call resumes it and records it then. A
job found finished (`resume=auto` skips it) is recorded again, which evaluates only what its
record lacks, so a record interrupted by the session's end is completed by the next call;
unless the run folder's RECORDED says this very command completed the record of this very
finish (its DONE) and the record is still there: then nothing is started (a relaunch of a
15-job table would otherwise start a process per finished job to find nothing to do).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from analysis.records import RUN_FILE, trained_record
from epoet.core.files import atomic_write
from epoet.run_state import DONE

RECORDED = "RECORDED"  # in a run folder: the records command that completed, and the DONE it read


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
        stamp = json.dumps(
            {
                "command": command[1:],  # not the interpreter: a new venv records the same
                "done": hashlib.sha256((run_dir / DONE).read_bytes()).hexdigest(),
            }
        )
        record = self.out / trained_record(config.algo.name, config.seed)
        recorded = run_dir / RECORDED
        if (record / RUN_FILE).is_file() and recorded.is_file() and recorded.read_text() == stamp:
            print(f"[paper] {run_dir.name} is recorded in {record} already", flush=True)
            return
        print(f"[paper] recording {run_dir.name}: {' '.join(command[1:])}", flush=True)
        if (code := subprocess.run(command).returncode) != 0:
            print(
                f"[paper] recording {run_dir.name} stopped with exit code {code}; the next "
                f"call records it again",
                file=sys.stderr,
                flush=True,
            )
            return
        with atomic_write(recorded) as file:
            file.write(stamp.encode())
