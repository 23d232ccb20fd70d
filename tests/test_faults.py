"""Faults a long run meets: its main process killed (any signal), a worker dying mid-call, a
physics blow-up, a NaN in a learner update, a full or read-only disk at checkpoint time, and a
resumed run re-logging metrics. Real processes, real signals, real MuJoCo, real file systems."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import mlflow
import numpy as np
import pytest
import torch

from conftest import ES_SIZES, tiny_run, without_evaluation
from epoet import driver
from epoet.config import load
from epoet.core.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from epoet.core.lifecycle import StopOnSignal, Stopped, raise_if_stopped, stop_requested
from epoet.rollout.engine import RolloutEngine
from epoet.rollout.evaluators import make_evaluator
from epoet.rollout.policy import init_params
from epoet.rollout.populations import Mirrored, Request
from epoet.terrain import Terrain
from epoet.tracking import MlflowTracker
from pool_state import assert_same_state
from processes import processes_with_env

SMOKE = ["budget=smoke", "algo.es.hidden=[8]", "terrain.grid=40"]
CFG = load(SMOKE)


def _tagged_processes(tag: str) -> list[int]:
    return processes_with_env("EPOET_TEST_TAG", tag)


# each test's runs write into tmp_path/mlflow.db, an empty store made ready (conftest)
pytestmark = pytest.mark.usefixtures("store_in_tmp_path")


def _launch(args: list[str], tmp_path: Path, tag: str) -> subprocess.Popen:
    env = {
        **os.environ,
        "EPOET_TEST_TAG": tag,
        "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path}/mlflow.db",
    }
    return subprocess.Popen(
        [sys.executable, "-m", "epoet", *without_evaluation(args)],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for(predicate, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.1)


def test_a_killed_run_leaves_no_worker_process_behind(tmp_path: Path) -> None:
    sig = signal.SIGKILL  # the hardest case: no handler runs, nothing is cleaned up
    tag = f"orphans-{os.getpid()}"
    run_dir = tmp_path / "run"
    proc = _launch(
        [
            *SMOKE,
            "workers.num=2",
            "budget.iterations=1000",
            "checkpoint_every=1",
            f"hydra.run.dir={run_dir}",
        ],
        tmp_path,
        tag,
    )
    try:
        _wait_for(lambda: (run_dir / "checkpoint.pkl").exists())  # the workers are running
        assert len(_tagged_processes(tag)) >= 4  # main, fork server, two workers
        os.kill(proc.pid, sig)
        proc.wait(timeout=30)
        _wait_for(lambda: not _tagged_processes(tag), timeout=5)
    finally:
        for pid in _tagged_processes(tag):
            os.kill(pid, signal.SIGKILL)


def test_a_run_killed_before_its_first_checkpoint_is_closed_as_killed(tmp_path: Path) -> None:
    """SIGKILL before the first checkpoint leaves the MLflow run RUNNING; the tables say so, and
    the next run in the folder (a fresh start: there is nothing to resume) closes it as KILLED.
    (One algorithm: the run's folder and MLflow run are opened and closed by run.py for all.)"""
    run_dir, uri = tmp_path / "run", f"sqlite:///{tmp_path}/mlflow.db"
    args = [*tiny_run("epoet"), f"hydra.run.dir={run_dir}", "checkpoint_every=100000"]
    proc = _launch([*args, "budget.iterations=1000"], tmp_path, "k")
    try:  # its MLflow run is open once the folder is marked
        _wait_for(lambda: (run_dir / "RUNNING").exists() or proc.poll() is not None)
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert not (run_dir / "checkpoint.pkl").exists()
    client = mlflow.MlflowClient(uri)
    experiment = [client.get_experiment_by_name("epoet").experiment_id]
    (first,) = client.search_runs(experiment)
    assert first.info.status == "RUNNING"
    script = "from analysis.store import connect, select_runs; select_runs(*connect(), 'epoet')"
    seen = subprocess.run(
        [sys.executable, "-c", script],
        env={**os.environ, "MLFLOW_TRACKING_URI": uri},
        capture_output=True,
        text=True,
    )
    assert f"RUNNING with no live process (killed): {first.info.run_id}" in seen.stderr
    again = _launch(args, tmp_path, "k")
    assert again.wait(timeout=300) == 0, again.stderr.read()
    assert client.get_run(first.info.run_id).info.status == "KILLED"
    statuses = sorted(r.info.status for r in client.search_runs(experiment))
    assert statuses == ["FINISHED", "KILLED"] and not (run_dir / "RUNNING").exists()


def test_evaluating_a_killed_runs_folder_closes_its_run_as_killed(tmp_path: Path) -> None:
    """`evaluate run=<folder>` of a run whose process was killed after a checkpoint evaluates its
    agent and closes its MLflow run, left RUNNING, as KILLED."""
    from conftest import subset_suite

    run_dir, uri = tmp_path / "run", f"sqlite:///{tmp_path}/mlflow.db"
    args = [*SMOKE, f"hydra.run.dir={run_dir}", "checkpoint_every=1", "budget.iterations=1000"]
    proc = _launch(args, tmp_path, "k")
    try:
        _wait_for(lambda: (run_dir / "checkpoint.pkl").exists() or proc.poll() is not None)
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    client = mlflow.MlflowClient(uri)
    (killed,) = client.search_runs([client.get_experiment_by_name("epoet").experiment_id])
    assert killed.info.status == "RUNNING"
    suite = subset_suite(tmp_path / "suite", [("easy", 0)])
    evaluate = [f"run={run_dir}", f"suite={suite}", "episodes=1", f"out={tmp_path / 'eval'}"]
    done = subprocess.run(
        [sys.executable, "-m", "epoet.eval.evaluate", *evaluate],
        env={**os.environ, "MLFLOW_TRACKING_URI": uri},
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    after = client.get_run(killed.info.run_id)
    assert after.info.status == "KILLED" and "suite/suite/success_rate" in after.data.metrics


class _KilledBetweenWrites(Exception):
    pass


class _AgentsThenKilled:
    """The driver's view of an algorithm whose process dies once its agents are written."""

    def save_agents(self, folder: Path) -> None:
        (folder / "agents").write_text("the run's agents")

    def state_dict(self) -> dict:
        raise _KilledBetweenWrites


def test_a_checkpoint_is_written_after_its_agents(tmp_path: Path) -> None:
    """A process killed between a checkpoint's two writes leaves agents without a checkpoint,
    never a checkpoint without agents (under load the killed-run test above once caught a first
    checkpoint whose agents were not written yet, and `evaluate` refused the folder)."""
    with pytest.raises(_KilledBetweenWrites):
        driver.checkpoint(_AgentsThenKilled(), load([]), None, tmp_path)  # type: ignore[arg-type]
    assert (tmp_path / "agents").exists() and not list(tmp_path.glob("checkpoint*"))


def test_sigint_and_sigterm_request_a_stop_and_a_second_signal_stops_at_once() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):
        with StopOnSignal():
            assert not stop_requested()
            raise_if_stopped("nowhere")  # nothing asked for yet
            os.kill(os.getpid(), sig)
            assert stop_requested()
            with pytest.raises(Stopped) as stopped:
                raise_if_stopped("after iteration 3")
            assert stopped.value.exit_code == 128 + sig
            assert str(stopped.value) == f"stopped by {sig.name} after iteration 3"
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), sig)
        assert not stop_requested()  # the handlers are gone with the context
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def test_sigterm_checkpoints_then_the_resumed_run_equals_an_uninterrupted_one(
    tmp_path: Path,
) -> None:
    sig = signal.SIGTERM  # SLURM's preemption; SIGINT takes the same path (test above)
    run_dir = tmp_path / "stopped"
    overrides = [*SMOKE, "workers.num=2", "checkpoint_every=1000"]
    proc = _launch(
        [*overrides, "budget.iterations=1000", f"hydra.run.dir={run_dir}"],
        tmp_path,
        f"stop-{os.getpid()}",
    )
    lines = []
    for line in proc.stdout:  # wait for the second iteration: no checkpoint is due before 1000
        lines.append(line)
        if line.startswith("[epoet] it 2/"):
            break
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, err
    assert f"stopped by {sig.name}" in err, err
    # one line to continue it: resume= and every override it was started with
    (said,) = [line for line in err.splitlines() if "continue with" in line]
    assert f"python -m epoet resume={run_dir} " in said and "budget.iterations=1000" in said
    assert all(o in said for o in overrides), said
    state = load_checkpoint(run_dir / "checkpoint.pkl")
    stopped_at = state["open_ended"]["iteration"]
    assert 2 <= stopped_at < 1000
    client = mlflow.MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    assert client.get_run(state["run_id"]).info.status == "KILLED"
    assert not (run_dir / "DONE").exists()

    total = stopped_at + 2
    both = [
        _launch([*overrides, f"budget.iterations={total}", *args], tmp_path, "resume")
        for args in (
            [f"resume={run_dir}", f"hydra.run.dir={run_dir}"],
            [f"hydra.run.dir={tmp_path / 'straight'}"],
        )
    ]
    for proc in both:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
    resumed = load_checkpoint(run_dir / "checkpoint.pkl")
    straight = load_checkpoint(tmp_path / "straight" / "checkpoint.pkl")
    assert resumed["open_ended"]["iteration"] == straight["open_ended"]["iteration"] == total
    assert_same_state(resumed["open_ended"], straight["open_ended"])  # every entry, pools by length
    steps = [m.step for m in client.get_metric_history(state["run_id"], "best_score")]
    assert sorted(steps) == list(range(total))  # every iteration once: none lost, none twice


def test_a_resumed_run_never_logs_a_metric_point_twice(tmp_path: Path) -> None:
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    with MlflowTracker(uri, "faults") as first:
        run_id = first.start("killed")
        for step in range(6):
            first.log_metrics(step, {"a": step, "final/x": 1.0} if step == 5 else {"a": step})
    # Resumed from a checkpoint at step 2: steps 3-5 are computed again, then the run goes on.
    with MlflowTracker(uri, "faults") as resumed:
        resumed.start("killed", resume_run_id=run_id)
        for step in range(3, 8):
            resumed.log_metrics(step, {"a": step})
        resumed.log_metrics(5, {"final/x": 1.0})
        resumed.log_metrics(8, {"final/x": 2.0})
    client = mlflow.MlflowClient(uri)
    assert sorted(m.step for m in client.get_metric_history(run_id, "a")) == list(range(8))
    assert [(m.step, m.value) for m in client.get_metric_history(run_id, "final/x")] == [
        (5, 1.0),
        (8, 2.0),
    ]


def test_a_worker_killed_mid_call_is_replaced_and_the_results_are_unchanged() -> None:
    terrain = Terrain(np.zeros((40, 40)), 0.0, CFG.terrain.size, "bowl", 0)
    agent = replace(CFG.agent, max_episode_steps=200)
    terrain_cfg = replace(CFG.terrain, grid=40)
    seeds = np.arange(80)  # a call of seconds, so the kill lands inside it
    es = Request(terrain, Mirrored.of(init_params(3, ES_SIZES), seeds, 0.05, seeds + 100))
    with make_evaluator(agent, terrain_cfg, 1, 4, ES_SIZES) as one:
        expected = one.run([es])[0].returns
    with make_evaluator(agent, terrain_cfg, 2, 4, ES_SIZES) as two:
        victim = next(iter(two._pool._processes))
        killer = threading.Timer(0.5, os.kill, (victim, signal.SIGKILL))
        killer.start()
        started = time.monotonic()
        returns = two.run([es])[0].returns
        killer.join()
        assert time.monotonic() - started > 0.5, "the call ended before the kill: make it longer"
        assert two.restarts == 1
        np.testing.assert_array_equal(returns, expected)


def test_a_physics_blow_up_ends_the_episode_as_a_failure(tmp_path: Path) -> None:
    # A 1 s RK4 step makes the hexapod's physics diverge (NaN) within its first steps.
    agent = replace(CFG.agent, timestep=1.0, integrator="rk4", max_episode_steps=50)
    engine = RolloutEngine(agent, replace(CFG.terrain, grid=40), 4, ES_SIZES)
    terrain = Terrain(np.zeros((40, 40)), 0.0, CFG.terrain.size, "bowl", 0)
    params = np.stack([init_params(s, ES_SIZES) for s in range(4)])
    episodes = engine.run(terrain, params, np.arange(4), record=True)
    assert (episodes.lengths < 50).all() and not episodes.finished.any()
    assert np.isfinite(episodes.returns).all()
    t = episodes.transitions
    assert all(np.isfinite(t[k]).all() for k in ("obs", "next_obs", "reward"))
    assert t["terminated"][np.r_[np.flatnonzero(np.diff(t["episode"])), -1]].all()


def test_a_non_finite_learner_loss_skips_the_update_and_counts_it() -> None:
    from epoet.rl.env import make_env
    from epoet.sac.learner import SacLearner

    cfg = load(["algo=sac", "budget=smoke", "algo.batch_size=8"])
    env = make_env(cfg, obs_norm=False, seed=0)
    learner = SacLearner(cfg.algo, env)
    data = env.rollout(16)
    data["next", "reward"][:] = float("nan")  # e.g. a corrupted transition in every sample
    learner.add(data)
    before = [p.detach().clone() for p in learner.loss.parameters()]
    learned = learner.gradient_steps(2)
    assert learned == {"skipped_updates": 2}
    for old, new in zip(before, learner.loss.parameters()):
        torch.testing.assert_close(old, new.detach(), rtol=0, atol=0)


@contextmanager
def _mounted(tmp_path: Path, size: str) -> Path:
    """A real, tiny tmpfs (needs CAP_SYS_ADMIN, as root in a container has)."""
    point = tmp_path / "mnt"
    point.mkdir()
    if (
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(point)], capture_output=True
        ).returncode
        != 0
    ):
        pytest.skip("mounting a tmpfs needs CAP_SYS_ADMIN")
    try:
        yield point
    finally:
        subprocess.run(["umount", "-l", str(point)], check=False)


def test_a_full_or_read_only_disk_at_checkpoint_time_keeps_the_previous_checkpoint(
    tmp_path: Path,
) -> None:
    with _mounted(tmp_path, "256k") as disk:
        path = disk / "checkpoint.pkl"
        save_checkpoint(path, {"iteration": 1})
        saved = path.read_bytes()
        with pytest.raises(CheckpointError, match="No space left on device"):
            save_checkpoint(path, {"iteration": 2, "replay": np.zeros(1 << 20)})
        assert path.read_bytes() == saved and os.listdir(disk) == ["checkpoint.pkl"]
        subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True)
        with pytest.raises(CheckpointError, match="Read-only file system"):
            save_checkpoint(path, {"iteration": 2})
        assert load_checkpoint(path) == {"iteration": 1}
