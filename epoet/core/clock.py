"""CPU seconds of a run's own processes: the clock `budget.cpu_hours` counts.

Wall time bends with the machine's load (runs at load 6-9 made a fifth fewer iterations than
quiet ones in the same hours); the CPU time of the run's processes -- the main process with its
threads, its worker processes and anything they started, alive or already reaped -- does not, so
runs compared at equal CPU time had equal compute whatever else the machine ran.
"""

from __future__ import annotations

import psutil


def process_tree_cpu() -> float:
    """User + system CPU seconds of this process, its reaped children and its live
    descendants."""
    me = psutil.Process()
    times = me.cpu_times()
    total = times.user + times.system + times.children_user + times.children_system
    for child in me.children(recursive=True):
        try:
            child_times = child.cpu_times()
        except psutil.Error:  # it ended between the listing and the read: reaped, counted above
            continue
        total += child_times.user + child_times.system
    return total


class CpuMeter:
    """CPU seconds of the process tree between successive `lap()` calls, so a loop adds each
    iteration's share (its steps, evaluations, checkpoint and logging) to a total it
    checkpoints."""

    def __init__(self) -> None:
        self._last = process_tree_cpu()

    def lap(self) -> float:
        """CPU seconds since the meter was made or last lapped."""
        now = process_tree_cpu()
        spent, self._last = now - self._last, now
        return max(spent, 0.0)  # a worker's time vanishes if it dies unreaped: never negative
