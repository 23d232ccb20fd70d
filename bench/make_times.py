"""How long the README's two commands take, and what `make train` ends with: the timing record
the README's times come from (bench/make_times.json).

Each target runs in a fresh clone of the commit, as a user runs it, with this environment's
venv in place of the clone's own (`make -o .venv/.installed`: the install step, which needs the
package registry, is not timed and the venv's editable install keeps pointing where it did).
The record keeps the date, commit, machine, wall-clock seconds, the load, the command's exit
code and its last lines; for `make train` also the wall-clock second at which the open-ended
loop first admitted a child, first transferred and first had ANNECS above 1:

    python bench/make_times.py [--targets train,test] [--commit HEAD] [--out bench/make_times.json]

Times need a quiet machine: the record says the load it ran under.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

from epoet.eval.reference.files import ENV, MissingReferenceFiles, source

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "bench" / "make_times.json"
TAIL = 12  # lines of each command's output kept in the record

# What ePOET's progress line shows (its runner's `[epoet] it N/M ... annecs=A`, then
# `admitted=K transfers=T` on the iterations that reproduce or transfer).
MILESTONES = {
    "first_admission": re.compile(r"\badmitted=[1-9]"),
    "first_transfer": re.compile(r"\btransfers=[1-9]"),
    "annecs_above_1": re.compile(r"\bannecs=([2-9]|\d\d+)\b"),
}


def machine() -> dict[str, object]:
    """What the times were measured on."""
    model = next(
        (
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        ),
        platform.processor(),
    )
    memory_kb = int(Path("/proc/meminfo").read_text().split()[1])
    return {
        "cpus": os.cpu_count(),
        "cpu": model,
        "memory_gib": round(memory_kb / 2**20, 1),
        "system": platform.platform(),
        "python": platform.python_version(),
    }


class LoadSampler(threading.Thread):
    """The 1-minute load average every few seconds while a command runs."""

    def __init__(self, every: float = 5.0) -> None:
        super().__init__(daemon=True)
        self.every, self.samples, self.stopped = every, [os.getloadavg()[0]], threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(self.every):
            self.samples.append(os.getloadavg()[0])

    def summary(self) -> dict[str, float]:
        return {
            "mean": round(sum(self.samples) / len(self.samples), 2),
            "max": round(max(self.samples), 2),
        }


def clone(commit: str, into: Path) -> str:
    """A fresh clone of `commit` with this venv linked in; the full commit hash."""
    subprocess.run(["git", "clone", "-q", str(ROOT), str(into)], check=True)
    subprocess.run(["git", "-C", str(into), "checkout", "-q", commit], check=True)
    (into / ".venv").symlink_to(Path(sys.prefix))
    return subprocess.run(
        ["git", "-C", str(into), "rev-parse", "HEAD"], check=True, capture_output=True, text=True
    ).stdout.strip()


def clone_environment(checkout: Path) -> dict[str, str]:
    """This environment with the checkout's code first on PYTHONPATH, EPOET_3D naming the
    authors' files it reads (a clone elsewhere has no `../shared/ePOET_3D` beside it, and
    `make test` needs them: README), and EPOET_MAKE_TIMES, which tells the timing record's own
    age check that it is being remade.

    PYTHONPATH: the linked venv holds this repository as an editable install, which a process
    started outside the checkout (a test's `python -m epoet` in its tmp folder) would import
    instead, so a clone of another commit would time this working tree's code."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(checkout), os.environ.get("PYTHONPATH")])),
        "EPOET_MAKE_TIMES": "1",  # tests/test_doc_facts.py: the record comes after
    }
    try:
        folder = source()
    except MissingReferenceFiles:
        return env  # the tests that need them say so
    return {**env, ENV: str(folder.resolve())}


def time_target(target: str, cwd: Path) -> dict[str, object]:
    """Run `make <target>` in `cwd`; its wall time, load, exit code, milestones and tail. (No
    CPU time: the run's worker processes are not the command's waited children, so rusage
    misses them; a training run reports its own CPU time in its last lines.)"""
    load = LoadSampler()
    start = time.perf_counter()
    load.start()
    process = subprocess.Popen(
        ["make", "-o", ".venv/.installed", target],
        cwd=cwd,
        env=clone_environment(cwd),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # its own process group, ended with the bench however it ends
    )
    assert process.stdout is not None
    lines: list[str] = []
    milestones: dict[str, float | None] = dict.fromkeys(MILESTONES)
    try:
        for line in process.stdout:
            print(line, end="", flush=True)
            lines.append(line.rstrip("\n"))
            for name, pattern in MILESTONES.items():
                if milestones[name] is None and pattern.search(line):
                    milestones[name] = round(time.perf_counter() - start, 1)
        code = process.wait()
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    wall = time.perf_counter() - start
    load.stopped.set()
    record: dict[str, object] = {
        "command": f"make {target}",
        "exit_code": code,
        "wall_s": round(wall, 1),
        "load1": load.summary(),
        "tail": lines[-TAIL:],
    }
    if target == "train":
        record["milestones_s"] = milestones
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--targets",
        default="train,test",
        help="Makefile targets to time, comma-separated (default: train,test)",
    )
    parser.add_argument("--commit", default="HEAD", help="the commit to clone (default: HEAD)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"the record (default: {OUT})")
    args = parser.parse_args()
    # One entry per target, each with its own date and commit: timing `test` again keeps the
    # last `train`.
    record = json.loads(args.out.read_text(encoding="utf-8")) if args.out.exists() else {}
    for target in (t for t in args.targets.split(",") if t):
        with tempfile.TemporaryDirectory(prefix=f"make_{target}_") as folder:
            checkout = Path(folder) / "epoet"
            entry: dict[str, object] = {
                "date": datetime.now(UTC).isoformat(timespec="seconds"),
                "commit": clone(args.commit, checkout),
                "machine": machine(),
                "install": "not timed: an installed venv (make -o .venv/.installed)",
            }
            entry.update(time_target(target, checkout))
        record[target] = entry
        print(f"make {target}: {entry['wall_s']} s, exit {entry['exit_code']}", flush=True)
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
        tmp.replace(args.out)  # atomic: the record is whole, old or new
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
