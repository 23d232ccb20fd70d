"""How a run and the processes it starts end: together, and with a checkpoint when asked nicely.

- Workers end with the main process, whatever kills it (SIGKILL and the OOM killer included):
  each watches the main process through a pidfd and exits as soon as it is gone, so no rollout
  worker outlives its run (`end_with`). Workers ignore SIGINT and SIGTERM, which a terminal or
  SLURM sends to the whole process group: stopping is the main process's decision.
- The main process turns its first SIGINT or SIGTERM (Ctrl-C; SLURM's preemption) into a stop
  request that the runner honours at its next checkpoint boundary (an ES iteration, a collector
  batch): the run writes a checkpoint and exits with 128 + the signal, losing nothing
  (`StopOnSignal`). A second signal stops at once (KeyboardInterrupt), losing the step in
  progress.
"""

from __future__ import annotations

import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Stopped(Exception):
    """The run stopped after writing its checkpoint, to be resumed: on a signal (exit code
    128 + signal, `by_signal`) or because its workers are gone (`WORKERS_GONE`)."""

    WORKERS_GONE = 75  # sysexits.h EX_TEMPFAIL: a temporary failure, try again (resume) later

    def __init__(self, reason: str, exit_code: int) -> None:
        self.exit_code = exit_code
        super().__init__(reason)

    @classmethod
    def by_signal(cls, signum: int, where: str) -> Stopped:
        return cls(f"stopped by {signal.Signals(signum).name} {where}", 128 + signum)


class StopOnSignal:
    """While active, SIGINT and SIGTERM request a stop instead of killing the process.

    Runners ask `stop_requested()` at each checkpoint boundary; when it is true they write the
    checkpoint (due or not) and call `raise_if_stopped`. Outside the main thread (e.g. a
    launcher's worker thread) signals cannot be caught, and Python's defaults stay.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Callable[[int, FrameType | None], Any] | int | None] = {}

    def __enter__(self) -> StopOnSignal:
        global _active
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        _active = self
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        global _active
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        _active = None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt  # asked twice: stop now
        self.signum = signum
        print(
            f"\n[epoet] {signal.Signals(signum).name} received: stopping at the next "
            f"checkpoint boundary (send it again to stop at once)",
            file=sys.stderr,
            flush=True,
        )


_active: StopOnSignal | None = None  # the run's, while it trains


def stop_requested() -> bool:
    """Whether a signal asked the run to stop (write a checkpoint now, then `raise_if_stopped`)."""
    return _active is not None and _active.signum is not None


def raise_if_stopped(where: str) -> None:
    """Raise `Stopped` if a stop was requested; call it right after writing the checkpoint."""
    if _active is not None and _active.signum is not None:  # stop_requested(), narrowed
        raise Stopped.by_signal(_active.signum, where)


def ignore_stop_signals() -> None:
    """For worker processes: SIGINT and SIGTERM are the main process's to handle."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def end_with(pid: int) -> None:
    """Exit this process as soon as process `pid` ends (a daemon thread waits on its pidfd).

    The Linux parent-death signal would not do: pool workers are children of the fork server,
    not of the main process. Without pidfds (Linux < 5.3) the thread polls once a second.
    """
    try:
        fd = os.pidfd_open(pid)
    except (AttributeError, OSError):
        fd = None
    if fd is None and not _alive(pid):
        os._exit(1)

    def wait() -> None:
        if fd is not None:
            select.select([fd], [], [])
        else:
            while _alive(pid):
                time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=wait, name=f"end-with-{pid}", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
