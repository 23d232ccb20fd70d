"""A local process pool, one `RolloutEngine` per process, episodes shared out one by one.

Load balancing is per episode: every worker's engine pulls the next (request, episode) item from
a shared queue as a slot frees up, whichever request it belongs to (the engine holds every
terrain of the call), so a worker is busy until the queue is empty.

Processes start with "forkserver" (fork after torch/OpenMP threads exist can deadlock); each
builds its engine once in the pool initializer and ends with the main process
(`epoet.core.lifecycle`).
A worker exception is re-raised in the parent (the pool stays usable: the queue items of a failed
call are tagged with its call number and skipped later).
"""

from __future__ import annotations

import itertools
import math
import multiprocessing as mp
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.queues import Queue
from typing import TypeVar

import numpy as np

from epoet.core.lifecycle import end_with, ignore_stop_signals
from epoet.envs.config import AgentConfig
from epoet.rollout.backends.base import (
    Backend,
    Relief,
    WorkerLost,
    engine_jobs,
    reliefs_of,
    split_results,
)
from epoet.rollout.engine import Episodes, RolloutEngine
from epoet.rollout.populations import Population, Request
from epoet.terrain.config import TerrainConfig

T = TypeVar("T")

_engine: RolloutEngine | None = None  # this worker process's engine, built by _init_worker
_queue: Queue | None = None  # episode indices of the current call, shared by workers


def _init_worker(
    agent: AgentConfig,
    terrain_cfg: TerrainConfig,
    batch: int,
    layer_sizes: tuple[int, ...],
    queue: Queue,
    main_pid: int,
) -> None:
    global _engine, _queue
    ignore_stop_signals()
    end_with(main_pid)
    _engine = RolloutEngine(agent, terrain_cfg, batch, layer_sizes)
    _queue = queue


def _items(call: int) -> Iterator[tuple[int, int]]:
    """This call's (request, episode) items from the shared queue, up to one end marker."""
    assert _queue is not None  # set by _init_worker
    while True:
        tag, request, index = _queue.get()
        if tag != call:
            continue  # left over from an earlier call that failed part-way
        if request is None:
            return
        yield request, index


def _work(
    call: int,
    reliefs: Sequence[Relief],
    populations: Sequence[Population],
    records: Sequence[int],
    slots: int,
) -> tuple[np.ndarray, Episodes]:
    """Run this call's queue items until the end marker: (encoded indices, results)."""
    assert _engine is not None  # built by _init_worker
    _engine.set_terrains(reliefs)
    return _engine.run_jobs(engine_jobs(_items(call), populations, records), slots=slots)


def fair_slots(batch: int, episodes: int, workers: int) -> int:
    """Slots a worker fills at first: at most its fair share, so none hoards the queue."""
    return min(batch, math.ceil(episodes / workers))


class PoolEvaluator(Backend):
    """A local process pool, one RolloutEngine per process; episodes are shared out one by one."""

    def __init__(
        self,
        agent: AgentConfig,
        terrain_cfg: TerrainConfig,
        workers: int,
        batch: int,
        layer_sizes: Sequence[int],
    ) -> None:
        super().__init__(agent, layer_sizes)
        if workers < 2:
            raise ValueError(f"a process pool needs workers >= 2, got {workers}.")
        self.workers = int(workers)
        self.batch = int(batch)
        self._ctx = mp.get_context("forkserver")
        # The fork server imports this module (numpy, MuJoCo, the engine) once; each worker is
        # then a cheap fork of it (~0.05 s instead of ~0.5 s of imports per process).
        self._ctx.set_forkserver_preload([__name__])
        self._initargs = (agent, terrain_cfg, self.batch, tuple(layer_sizes))
        self._calls = itertools.count()
        self._pool: ProcessPoolExecutor | None = None
        self._start()

    def _start(self) -> None:
        # A fresh queue each time: a worker killed while reading may leave the old one's lock held.
        self._queue = self._ctx.Queue()
        self._pool = ProcessPoolExecutor(
            self.workers,
            mp_context=self._ctx,
            initializer=_init_worker,
            initargs=(*self._initargs, self._queue, os.getpid()),
        )
        # Start every worker now (the pool spawns lazily), so start-up is paid here, once.
        self._submit_all(os.getpid)

    def _restart(self) -> None:
        self.close()
        self._start()

    def _submit_all(self, fn: Callable[..., T], *args: object) -> list[T]:
        """Run fn(*args) as one task per worker; all must end before any error is raised, so no
        task of this call is still reading the queue when the next call starts."""
        if self._pool is None:
            raise RuntimeError("this evaluator is closed.")
        try:
            futures = [self._pool.submit(fn, *args) for _ in range(self.workers)]
            wait(futures)
            return [f.result() for f in futures]
        except BrokenProcessPool as err:
            # The broken executor terminates the other workers with SIGTERM, which they ignore
            # (epoet.core.lifecycle), then joins them: kill them, so that join returns. (It closes
            # its task pipe's read end itself, gh-94777; closing it here too raced that close.)
            self._kill_workers()
            raise WorkerLost("a rollout worker process died") from err

    def _run(self, requests: Sequence[Request]) -> list[Episodes]:
        if self._pool is None:
            raise RuntimeError("this evaluator is closed.")
        call = next(self._calls)
        sizes = [len(r.population) for r in requests]
        for request, n in enumerate(sizes):
            for e in range(n):
                self._queue.put((call, request, e))
        for _ in range(self.workers):
            self._queue.put((call, None, None))
        slots = fair_slots(self.batch, sum(sizes), self.workers)
        return split_results(
            self._submit_all(
                _work,
                call,
                reliefs_of(requests),
                [r.population for r in requests],
                [r.record for r in requests],
                slots,
            ),
            sizes,
        )

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is not None and self._pool is not None:
            # Interrupted or failed mid-call: stop the workers now rather than letting them
            # finish an ES step nobody will read.
            self._kill_workers()
        self.close()

    def _kill_workers(self) -> None:
        """SIGKILL every worker (ProcessPoolExecutor has no public terminate before Python
        3.14, and its terminate sends the SIGTERM workers ignore)."""
        assert self._pool is not None
        for process in list((self._pool._processes or {}).values()):
            process.kill()

    def close(self) -> None:
        """Stop the worker processes (idempotent)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            # Items a failed call left behind may never be read: do not wait to flush them.
            self._queue.cancel_join_thread()
            self._queue.close()
