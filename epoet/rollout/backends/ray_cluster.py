"""workers=ray, the cluster side: the rollout actors and their feed on a Ray cluster, for runs
that outgrow one machine. They are driven from the Ray host process (ray_host.py), never from
the run's own process.

The design is the local pool's (`epoet.rollout.backends.pool`), with Ray's processes and object
store:
- each Ray actor holds one `RolloutEngine`, built once;
- a call ships every request's terrain and population *description* once (`ray.put`, fetched once
  per node), and the (request, episode) items go into a feed actor that the rollout actors pull
  from as their slots free up, so load balances per episode across machines;
- results come back as (encoded indices, Episodes) parts and are split per request exactly as the
  pool's are, so for a seed the results equal `workers=local` (an episode's result depends on its
  parameters, spawn seed and terrain only).

Items are taken in guided chunks (a share of what is left, shrinking to one), so a remote actor
makes few round trips early and the tail still balances. An actor that dies (its node lost, the
process killed) raises `WorkerLost`; the backend replaces the dead actors and runs the call again.
`address` joins a running cluster (`ray start --head` on the head node); without it a local Ray
starts with the Ray host process and stops with it.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import socket
import subprocess
import sys
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import psutil

from epoet.core.schema import ConfigError
from epoet.envs.config import AgentConfig
from epoet.rollout.backends.base import (
    Relief,
    WorkerLost,
    engine_jobs,
    reliefs_of,
    split_results,
)
from epoet.rollout.backends.pool import fair_slots
from epoet.rollout.engine import Episodes, RolloutEngine
from epoet.rollout.populations import Population, Request
from epoet.terrain.config import TerrainConfig

try:
    import ray
    from ray.exceptions import RayActorError, RayTaskError, WorkerCrashedError
except ImportError:  # the optional extra; RayEvaluator says how to install it
    ray = None  # type: ignore[assignment]  # RayEvaluator checks for None before any use

INSTALL_HINT = "pip install -c constraints.txt -e '.[distributed]'"
# An actor's process gone (killed, crashed): its work is redone by actors started anew.
_ACTOR_LOST = () if ray is None else (RayActorError, WorkerCrashedError)


# HTTP/2's client preface and an empty SETTINGS frame; Ray's GCS (a gRPC server) answers with
# its own SETTINGS frame (type 4, stream 0), which anything that is not HTTP/2 does not send.
_HTTP2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
HELLO_SECONDS = 2.0


def _speaks_http2(host: str, port: int) -> bool:
    """Whether the server at host:port answers HTTP/2's preface within HELLO_SECONDS: the cheap
    test first, so a port where something else listens fails in seconds without starting Ray."""
    try:
        with socket.create_connection((host, port), timeout=HELLO_SECONDS) as conn:
            conn.sendall(_HTTP2_HELLO)
            header = b""
            while len(header) < 9 and (chunk := conn.recv(9 - len(header))):
                header += chunk
    except OSError:  # a timeout included
        return False
    return len(header) == 9 and header[3] == 4 and header[5:9] == bytes(4)


# Then speaks to the address as `ray.init` does (Ray's own GCS client), in a child process that is
# killed at the deadline: `ray.init` waits minutes on a port where something else listens, and a
# client that gives up leaves threads behind, so neither runs in this process.
_PROBE = """
import sys
try:
    from ray._raylet import GcsClient
    GcsClient(address=sys.argv[1])
except Exception as exc:
    print(exc)
    sys.exit(1)
"""
PROBE_SECONDS = 8.0
# Ray's own connect timeouts (the client waits up to three), so the probe ends with its reason.
_PROBE_ENV = {"RAY_gcs_rpc_server_connect_timeout_s": "2", "RAY_py_gcs_connect_timeout_s": "2"}


def check_address(address: str) -> None:
    """Fail in seconds, in one sentence, when a cluster address is not a Ray cluster's (`ray.init`
    would retry for minutes): nothing listens there, or what listens is not Ray's GCS. `auto`
    and `ray://` addresses are left to Ray."""
    host, _, port = address.rpartition(":")
    if address == "auto" or "://" in address or not port.isdigit():
        return
    if ray is None:
        raise ConfigError(f"workers=ray needs Ray, the 'distributed' extra: {INSTALL_HINT}")
    host = host or "127.0.0.1"
    fix = (
        f"start one with `ray start --head --port={port}`, or use workers.address=null for a "
        f"local Ray."
    )
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
    except OSError as exc:
        raise ConfigError(
            f"no Ray cluster answers at workers.address={address} ({exc.strerror or exc}); {fix}"
        ) from None
    tls = os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true")  # no plain HTTP/2 then
    if not tls and not _speaks_http2(host, int(port)):
        raise ConfigError(
            f"no Ray cluster answers at workers.address={address} (something "
            f"listens there but does not speak Ray's gRPC); {fix}"
        )
    env = {**_PROBE_ENV, **os.environ}  # a user's own Ray timeouts win; the deadline holds anyway
    try:
        probe = subprocess.run(
            [sys.executable, "-c", _PROBE, f"{host}:{port}"],
            env=env,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=PROBE_SECONDS,
        )
    except subprocess.TimeoutExpired:
        raise ConfigError(
            f"no Ray cluster answers at workers.address={address} (something "
            f"listens there but does not answer as Ray in {PROBE_SECONDS:.0f} s); "
            f"{fix}"
        ) from None
    if probe.returncode == 0:
        return
    if "authentication" in probe.stderr.lower() or "authentication" in probe.stdout.lower():
        raise ConfigError(
            f"the Ray cluster at workers.address={address} wants token "
            f"authentication: export RAY_AUTH_MODE=token with the cluster's token in "
            f"~/.ray/auth_token (or RAY_AUTH_TOKEN)."
        )
    reason = (probe.stdout.strip().splitlines() or [f"exit code {probe.returncode}"])[-1]
    raise ConfigError(
        f"no Ray cluster answers at workers.address={address} (something listens "
        f"there but does not answer as Ray: {reason.rstrip('.')}); {fix}"
    )


class _Feed:
    """The items of the current call, handed out in guided chunks."""

    def __init__(self) -> None:
        self._call = -1
        self._items: list[tuple[int, int]] = []
        self._next = 0
        self._takers = 1

    def ready(self) -> int:
        """This actor's process id."""
        return os.getpid()

    def load(self, call: int, items: list[tuple[int, int]], takers: int) -> None:
        self._call, self._items, self._next, self._takers = call, items, 0, takers

    def take(self, call: int) -> list[tuple[int, int]]:
        if call != self._call:
            return []  # a call that was abandoned (an actor died) and started again
        left = len(self._items) - self._next
        n = min(left, max(1, math.ceil(left / (4 * self._takers))))
        chunk = self._items[self._next : self._next + n]
        self._next += n
        return chunk


class _RolloutActor:
    """One rollout engine on a Ray worker process."""

    def __init__(
        self,
        agent: AgentConfig,
        terrain_cfg: TerrainConfig,
        batch: int,
        layer_sizes: tuple[int, ...],
    ) -> None:
        self.engine = RolloutEngine(agent, terrain_cfg, batch, layer_sizes)

    def ready(self) -> int:
        """This actor's process id, once its engine is built."""
        return os.getpid()

    def work(
        self,
        feed: Any,
        call: int,
        reliefs: Sequence[Relief],
        populations: Sequence[Population],
        records: Sequence[int],
        slots: int,
    ) -> tuple[np.ndarray, Episodes]:
        self.engine.set_terrains(reliefs)
        jobs = engine_jobs(_pull(feed, call), populations, records)
        return self.engine.run_jobs(jobs, slots=slots)


def _is_live_raylet(process: psutil.Process) -> bool:
    try:
        # a killed raylet stays a zombie until it is reaped
        return process.name() == "raylet" and process.status() != psutil.STATUS_ZOMBIE
    except psutil.Error:  # it ended between the listing and the read
        return False


def _pull(feed: Any, call: int) -> Iterator[tuple[int, int]]:
    while chunk := ray.get(feed.take.remote(call)):
        yield from chunk


class RayActors:
    """The rollout actors and the feed on a Ray cluster, driven from the Ray host process
    (ray_host.py), which is the Ray driver: `workers` actors (None: one per CPU of the cluster)."""

    def __init__(
        self,
        agent: AgentConfig,
        terrain_cfg: TerrainConfig,
        workers: int | None,
        batch: int,
        layer_sizes: Sequence[int],
        address: str | None = None,
    ) -> None:
        if ray is None:
            raise RuntimeError(f"workers=ray needs Ray, the 'distributed' extra: {INSTALL_HINT}")
        try:
            # Local: as many CPUs as workers (or the machine's); a cluster brings its own.
            ray.init(
                address=address,
                num_cpus=None if address else workers,
                include_dashboard=False,
                configure_logging=False,
                log_to_driver=True,
            )
        except (ConnectionError, RuntimeError, ValueError) as exc:
            hint = (
                " (export RAY_AUTH_MODE=token: a cluster started with `ray start` wants it)"
                if os.environ.get("RAY_AUTH_MODE") != "token"
                else ""
            )
            raise RuntimeError(f"cannot join the Ray cluster at {address}: {exc}{hint}") from exc
        self.local = address is None  # this process started the Ray it drives
        self.workers = int(workers or ray.cluster_resources().get("CPU", 1))
        self.batch = int(batch)
        self._args = (agent, terrain_cfg, self.batch, tuple(layer_sizes))
        self._remote_actor = ray.remote(num_cpus=1)(_RolloutActor)
        self._remote_feed = ray.remote(num_cpus=0)(_Feed)
        self._calls = itertools.count()
        # Any: ray's types do not give an actor handle's methods their `.remote`.
        self._feed: Any = None
        self._actors: list[Any] = []
        self._start()

    def engine_batches(self) -> list[int]:
        """Each rollout actor's engine's slots."""
        return ray.get(
            [a.__ray_call__.remote(lambda self: self.engine.batch) for a in self._actors]
        )

    def _start(self) -> None:
        """The feed and the rollout actors, each process's id in `feed_pid` and `pids`."""
        self._feed = self._remote_feed.remote()
        self._actors = [self._remote_actor.remote(*self._args) for _ in range(self.workers)]
        try:
            self.feed_pid, *self.pids = ray.get(
                [self._feed.ready.remote(), *(a.ready.remote() for a in self._actors)]
            )
        except _ACTOR_LOST as exc:
            raise WorkerLost(f"a Ray actor died while starting: {exc}") from exc

    def lost_local_raylet(self) -> bool:
        """Whether the local Ray this process started has lost its raylet (a child of this
        process). Ray notices only when the raylet's heartbeats time out, seconds later, and
        then ends this process itself; actors asked for meanwhile wait for that."""
        if not self.local:
            return False
        return not any(_is_live_raylet(p) for p in psutil.Process().children(recursive=True))

    def restart(self) -> None:
        """Every actor anew, the feed too: any of them may be the one that died."""
        for actor in [*self._actors, self._feed]:
            ray.kill(actor)
        self._start()

    def run(self, requests: Sequence[Request]) -> list[Episodes]:
        """One call's episodes; `WorkerLost` when an actor died (`restart`, then call again)."""
        call = next(self._calls)
        sizes = [len(r.population) for r in requests]
        items = [(k, e) for k, n in enumerate(sizes) for e in range(n)]
        futures: list = []
        try:
            ray.get(self._feed.load.remote(call, items, self.workers))
            shared = [ray.put(reliefs_of(requests)), ray.put([r.population for r in requests])]
            slots = fair_slots(self.batch, len(items), self.workers)
            futures = [
                a.work.remote(self._feed, call, *shared, [r.record for r in requests], slots)
                for a in self._actors
            ]
            parts = ray.get(futures)
        except (*_ACTOR_LOST, RayTaskError) as exc:
            lost = exc.cause if isinstance(exc, RayTaskError) else exc  # a pull from a dead feed
            if not isinstance(lost, _ACTOR_LOST):
                raise
            with contextlib.suppress(*_ACTOR_LOST):  # the feed, if alive, stops the survivors
                ray.get(self._feed.load.remote(-1, [], 1))
            ray.wait(futures, num_returns=len(futures))
            raise WorkerLost(f"a Ray actor died ({type(lost).__name__})") from exc
        return split_results(parts, sizes)

    def close(self) -> None:
        """Stop the actors and leave the cluster (a local Ray stops with it)."""
        for actor in [*self._actors, self._feed]:
            ray.kill(actor)
        self._actors = []
        ray.shutdown()
