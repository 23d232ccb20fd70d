"""workers=ray, the run's side: `RayEvaluator`, whose Ray driver lives in a child process (the
Ray host), so that no Ray process's death ends the run.

Ray ends its driver process outright when the local cluster's raylet dies (measured: the
process exits with code 1, no Python exception, no `finally`), so a run that were its own Ray
driver could not even save a checkpoint. Here the run's process sends each call's requests to
the host over a pipe and gets the episodes back; the host drives the actors
(ray_cluster.py `RayActors`). What can die, and what happens:

- a rollout actor or the feed: the host replaces every actor and the call runs again;
- the host itself, or the local cluster under it (raylet, GCS; Ray then ends the host, at its
  heartbeat timeout, unless the host finds its raylet gone first): a new host starts (a new
  local Ray, or rejoins `address`) and the call runs again;
- more losses in one call than `MAX_RESTARTS`, or a host that cannot start (the remote cluster
  gone): `WorkersGone`, which the driver turns into a checkpoint at the last step's end, one
  line with the resume command and a non-zero exit.

A call's results do not depend on which workers ran it, so every recovery gives the results an
uninterrupted run gets.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

from epoet.core.environ import environ_defaults
from epoet.core.lifecycle import end_with, ignore_stop_signals
from epoet.core.schema import ConfigError
from epoet.envs.config import AgentConfig
from epoet.rollout.backends.base import Backend, WorkerLost, WorkersGone
from epoet.rollout.backends.ray_cluster import check_address
from epoet.rollout.engine import Episodes
from epoet.rollout.populations import Request
from epoet.terrain.config import TerrainConfig

# What the host sends back: ("ready", facts), ("done", episodes), ("lost", why), ("error", why)
READY, DONE, LOST, ERROR = "ready", "done", "lost", "error"
RESTART = "restart"  # what the run's process sends, besides a call's requests and None (stop)
# A host joins its cluster (or starts a local Ray) in seconds; one that has not answered by then
# hangs on a cluster that is not there.
HOST_START_SECONDS = 180.0
# A host that rejoins after a loss finds the cluster's GCS still answering (`ray stop` takes
# seconds) but this machine's raylet gone: `ray.init` then waits for a raylet here for Ray's GCS
# request timeout, 60 s (measured: 57 s in each of 3 runs of the lost-cluster test). Rejoining,
# 10 s; Ray reads it at import, in the host.
REJOIN_ENV = {"RAY_gcs_server_request_timeout_seconds": "10"}


def _host(conn: Connection, main_pid: int, args: tuple[Any, ...]) -> None:
    """The Ray host process: the Ray driver; it serves calls until told to stop or the run ends."""
    from epoet.rollout.backends.ray_cluster import RayActors

    ignore_stop_signals()  # the run's process decides when to stop
    end_with(main_pid)
    try:
        actors = RayActors(*args)
    except Exception as exc:  # noqa: BLE001 - told to the run's process, in one line
        conn.send((ERROR, f"{type(exc).__name__}: {exc}"))
        return
    conn.send(
        (READY, {"workers": actors.workers, "feed_pid": actors.feed_pid, "pids": actors.pids,
                 "batches": actors.engine_batches()})
    )  # fmt: skip
    try:
        while (message := conn.recv()) is not None:
            try:
                if message == RESTART:
                    if actors.lost_local_raylet():  # end now, as Ray would at its timeout
                        conn.send((LOST, "the local Ray's raylet died"))
                        os._exit(1)  # no `finally`: Ray's shutdown would wait on the raylet
                    actors.restart()
                    conn.send((READY, {"feed_pid": actors.feed_pid, "pids": actors.pids}))
                else:
                    conn.send((DONE, actors.run(message)))
            except WorkerLost as lost:
                conn.send((LOST, str(lost)))
    finally:
        actors.close()


class RayEvaluator(Backend):
    """Rollout actors on a Ray cluster, driven from the Ray host process (module docstring);
    `workers` actors (None: one per CPU of the cluster)."""

    def __init__(
        self,
        agent: AgentConfig,
        terrain_cfg: TerrainConfig,
        workers: int | None,
        batch: int,
        layer_sizes: Sequence[int],
        address: str | None = None,
    ) -> None:
        super().__init__(agent, layer_sizes)
        self.batch = int(batch)
        self.address = address
        self._args = (agent, terrain_cfg, workers, self.batch, tuple(layer_sizes), address)
        self._ctx = mp.get_context("spawn")  # a fresh interpreter: no threads of this process
        self._process: Any = None
        self._conn: Connection | None = None
        self._start_host()

    def _start_host(self) -> None:
        """A new Ray host, its actors ready: their processes' ids in `feed_pid` and `pids`."""
        rejoined = self.address if self._process is not None else None  # a cluster, again
        if rejoined is not None:  # is it there?
            try:
                check_address(rejoined)  # seconds, where `ray.init` would wait minutes
            except ConfigError as gone:
                raise WorkersGone(str(gone).rstrip(".")) from None
        ours, theirs = self._ctx.Pipe()
        self._process = self._ctx.Process(
            target=_host, args=(theirs, os.getpid(), self._args), name="epoet-ray-host"
        )
        with environ_defaults(REJOIN_ENV if rejoined else {}):  # the host inherits os.environ
            self._process.start()
        theirs.close()
        self._conn = ours
        if not ours.poll(HOST_START_SECONDS):
            self._stop_host()
            raise WorkersGone(f"the Ray host did not start in {HOST_START_SECONDS:.0f} s")
        kind, facts = self._receive()
        if kind != READY:
            self._stop_host()
            raise WorkersGone(f"the Ray host could not start: {facts}")
        self.workers = int(facts["workers"])
        self.engine_batches: list[int] = facts["batches"]
        self._ready(facts)

    def _ready(self, facts: dict[str, Any]) -> None:
        self.feed_pid, self.pids = int(facts["feed_pid"]), [int(p) for p in facts["pids"]]
        self.host_pid = int(self._process.pid)

    def _receive(self) -> tuple[str, Any]:
        """The host's answer; a host that died answers ("lost", why)."""
        assert self._conn is not None  # a host is running
        try:
            return self._conn.recv()
        except (EOFError, OSError):
            self._process.join(timeout=5)
            return LOST, f"the Ray host died (exit code {self._process.exitcode})"

    def _run(self, requests: Sequence[Request]) -> list[Episodes]:
        if self._conn is None:
            raise RuntimeError("this evaluator is closed.")
        try:
            self._conn.send(list(requests))
        except OSError:  # the host is gone: its answer says so
            pass
        kind, answer = self._receive()
        if kind == DONE:
            return answer
        if kind == LOST:
            raise WorkerLost(answer)
        raise RuntimeError(f"the Ray host failed: {answer}")

    def _restart(self) -> None:
        """Every actor anew (the host's job), or a new host when the old one is gone."""
        if self._process.is_alive():
            assert self._conn is not None  # a host is running
            self._conn.send(RESTART)
            kind, facts = self._receive()
            if kind == READY:
                self._ready(facts)
                return
        self._stop_host()
        self._start_host()

    def _stop_host(self) -> None:
        if self._conn is not None:
            try:
                self._conn.send(None)
            except OSError:
                pass
            self._conn.close()
            self._conn = None
        if self._process is not None:
            self._process.join(timeout=30)
            if self._process.is_alive():
                self._process.kill()
                self._process.join()

    def close(self) -> None:
        """Stop the host, its actors and the local Ray it started (idempotent)."""
        self._stop_host()
