"""`workers.address` where something that is not Ray listens: the run stops at start-up, in one
line that names the address and the fix, within seconds (`ray.init` alone waited minutes there,
as the TCP probe passed) and leaves no Ray process behind."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import mlflow
import pytest
from conftest import without_evaluation

pytest.importorskip("ray", reason="workers=ray comes with the 'distributed' extra")

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
    return {int(line.split()[0]) for line in out.splitlines()
            if "gcs_server" in line or "raylet" in line or "ray::" in line}


def test_an_address_where_something_else_listens_is_one_line_in_seconds(not_ray: str,
                                                                        tmp_path: Path) -> None:
    before = _ray_processes()
    start = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-m", "epoet", *without_evaluation([
            "workers=ray", f"workers.address={not_ray}", "budget=smoke",
            f"tracking.uri=sqlite:///{tmp_path}/mlflow.db", f"hydra.run.dir={tmp_path / 'run'}"])],
        cwd=tmp_path, env=os.environ, capture_output=True, text=True, timeout=40)
    elapsed = time.monotonic() - start
    assert out.returncode == 2, out.stderr[-2000:]
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr[-2000:]
    assert lines[0].startswith("error: ")
    assert f"workers.address={not_ray}" in lines[0]
    assert "ray start --head" in lines[0] and "workers.address=null" in lines[0]
    assert "Traceback" not in out.stderr + out.stdout
    assert elapsed < BOUND_SECONDS, f"{elapsed:.1f} s to fail"
    assert not (tmp_path / "mlflow.db").exists() or not mlflow.MlflowClient(  # before any run
        f"sqlite:///{tmp_path}/mlflow.db").search_runs(["0"])
    assert _ray_processes() <= before  # no Ray process left behind


@pytest.mark.parametrize("not_ray", ["http2"], indirect=True)
def test_an_http2_server_that_is_not_ray_fails_through_rays_own_client(not_ray: str) -> None:
    # It passes the HTTP/2 hello, so Ray's GCS client (in a child process) has to turn it down.
    from epoet.config import ConfigError
    from epoet.es.ray_workers import PROBE_SECONDS, check_address

    threads = threading.active_count()
    start = time.monotonic()
    with pytest.raises(ConfigError, match=f"workers.address={not_ray} .*does not answer as Ray"):
        check_address(not_ray)
    assert time.monotonic() - start < PROBE_SECONDS + 2
    assert threading.active_count() == threads  # no Ray thread in this process
