"""Evaluation backends: the same episodes run in-process (workers=1) or over a local process pool.

A call runs a list of requests, each a population of episodes on one terrain: every pair's ES
episodes of an iteration go out as one call, then every evaluation as another, so no worker waits
at a per-pair barrier. What crosses process boundaries is small: per call, each worker gets every
request's terrain and population *description* once (theta, sigma and integer noise seeds for an
ES step; the K agents' parameter vectors for an evaluation), and (request, episode) indices one at
a time from a shared queue; it rebuilds theta +- sigma * noise(seed) itself and sends back returns
(and transitions if asked for). Parameter vectors per sample never travel.

Load balancing is per episode: every worker runs one `RolloutEngine` whose free slots pull the next
episode from the shared queue, whichever request it belongs to (the engine holds every terrain
of the call), so a worker is busy until the queue is empty. An episode's result is a function of
its parameters, spawn seed and terrain only, hence identical for any worker count, batch size or
scheduling.

Processes start with "forkserver" (fork after torch/OpenMP threads exist can deadlock); each
builds its engine once in the pool initializer and ends with the main process (`epoet.lifecycle`).
A worker exception is re-raised in the parent (the pool stays usable: the queue items of a failed
call are tagged with its call number and skipped later). A worker that dies (killed, out of memory)
is a lost worker: the backend restarts its workers and runs the call again, which gives the same
results, since an episode's result does not depend on the worker that runs it. `workers=ray` is
the same design on a Ray cluster (`epoet.es.ray_workers`).
"""
from __future__ import annotations

import itertools
import math
import multiprocessing as mp
import os
import sys
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing.queues import Queue
from typing import NamedTuple, Protocol, TypeVar

import numpy as np

from epoet.config import AgentConfig, TerrainConfig, WorkersConfig
from epoet.es.obs_norm import Standardizer
from epoet.es.optimizer import mirrored_population
from epoet.es.policy import LAYER_SIZES, num_params
from epoet.es.rollout import (DEFAULT_BATCH, Episodes, Job, RolloutEngine, TerrainLike,
                              check_seeds, merge_episodes)
from epoet.lifecycle import end_with, ignore_stop_signals

# How many times one call may lose a worker before the run gives up (a worker that dies on every
# try is a bug or a machine without memory, not bad luck).
MAX_RESTARTS = 3


class WorkerLost(Exception):
    """A rollout worker died during a call; its backend can restart its workers."""


class _Relief(NamedTuple):
    """What a worker needs of a terrain: plain arrays, whatever the caller's terrain type is
    (a Terrain's CPPN genome, say, is neither needed nor shipped)."""

    heightmap: np.ndarray
    max_height: float
    size: float


class Population(Protocol):
    """A numbered set of episodes whose parameters are rebuilt on demand from a compact form."""

    num_params: int
    shape: tuple[int, ...]      # how the episodes' results are arranged for the caller

    def __len__(self) -> int: ...

    def job(self, e: int) -> tuple[np.ndarray, int]:
        """(policy parameters, spawn seed) of episode e."""
        ...


@dataclass(frozen=True)
class Mirrored:
    """2n ES episodes in `mirrored_population` order: e < n is theta + sigma*eps_e, e >= n is
    theta - sigma*eps_(e-n); pair i's two episodes share spawn_seeds[i] (common random numbers)."""

    theta: np.ndarray
    sigma: float
    noise_seeds: np.ndarray
    spawn_seeds: np.ndarray
    standardizer: Standardizer | None = None  # theta acts on standardised observations

    @classmethod
    def of(cls, theta: np.ndarray, noise_seeds: np.ndarray, sigma: float,
           spawn_seeds: np.ndarray, standardizer: Standardizer | None = None) -> "Mirrored":
        """The checked population of one ES step around `theta`."""
        theta = np.asarray(theta, dtype=np.float64)
        noise = check_seeds(noise_seeds, "noise_seeds")
        spawn = check_seeds(spawn_seeds, "spawn_seeds")
        if theta.ndim != 1 or not theta.size:
            raise ValueError(f"theta must be a non-empty 1-D vector, got shape {theta.shape}.")
        if noise.ndim != 1 or not len(noise):
            raise ValueError(f"noise_seeds must be a non-empty 1-D array, got {noise.shape}.")
        if spawn.shape != noise.shape:
            raise ValueError(f"spawn_seeds must have one seed per noise seed {noise.shape}, got "
                             f"{spawn.shape}.")
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}.")
        return cls(theta, float(sigma), noise, spawn, standardizer)

    @property
    def num_params(self) -> int:
        return self.theta.size

    @property
    def shape(self) -> tuple[int, ...]:
        return (len(self),)

    def __len__(self) -> int:
        return 2 * len(self.noise_seeds)

    def job(self, e: int) -> tuple[np.ndarray, int]:
        n = len(self.noise_seeds)
        # The pair through `mirrored_population` itself: bit-identical to its rows e and n + e.
        pair = mirrored_population(self.theta, self.noise_seeds[e % n:e % n + 1], self.sigma)
        params = pair[e // n]
        if self.standardizer is not None:
            params = self.standardizer.fold(params)
        return params, int(self.spawn_seeds[e % n])


@dataclass(frozen=True)
class Agents:
    """K agents times n episodes each; episode e = k * n + j is agent k with spawn_seeds[k, j]."""

    thetas: np.ndarray       # (K, P)
    spawn_seeds: np.ndarray  # (K, n)

    @classmethod
    def of(cls, thetas: np.ndarray, spawn_seeds: np.ndarray) -> "Agents":
        """K agents' episodes: `spawn_seeds` (n,) gives all the same starts, (K, n) each its own."""
        thetas = np.asarray(thetas, dtype=np.float64)
        seeds = check_seeds(spawn_seeds, "spawn_seeds")
        if thetas.ndim != 2 or not thetas.size:
            raise ValueError(f"thetas must have shape (K, P) with K, P >= 1, got "
                             f"{thetas.shape}.")
        k = len(thetas)
        if seeds.ndim == 1:
            seeds = np.broadcast_to(seeds, (k, len(seeds)))
        if seeds.ndim != 2 or seeds.shape[0] != k or not seeds.shape[1]:
            raise ValueError(f"spawn_seeds must have shape (n,) or ({k}, n) with n >= 1, got "
                             f"{np.shape(spawn_seeds)}.")
        return cls(thetas, np.ascontiguousarray(seeds))

    @property
    def num_params(self) -> int:
        return self.thetas.shape[1]

    @property
    def shape(self) -> tuple[int, ...]:
        return self.spawn_seeds.shape

    def __len__(self) -> int:
        return self.spawn_seeds.size

    def job(self, e: int) -> tuple[np.ndarray, int]:
        return self.thetas[e // self.spawn_seeds.shape[1]], int(self.spawn_seeds.flat[e])


class Request(NamedTuple):
    """A population of episodes on one terrain: the unit of work a call is made of.

    The transitions of its first `record` episodes (population order) are recorded, so a
    learner can take a bounded share of an ES step's experience (ePOET-SAC's shared replay).
    """

    terrain: TerrainLike
    population: Population
    record: int = 0


class Evaluator(Protocol):
    """Runs populations of episodes, one terrain each, many per call (see `make_evaluator`)."""

    workers: int
    restarts: int       # worker losses survived so far (each restarted the workers)

    def run(self, requests: Sequence[Request]) -> list[Episodes]: ...

    def close(self) -> None: ...

    def __enter__(self) -> "Evaluator": ...

    def __exit__(self, *exc: object) -> None: ...


T = TypeVar("T")


class _Backend(ABC):
    """The public calls shared by both backends; `_run` runs the episodes."""

    workers: int

    def __init__(self, layer_sizes: Sequence[int]) -> None:
        self.num_params = num_params(layer_sizes)
        self.restarts = 0

    @abstractmethod
    def _run(self, requests: Sequence[Request]) -> list[Episodes]:
        """All episodes of every request, one flat `Episodes` per request in population order;
        each request's first `record` episodes recorded. Raises `WorkerLost` if a worker died."""

    def _restart(self) -> None:
        """Replace the workers after a `WorkerLost` (backends without workers never lose one)."""
        raise RuntimeError(f"{type(self).__name__} has no workers to restart.")

    def _run_surviving(self, requests: Sequence[Request]) -> list[Episodes]:
        """`_run`, restarting the workers and running the call again when one dies."""
        for attempt in itertools.count(1):
            try:
                return self._run(requests)
            except WorkerLost as lost:
                if attempt > MAX_RESTARTS:
                    self.close()
                    raise RuntimeError(f"rollout workers died {attempt} times in one call "
                                       f"({lost}); giving up.") from lost
                print(f"[workers] {lost}: restarting the workers and running the call again "
                      f"(restart {attempt}/{MAX_RESTARTS})", file=sys.stderr, flush=True)
                self.restarts += 1
                self._restart()
        raise AssertionError("unreachable")

    def run(self, requests: Sequence[Request]) -> list[Episodes]:
        """Every request's episodes in one call; results shaped as each `population.shape`.

        Each request's first `request.record` episodes are recorded. Transitions stay flat per
        request, their `episode` the flat index; a request with none recorded has `transitions`
        None.
        """
        requests = [Request(*r) for r in requests]
        for r in requests:
            if r.population.num_params != self.num_params:
                raise ValueError(f"populations must have {self.num_params} parameters per "
                                 f"agent, got {r.population.num_params}.")
            if not len(r.population):
                raise ValueError("every request needs at least one episode.")
        if not requests:
            return []
        return [Episodes(e.returns.reshape(r.population.shape),
                         e.lengths.reshape(r.population.shape),
                         e.finished.reshape(r.population.shape), e.transitions)
                for r, e in zip(requests, self._run_surviving(requests))]

    def __enter__(self) -> "_Backend":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release resources (the serial backend holds none)."""


class SerialEvaluator(_Backend):
    """workers=1: one engine in this process; no start-up cost, nothing to pickle."""

    workers = 1

    def __init__(self, agent: AgentConfig, terrain_cfg: TerrainConfig, batch: int = DEFAULT_BATCH,
                 layer_sizes: Sequence[int] = LAYER_SIZES) -> None:
        super().__init__(layer_sizes)
        self.engine = RolloutEngine(agent, terrain_cfg, batch, layer_sizes)

    def _run(self, requests: Sequence[Request]) -> list[Episodes]:
        self.engine.set_terrains([r.terrain for r in requests])
        items = [(k, e) for k, r in enumerate(requests) for e in range(len(r.population))]
        part = self.engine.run_jobs(_jobs(iter(items), [r.population for r in requests],
                                          [r.record for r in requests]))
        return _split([part], [len(r.population) for r in requests])


def _jobs(items: Iterator[tuple[int, int]], populations: Sequence[Population],
          records: Sequence[int]) -> Iterator[Job]:
    """Engine jobs for (request, episode) items, on the request's terrain; the engine's episode
    index packs both (`_encode`), so results can be split back per request."""
    for k, e in items:
        params, seed = populations[k].job(e)
        yield _encode(k, e), params, seed, k, e < records[k]


# An engine job's index packs (request, episode): the request in the high bits.
_SHIFT = 32


def _encode(request: int, episode: int) -> int:
    return (request << _SHIFT) | episode


def _split(parts: Sequence[tuple[np.ndarray, Episodes]], sizes: Sequence[int]
           ) -> list[Episodes]:
    """Per-request `Episodes` from engine results (from one or several workers) whose indices
    are `_encode`d."""
    mask = (1 << _SHIFT) - 1
    out = []
    for k, n in enumerate(sizes):
        mine = []
        for index, episodes in parts:
            rows = (index >> _SHIFT) == k
            part = Episodes(episodes.returns[rows], episodes.lengths[rows],
                            episodes.finished[rows])
            t = episodes.transitions
            keep = None if t is None else (t["episode"] >> _SHIFT) == k
            if keep is not None and keep.any():
                part.transitions = {**{key: v[keep] for key, v in t.items()},
                                    "episode": t["episode"][keep] & mask}
            mine.append((index[rows] & mask, part))
        out.append(merge_episodes(mine, n))
    return out


# ---------------------------------------------------------------- process pool

_engine: RolloutEngine | None = None  # this worker process's engine, built by _init_worker
_queue: Queue | None = None           # episode indices of the current call, shared by workers


def _init_worker(agent: AgentConfig, terrain_cfg: TerrainConfig, batch: int,
                 layer_sizes: tuple[int, ...], queue: Queue, main_pid: int) -> None:
    global _engine, _queue
    ignore_stop_signals()
    end_with(main_pid)
    _engine = RolloutEngine(agent, terrain_cfg, batch, layer_sizes)
    _queue = queue


def _items(call: int) -> Iterator[tuple[int, int]]:
    """This call's (request, episode) items from the shared queue, up to one end marker."""
    while True:
        tag, request, index = _queue.get()
        if tag != call:
            continue  # left over from an earlier call that failed part-way
        if request is None:
            return
        yield request, index


def _work(call: int, reliefs: Sequence[_Relief], populations: Sequence[Population],
          records: Sequence[int], slots: int) -> tuple[np.ndarray, Episodes]:
    """Run this call's queue items until the end marker: (encoded indices, results)."""
    _engine.set_terrains(reliefs)
    return _engine.run_jobs(_jobs(_items(call), populations, records), slots=slots)


def reliefs_of(requests: Sequence[Request]) -> list[_Relief]:
    """The requests' terrains as the plain arrays a worker needs."""
    return [_Relief(np.asarray(r.terrain.heightmap), float(r.terrain.max_height),
                    float(r.terrain.size)) for r in requests]


def fair_slots(batch: int, episodes: int, workers: int) -> int:
    """Slots a worker fills at first: at most its fair share, so none hoards the queue."""
    return min(batch, math.ceil(episodes / workers))


class PoolEvaluator(_Backend):
    """A local process pool, one RolloutEngine per process; episodes are shared out one by one."""

    def __init__(self, agent: AgentConfig, terrain_cfg: TerrainConfig, workers: int,
                 batch: int = DEFAULT_BATCH, layer_sizes: Sequence[int] = LAYER_SIZES) -> None:
        super().__init__(layer_sizes)
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
            self.workers, mp_context=self._ctx, initializer=_init_worker,
            initargs=(*self._initargs, self._queue, os.getpid()))
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
            # (epoet.lifecycle), then joins them: kill them, so that join returns. (It closes
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
        return _split(self._submit_all(_work, call, reliefs_of(requests),
                                       [r.population for r in requests],
                                       [r.record for r in requests], slots), sizes)

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is not None and self._pool is not None:
            # Interrupted or failed mid-call: stop the workers now rather than letting them
            # finish an ES step nobody will read.
            self._kill_workers()
        self.close()

    def _kill_workers(self) -> None:
        """SIGKILL every worker (ProcessPoolExecutor has no public terminate before Python
        3.14, and its terminate sends the SIGTERM workers ignore)."""
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


def default_workers() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0))


def make_evaluator(agent: AgentConfig, terrain_cfg: TerrainConfig, workers: int | str = "local",
                   batch: int = DEFAULT_BATCH, layer_sizes: Sequence[int] = LAYER_SIZES
                   ) -> Evaluator:
    """workers: 'local' (a pool with one process per core) or a count; 1 runs in-process."""
    if workers == "local":
        workers = default_workers()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be 'local' or an integer >= 1, got {workers!r}.")
    if workers == 1:
        return SerialEvaluator(agent, terrain_cfg, batch, layer_sizes)
    return PoolEvaluator(agent, terrain_cfg, workers, batch, layer_sizes)


def evaluator_for(workers: WorkersConfig, agent: AgentConfig, terrain_cfg: TerrainConfig,
                  layer_sizes: Sequence[int] = LAYER_SIZES) -> Evaluator:
    """The evaluator a run's `workers` config asks for."""
    if workers.backend == "ray":
        from epoet.es.ray_workers import RayEvaluator  # the optional extra, imported on demand
        return RayEvaluator(agent, terrain_cfg, workers.num, workers.batch, layer_sizes,
                            workers.address)
    return make_evaluator(agent, terrain_cfg, workers.num or "local", workers.batch, layer_sizes)
