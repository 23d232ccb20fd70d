"""Scaling out: workers=ray gives exactly workers=local's results, on a local Ray (which replaces
a killed actor) and, for a whole run, on a cluster started with `ray start --head`; a joblib
sweep runs its jobs in parallel into one sqlite store; the SLURM launcher config composes."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import mlflow
import numpy as np
import pytest

from conftest import ES_SIZES, run_epoet, without_evaluation
from epoet.config import load
from epoet.core.checkpoint import load_checkpoint
from epoet.rollout.evaluators import make_evaluator
from epoet.rollout.policy import init_params
from epoet.rollout.populations import Mirrored, Request
from epoet.terrain import Terrain

SMOKE = ["budget=smoke", "algo.es.hidden=[8]", "terrain.grid=40", "budget.iterations=2"]
RAY = shutil.which("ray", path=os.path.dirname(sys.executable))


# each test's runs write into tmp_path/mlflow.db, an empty store made ready (conftest)
pytestmark = pytest.mark.usefixtures("store_in_tmp_path")


def _epoet(args: list[str], tmp_path: Path, **env: str) -> subprocess.CompletedProcess:
    return run_epoet(args, tmp_path, f"sqlite:///{tmp_path}/mlflow.db", timeout=400, **env)


def _no_run_in(store: Path) -> bool:
    """No run in any experiment of the store (runs go to `epoet`, not MLflow's Default), or no
    store at all."""
    if not store.exists():
        return True
    client = mlflow.MlflowClient(f"sqlite:///{store}")
    return not client.search_runs([e.experiment_id for e in client.search_experiments()])


def _pool(run_dir: Path) -> list[dict]:
    return load_checkpoint(run_dir / "checkpoint.pkl")["open_ended"]["active"]


def _assert_same_pool(a: list[dict], b: list[dict]) -> None:
    assert len(a) == len(b)
    for pa, pb in zip(a, b):
        assert pa["scores"] == pb["scores"]
        np.testing.assert_array_equal(pa["es"]["theta"], pb["es"]["theta"])


@pytest.fixture(scope="module")
def local_run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("local")
    # the pools are compared, so neither run evaluates its agent on the suite
    out = _epoet(without_evaluation([*SMOKE, "workers.num=2", f"hydra.run.dir={tmp / 'run'}"]), tmp)
    assert out.returncode == 0, out.stderr[-2000:]
    return tmp / "run"


def test_a_local_ray_gives_the_local_results_and_survives_each_kind_of_killed_process() -> None:
    """Killed mid-call, each process of the Ray backend is replaced and the call gives the same
    episodes: a rollout actor, the feed and the local cluster's raylet. Ray then ends its
    driver, the Ray host, with no word to it, so this is also the host's own death: the run's
    process sees the host's pipe close either way (a fresh host and Ray; not killed twice, at
    ten seconds of a Ray start each). Each actor's engine steps as many robots as a local pool
    worker's (`workers.batch`: conf/workers/local.yaml owns it, ray.yaml inherits it)."""
    from epoet.rollout.backends.ray_host import RayEvaluator

    cfg = load([*SMOKE, "workers=ray", "workers.num=2"])
    workers = cfg.workers
    agent, terrain_cfg = replace(cfg.agent, max_episode_steps=200), cfg.terrain
    terrain = Terrain(np.zeros((40, 40)), 0.0, terrain_cfg.size, "bowl", 0)
    seeds = np.arange(80)  # a call of seconds, so the kill lands inside it
    es = Request(terrain, Mirrored.of(init_params(3, ES_SIZES), seeds, 0.05, seeds + 100), record=3)
    with make_evaluator(agent, terrain_cfg, 1, 4, ES_SIZES) as one:
        (expected,) = one.run([es])
    sigterm = signal.getsignal(signal.SIGTERM)
    with RayEvaluator(agent, terrain_cfg, workers.num, workers.batch, ES_SIZES) as on_ray:
        assert on_ray.engine_batches == [load([]).workers.batch] * 2 and workers.batch > 1
        # ray.init's own SIGTERM handler (sys.exit) would skip a run's checkpoint on SIGTERM
        assert signal.getsignal(signal.SIGTERM) == sigterm
        (episodes,) = on_ray.run([es])
        np.testing.assert_array_equal(episodes.returns, expected.returns)
        for key, value in expected.transitions.items():
            np.testing.assert_array_equal(episodes.transitions[key], value)
        victims = (
            lambda: on_ray.pids[0],
            lambda: on_ray.feed_pid,
            lambda: _raylet_of(on_ray.host_pid),
        )
        for restarts, victim in enumerate(victims, 1):
            killer = threading.Timer(0.5, os.kill, (victim(), signal.SIGKILL))
            killer.start()
            (episodes,) = on_ray.run([es])
            killer.join()
            assert on_ray.restarts == restarts
            np.testing.assert_array_equal(episodes.returns, expected.returns)


def _raylet_of(host_pid: int) -> int:
    """The raylet of the local Ray that the Ray host process started (its descendant)."""
    found = subprocess.run(["pgrep", "-x", "raylet"], capture_output=True, text=True).stdout
    for pid in map(int, found.split()):
        parent = pid
        while parent > 1:
            parent = int(Path(f"/proc/{parent}/stat").read_text().rsplit(")", 1)[1].split()[1])
            if parent == host_pid:
                return pid
    raise AssertionError(f"no raylet under the Ray host {host_pid}")


@pytest.fixture
def ray_cluster(tmp_path: Path):
    """A real Ray head node on this machine, as `ray start --head` starts one for users."""
    port = 6390
    env = {**os.environ, "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"}
    started = subprocess.run(
        [
            RAY,
            "start",
            "--head",
            f"--port={port}",
            "--num-cpus=2",
            "--include-dashboard=false",
            "--disable-usage-stats",
        ],
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
    )
    assert started.returncode == 0, started.stderr[-2000:]
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([RAY, "stop", "--force"], capture_output=True, timeout=120)


@pytest.mark.skipif(RAY is None, reason="the ray command comes with the 'distributed' extra")
def test_a_run_on_a_ray_cluster_gets_the_local_result_and_stops_cleanly_when_it_goes(
    local_run: Path, ray_cluster: str, tmp_path: Path
) -> None:
    """A run joins a cluster started with `ray start` and gets `workers=local`'s result. A second
    run loses the cluster mid-run (`ray stop`): the Ray host dies and no new one can join, so
    the run saves the state its step started from, says so in one line with the resume
    command, and exits 75; resumed on this machine's process pool (`workers` may change on
    resume), it finishes. (One test: one cluster start.)"""
    # `ray start` turns on token authentication; its token is in ~/.ray, as for users. The host
    # gives up on a lost cluster after 5 s here (Ray's default: 60 s).
    env = {"RAY_AUTH_MODE": "token", "RAY_gcs_rpc_server_reconnect_timeout_s": "5"}
    joined = tmp_path / "joined"
    cluster = ["workers=ray", f"workers.address={ray_cluster}"]
    out = _epoet(without_evaluation([*SMOKE, *cluster, f"hydra.run.dir={joined}"]), tmp_path, **env)
    assert out.returncode == 0, out.stderr[-2000:]
    _assert_same_pool(_pool(joined), _pool(local_run))

    run_dir, overrides = tmp_path / "run", without_evaluation([*SMOKE, "budget.iterations=1000"])
    proc = subprocess.Popen(
        [sys.executable, "-m", "epoet", *overrides, *cluster, f"hydra.run.dir={run_dir}"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path}/mlflow.db", **env},
    )  # fmt: skip
    assert proc.stdout is not None
    for line in proc.stdout:  # the cluster goes after the second iteration
        if line.startswith("[epoet] it 2/"):
            break
    subprocess.run([RAY, "stop", "--force"], capture_output=True, timeout=120)
    _, err = proc.communicate(timeout=200)
    assert proc.returncode == 75, err[-3000:]
    (said,) = [line for line in err.splitlines() if line.startswith("epoet: stopped after")]
    assert "its workers lost" in said and f"continue with python -m epoet resume={run_dir}" in said
    stopped_at = load_checkpoint(run_dir / "checkpoint.pkl")["open_ended"]["iteration"]
    assert stopped_at >= 2
    resumed = _epoet(
        [*SMOKE, f"budget.iterations={stopped_at + 1}", "workers.num=2", f"resume={run_dir}",
         f"hydra.run.dir={run_dir}"],
        tmp_path,
    )  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert load_checkpoint(run_dir / "checkpoint.pkl")["open_ended"]["iteration"] == stopped_at + 1


def test_an_unreachable_ray_cluster_is_one_line_before_any_run(tmp_path: Path) -> None:
    out = _epoet(
        [*SMOKE, "workers=ray", "workers.address=127.0.0.1:9", f"hydra.run.dir={tmp_path / 'run'}"],
        tmp_path,
    )
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [out.stderr.strip()]
    assert "no Ray cluster answers at workers.address=127.0.0.1:9" in out.stderr
    assert _no_run_in(tmp_path / "mlflow.db")


def test_a_joblib_sweep_runs_two_jobs_in_parallel_into_one_store(tmp_path: Path) -> None:
    out = _epoet(
        [
            "-m",
            *SMOKE,
            "workers.num=1",
            "seed=1,2",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            f"hydra.sweep.dir={tmp_path / 'sweep'}",
        ],
        tmp_path,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "database is locked" not in out.stderr
    client = mlflow.MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    runs = client.search_runs([client.get_experiment_by_name("epoet").experiment_id])
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in runs if "mlflow.parentRunId" in r.data.tags]
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    assert sorted(c.data.tags["seed"] for c in children) == ["1", "2"]
    assert all(c.data.tags["mlflow.parentRunId"] == parents[0].info.run_id for c in children)
    assert all(c.info.status == "FINISHED" for c in children)
    first, second = sorted(children, key=lambda c: c.info.start_time)
    assert second.info.start_time < first.info.end_time  # the two jobs ran at the same time


def test_the_slurm_launcher_config_composes(tmp_path: Path) -> None:
    out = _epoet(
        ["hydra/launcher=slurm", "--cfg", "hydra", "--package", "hydra.launcher"], tmp_path
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "hydra_plugins.hydra_submitit_launcher" in out.stdout and "timeout_min" in out.stdout


# --- workers.address where something that is not Ray listens: the run stops at start-up, in one
# line that names the address and the fix, within seconds (`ray.init` alone waited minutes there,
# as the TCP probe passed) and leaves no Ray process behind. In this file because the check of
# Ray processes must not overlap the other Ray tests (one xdist worker runs a file).

BOUND_SECONDS = 20.0  # the bound for joining or failing


# An HTTP/2 server's SETTINGS frame (empty): what a gRPC server that is not Ray's GCS says first.
SETTINGS = bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


@pytest.fixture(params=["silent", "garbage"])
def not_ray(request) -> Iterator[str]:
    """A plain TCP server on 127.0.0.1 that accepts and says nothing, a line of garbage, or (for
    "http2") an HTTP/2 SETTINGS frame and then nothing."""
    server = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return  # closed
            accepted.append(conn)
            if request.param == "garbage":
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\nnot ray\r\n")
            elif request.param == "http2":
                conn.sendall(SETTINGS)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.getsockname()[1]}"
    finally:
        server.close()
        for conn in accepted:
            conn.close()


def _ray_processes() -> set[int]:
    out = subprocess.run(["ps", "-eo", "pid=,args="], capture_output=True, text=True).stdout
    return {
        int(line.split()[0])
        for line in out.splitlines()
        if "gcs_server" in line or "raylet" in line or "ray::" in line
    }


def test_an_address_where_something_else_listens_is_one_line_in_seconds(
    not_ray: str, tmp_path: Path
) -> None:
    before = _ray_processes()
    start = time.monotonic()
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "epoet",
            *without_evaluation(
                [
                    "workers=ray",
                    f"workers.address={not_ray}",
                    "budget=smoke",
                    f"tracking.uri=sqlite:///{tmp_path}/mlflow.db",
                    f"hydra.run.dir={tmp_path / 'run'}",
                ]
            ),
        ],
        cwd=tmp_path,
        env=os.environ,
        capture_output=True,
        text=True,
        timeout=40,
    )
    elapsed = time.monotonic() - start
    assert out.returncode == 2, out.stderr[-2000:]
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr[-2000:]
    assert lines[0].startswith("error: ")
    assert f"workers.address={not_ray}" in lines[0]
    assert "ray start --head" in lines[0] and "workers.address=null" in lines[0]
    assert "Traceback" not in out.stderr + out.stdout
    assert elapsed < BOUND_SECONDS, f"{elapsed:.1f} s to fail"
    assert _no_run_in(tmp_path / "mlflow.db")  # it failed before any run
    assert _ray_processes() <= before  # no Ray process left behind


@pytest.mark.parametrize("not_ray", ["http2"], indirect=True)
def test_an_http2_server_that_is_not_ray_fails_through_rays_own_client(not_ray: str) -> None:
    # It passes the HTTP/2 hello, so Ray's GCS client (in a child process) has to turn it down.
    from epoet.core.schema import ConfigError
    from epoet.rollout.backends.ray_cluster import PROBE_SECONDS, check_address

    threads = threading.active_count()
    start = time.monotonic()
    with pytest.raises(ConfigError, match=f"workers.address={not_ray} .*does not answer as Ray"):
        check_address(not_ray)
    assert time.monotonic() - start < PROBE_SECONDS + 2
    assert threading.active_count() == threads  # no Ray thread in this process
