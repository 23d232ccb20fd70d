"""Counting a run's processes from outside it (tests/test_faults.py, bench/fault_soak.py)."""

from __future__ import annotations

from pathlib import Path


def processes_with_env(name: str, value: str) -> list[int]:
    """Live processes whose environment has name=value: a run's whole process tree when the run
    was started with a marker variable (how tests and bench/fault_soak.py count orphans)."""
    marker = f"{name}={value}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            environ = (entry / "environ").read_bytes()
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:  # gone meanwhile, or not ours to read
            continue
        if marker in environ.split(b"\0") and state != "Z":
            found.append(int(entry.name))
    return found
