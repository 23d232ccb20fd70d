"""What every evaluation backend shares: the `Evaluator` protocol, one call's jobs and results,
and surviving a lost worker.

A call runs a list of requests, each a population of episodes on one terrain: every pair's ES
episodes of an iteration go out as one call, then every evaluation as another, so no worker waits
at a per-pair barrier. A worker gets every request's terrain and population description once per
call and (request, episode) items one at a time, and sends back returns (and transitions if asked
for); parameter vectors per sample never travel. An episode's result is a function of its
parameters, spawn seed and terrain only, hence identical for any worker count, batch size or
scheduling. A worker that dies (killed, out of memory) is a lost worker: the backend restarts its
workers and runs the call again, which gives the same results.
"""

from __future__ import annotations

import itertools
import sys
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from typing import NamedTuple, Protocol

import numpy as np

from epoet.envs.config import AgentConfig
from epoet.rollout.engine import Episodes, Job, merge_episodes
from epoet.rollout.policy import num_params
from epoet.rollout.populations import Population, Request

# How many times one call may lose a worker before the run gives up (a worker that dies on every
# try is a bug or a machine without memory, not bad luck).
MAX_RESTARTS = 3


class WorkerLost(Exception):
    """A rollout worker died during a call; its backend can restart its workers."""


class WorkersGone(RuntimeError):
    """The workers cannot be brought back (they died `MAX_RESTARTS` times in one call, or the
    cluster they ran on is gone): the run checkpoints and stops (epoet/driver.py)."""


class Relief(NamedTuple):
    """What a worker needs of a terrain: plain arrays, whatever the caller's terrain type is
    (a Terrain's CPPN genome, say, is neither needed nor shipped)."""

    heightmap: np.ndarray
    max_height: float
    size: float


def reliefs_of(requests: Sequence[Request]) -> list[Relief]:
    """The requests' terrains as the plain arrays a worker needs."""
    return [
        Relief(np.asarray(r.terrain.heightmap), float(r.terrain.max_height), float(r.terrain.size))
        for r in requests
    ]


class Evaluator(Protocol):
    """Runs populations of episodes, one terrain each, many per call (see `make_evaluator`)."""

    workers: int
    restarts: int  # worker losses survived so far (each restarted the workers)
    layer_sizes: tuple[int, ...]  # the policy's: the robot's observations ... its actions
    agent: AgentConfig  # the robot and physics its episodes run, as agent files record them

    def run(self, requests: Sequence[Request]) -> list[Episodes]: ...

    def close(self) -> None: ...

    def __enter__(self) -> "Evaluator": ...

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None: ...


class Backend(ABC):
    """The public calls shared by both backends; `_run` runs the episodes."""

    workers: int

    def __init__(self, agent: AgentConfig, layer_sizes: Sequence[int]) -> None:
        self.layer_sizes = tuple(int(n) for n in layer_sizes)
        self.agent = agent
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
                    raise WorkersGone(
                        f"rollout workers died {attempt} times in one call ({lost}); giving up"
                    ) from lost
                print(
                    f"[workers] {lost}: restarting the workers and running the call again "
                    f"(restart {attempt}/{MAX_RESTARTS})",
                    file=sys.stderr,
                    flush=True,
                )
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
                raise ValueError(
                    f"populations must have {self.num_params} parameters per "
                    f"agent, got {r.population.num_params}."
                )
            if not len(r.population):
                raise ValueError("every request needs at least one episode.")
        if not requests:
            return []
        return [
            Episodes(
                e.returns.reshape(r.population.shape),
                e.lengths.reshape(r.population.shape),
                e.finished.reshape(r.population.shape),
                e.transitions,
            )
            for r, e in zip(requests, self._run_surviving(requests))
        ]

    def __enter__(self) -> "Backend":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release resources (the serial backend holds none)."""


def engine_jobs(
    items: Iterator[tuple[int, int]], populations: Sequence[Population], records: Sequence[int]
) -> Iterator[Job]:
    """Engine jobs for (request, episode) items, on the request's terrain; the engine's episode
    index packs both (`_encode`), so results can be split back per request."""
    for k, e in items:
        params, seed = populations[k].job(e)
        yield _encode(k, e), params, seed, k, e < records[k]


# An engine job's index packs (request, episode): the request in the high bits.
_SHIFT = 32


def _encode(request: int, episode: int) -> int:
    return (request << _SHIFT) | episode


def split_results(
    parts: Sequence[tuple[np.ndarray, Episodes]], sizes: Sequence[int]
) -> list[Episodes]:
    """Per-request `Episodes` from engine results (from one or several workers) whose indices
    are `_encode`d."""
    mask = (1 << _SHIFT) - 1
    out = []
    for k, n in enumerate(sizes):
        mine = []
        for index, episodes in parts:
            rows = (index >> _SHIFT) == k
            part = Episodes(episodes.returns[rows], episodes.lengths[rows], episodes.finished[rows])
            t = episodes.transitions
            keep = None if t is None else (t["episode"] >> _SHIFT) == k
            if t is not None and keep is not None and keep.any():
                part.transitions = {
                    **{key: v[keep] for key, v in t.items()},
                    "episode": t["episode"][keep] & mask,
                }
            mine.append((index[rows] & mask, part))
        out.append(merge_episodes(mine, n))
    return out
