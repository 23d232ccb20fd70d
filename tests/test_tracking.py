"""Tracking against a real MLflow sqlite store (one per module: creating it costs ~4 s)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mlflow import MlflowClient

from conftest import authors, new_store
from epoet.tracking import (
    PARENT_RUN_ENV,
    MlflowTracker,
    Tracker,
    TrackingError,
    default_tracking_uri,
    flatten,
    metric_key,
    parent_run_id,
    resolve_tracking_uri,
)
from epoet.tracking.writer import LOAD_METRIC


@pytest.fixture(scope="module")
def store(tmp_path_factory, empty_store) -> tuple[str, Path]:
    """A migrated sqlite store shared by this module's tests; each test uses its own experiment."""
    root = tmp_path_factory.mktemp("store")
    return new_store(empty_store, root), root


@pytest.fixture
def tracker(store, request) -> MlflowTracker:
    """A tracker on its own experiment that never flushes unless asked (or at close)."""
    uri, _ = store
    return MlflowTracker(uri, experiment=request.node.name, flush_seconds=3600)


def _history(uri: str, run_id: str, key: str) -> list[tuple[int, float]]:
    return sorted((m.step, m.value) for m in MlflowClient(uri).get_metric_history(run_id, key))


def test_metrics_are_buffered_and_sent_every_flush_every_points(store, tracker):
    uri, _ = store
    run_id = tracker.start("buffered")
    for step in range(2500):
        tracker.log_metrics(step, {"pair/0/return_mean": step * 0.5})
    assert len(_history(uri, run_id, "pair/0/return_mean")) == 2000  # two flushes of 1000
    tracker.flush()
    history = _history(uri, run_id, "pair/0/return_mean")
    assert len(history) == 2500
    assert history[3] == (3, 1.5)


def test_a_flush_records_the_machines_load_at_most_every_load_every_seconds(store, tracker):
    uri, _ = store
    run_id = tracker.start("load")
    tracker.log_metrics(3, {"score": 1.0})
    tracker.flush()
    tracker.log_metrics(4, {"score": 2.0})
    tracker.flush()  # within LOAD_EVERY of the first: no second point
    load = _history(uri, run_id, LOAD_METRIC)
    assert [step for step, _ in load] == [3] and load[0][1] >= 0.0


def test_large_flush_is_split_into_mlflow_sized_batches(store, request):
    uri, _ = store
    tracker = MlflowTracker(
        uri, experiment=request.node.name, flush_every=10**6, flush_seconds=3600
    )
    run_id = tracker.start("chunked")
    for step in range(1250):  # one flush of 2500 points: MLflow accepts 1000 per call
        tracker.log_metrics(step, {"a": 1.0, "b": 2.0})
    assert _history(uri, run_id, "a") == []
    tracker.flush()
    assert len(_history(uri, run_id, "a")) == len(_history(uri, run_id, "b")) == 1250


def test_a_failed_flush_keeps_the_points_for_the_next(store, request):
    uri, _ = store
    tracker = MlflowTracker(
        uri, experiment=request.node.name, flush_every=10**6, flush_seconds=3600
    )
    run_id = tracker.start("refused")
    for step in range(1500):
        tracker.log_metrics(step, {"a": 1.0})
    MlflowClient(uri).delete_run(run_id)  # MLflow refuses metrics for a deleted run
    with pytest.raises(TrackingError, match="cannot send metrics"):
        tracker.flush()
    MlflowClient(uri).restore_run(run_id)
    tracker.flush()
    assert len(_history(uri, run_id, "a")) == 1500


def test_time_based_flush_and_close_flushes(store, request):
    uri, _ = store
    tracker = MlflowTracker(uri, experiment=request.node.name, flush_seconds=0)
    run_id = tracker.start("timed")
    tracker.log_metrics(0, {"loss": 2.0})
    assert _history(uri, run_id, "loss") == [(0, 2.0)]  # flush_seconds=0: sent at once

    slow = MlflowTracker(uri, experiment=request.node.name, flush_seconds=3600)
    slow_id = slow.start("closed")
    slow.log_metrics(4, {"loss": 1.0})
    assert _history(uri, slow_id, "loss") == []
    slow.close()
    assert _history(uri, slow_id, "loss") == [(4, 1.0)]
    assert MlflowClient(uri).get_run(slow_id).info.status == "FINISHED"


def test_params_are_the_flattened_config_and_tags_are_set(store, tracker):
    uri, _ = store
    cfg = {
        "algo": {"name": "ppo", "lr": 3e-4, "hidden": [256, 256]},
        "seed": 1,
        "terrain": {"cppn": {"enabled": True}},
        "long": "x" * 7000,
    }
    run_id = tracker.start("params", params=flatten(cfg), tags={"algo": "ppo", "seed": 1})
    tracker.close()

    run = MlflowClient(uri).get_run(run_id)
    assert run.data.params["algo.name"] == "ppo"
    assert run.data.params["algo.lr"] == "0.0003"
    assert run.data.params["algo.hidden"] == "[256, 256]"
    assert run.data.params["terrain.cppn.enabled"] == "True"
    assert len(run.data.params["long"]) == 6000  # MLflow's param value limit
    assert run.data.tags["algo"] == "ppo" and run.data.tags["seed"] == "1"
    assert re.fullmatch(r"[0-9a-f]{40}|unknown", run.data.tags["mlflow.source.git.commit"])
    assert run.info.run_name == "params"


def test_flatten_keeps_empty_mappings_and_stringifies():
    assert flatten({"a": {"b": {"c": 1}}, "e": {}, "n": None}) == {
        "a.b.c": "1",
        "e": "{}",
        "n": "None",
    }


@pytest.mark.parametrize(
    "name, key",
    [
        ("pair/0/return_mean", "pair/0/return_mean"),
        ("sac.loss q", "sac.loss q"),
        ("loss(pi):x", "loss_pi__x"),
        ("/a//b/", "a/b"),
        ("a/../b", "a/__/b"),
    ],
)
def test_metric_keys_are_made_mlflow_valid(store, tracker, name, key):
    assert metric_key(name) == key
    tracker.start("keys")
    tracker.log_metrics(0, {name: 1.0})
    tracker.flush()  # MLflow itself accepts the sanitised key
    assert _history(store[0], tracker.run_id, key) == [(0, 1.0)]


def test_bad_metric_input_is_one_sentence(tracker):
    tracker.start("bad")
    with pytest.raises(TrackingError, match="metric 'x' must be a number"):
        tracker.log_metrics(0, {"x": "high"})
    with pytest.raises(TrackingError, match="no characters MLflow accepts"):
        tracker.log_metrics(0, {"//": 1.0})
    with pytest.raises(TrackingError, match="step must be a non-negative int"):
        tracker.log_metrics(-1, {"x": 1.0})


def test_artifacts_are_uploaded_beside_the_database(store, tracker, tmp_path):
    uri, root = store
    (tmp_path / "terrains").mkdir()
    (tmp_path / "terrains" / "t0.npy").write_bytes(b"\x00" * 8)
    (tmp_path / "eval.csv").write_text("env,success\nbowl,1\n")
    run_id = tracker.start("artifacts")
    tracker.log_artifact(tmp_path / "eval.csv")
    tracker.log_artifact(tmp_path / "terrains", artifact_path="terrains")
    tracker.log_dict({"seed": 1}, "config.yaml")
    with pytest.raises(TrackingError, match="does not exist"):
        tracker.log_artifact(tmp_path / "missing.csv")
    tracker.close()

    client = MlflowClient(uri)
    assert sorted(a.path for a in client.list_artifacts(run_id)) == [
        "config.yaml",
        "eval.csv",
        "terrains",
    ]
    assert [a.path for a in client.list_artifacts(run_id, "terrains")] == ["terrains/t0.npy"]
    assert client.get_run(run_id).info.artifact_uri.startswith((root / "mlartifacts").as_uri())


def test_resume_continues_the_same_run(store, request):
    uri, _ = store
    first = MlflowTracker(uri, experiment=request.node.name)
    run_id = first.start("resumable", params={"seed": "1", "budget.iterations": "10"})
    first.log_metrics(0, {"return": 1.0})
    first.close("KILLED")

    second = MlflowTracker(uri, experiment=request.node.name)
    assert (
        second.start(
            params={"seed": "1", "budget.iterations": "20", "new": "yes"}, resume_run_id=run_id
        )
        == run_id
    )
    assert MlflowClient(uri).get_run(run_id).info.status == "RUNNING"
    second.log_metrics(1, {"return": 2.0})
    second.close()

    run = MlflowClient(uri).get_run(run_id)
    assert _history(uri, run_id, "return") == [(0, 1.0), (1, 2.0)]
    assert run.data.params == {"seed": "1", "budget.iterations": "10", "new": "yes"}
    assert run.info.status == "FINISHED"
    assert len(MlflowClient(uri).search_runs([run.info.experiment_id])) == 1


def test_resume_of_unknown_run_is_one_sentence(tracker):
    with pytest.raises(TrackingError, match="cannot resume MLflow run 0123abc"):
        tracker.start(resume_run_id="0123abc")


def test_parent_child_tag_and_child_listing(store, request):
    uri, _ = store
    parent = MlflowTracker(uri, experiment=request.node.name)
    parent_id = parent.start("sweep")
    child = MlflowTracker(uri, experiment=request.node.name)
    child_id = child.start("job", parent_run_id=parent_id)
    child.close("FAILED")
    assert MlflowClient(uri).get_run(child_id).data.tags["mlflow.parentRunId"] == parent_id
    assert parent.child_runs() == {child_id: "FAILED"}


def test_exception_inside_context_marks_run_failed(store, request):
    uri, _ = store
    with pytest.raises(RuntimeError):
        with MlflowTracker(uri, experiment=request.node.name) as tracker:
            run_id = tracker.start("crash")
            tracker.log_metrics(0, {"x": 1.0})
            raise RuntimeError("diverged")
    assert MlflowClient(uri).get_run(run_id).info.status == "FAILED"
    assert _history(uri, run_id, "x") == [(0, 1.0)]


def test_closed_tracker_refuses_metrics(tracker):
    tracker.start("closed")
    tracker.close()
    tracker.close()  # a second close is a no-op
    with pytest.raises(TrackingError, match="not open"):
        tracker.log_metrics(0, {"x": 1.0})


@pytest.mark.parametrize(
    "uri, problem",
    [
        ("http://127.0.0.1:9", "Connection refused"),
        ("sqlite:///{tmp}/no/such/dir/mlflow.db", "does not exist"),
        ("sqlite:///{tmp}/file.txt/mlflow.db", "file.txt is not a directory"),
        ("sqlite:///{tmp}", "is a directory, not a database file"),
        ("sqlite:///{tmp}/file.txt", "not a usable sqlite database (file is not a database)"),
    ],
)
def test_unusable_store_fails_fast_with_one_line(tmp_path, monkeypatch, uri, problem):
    (tmp_path / "file.txt").write_text("not a directory")
    uri = uri.format(tmp=tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)  # the env var overrides the default store
    start = time.monotonic()
    with pytest.raises(TrackingError) as info:
        MlflowTracker(None, "unusable")
    assert time.monotonic() - start < 15
    message = str(info.value)
    assert "\n" not in message and uri in message and problem in message
    assert not (tmp_path / "no").exists()  # MLflow would have created the directories


def test_the_default_store_is_absolute_sqlite_where_the_command_started(monkeypatch, tmp_path):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.chdir(tmp_path)
    assert resolve_tracking_uri() == default_tracking_uri() == f"sqlite:///{tmp_path}/mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "sqlite:////x/y.db")
    assert resolve_tracking_uri() == "sqlite:////x/y.db"
    assert resolve_tracking_uri("http://h:5000") == "http://h:5000"


def test_parent_run_id_reads_the_environment(monkeypatch):
    monkeypatch.delenv(PARENT_RUN_ENV, raising=False)
    assert parent_run_id() is None
    monkeypatch.setenv(PARENT_RUN_ENV, "abc")
    assert parent_run_id() == "abc"


def test_numpy_steps_and_values_are_accepted(store, tracker):
    """Iteration counters and results often are numpy scalars."""
    assert isinstance(tracker, Tracker)
    run_id = tracker.start("numpy")
    tracker.log_metrics(0, {"pair/0/return": 1.5, "bad name!": 2})
    tracker.log_metrics(np.int64(1), {"pair/0/return": np.float32(2.5)})
    with pytest.raises(TrackingError, match="must be a number"):
        tracker.log_metrics(2, {"x": None})
    with pytest.raises(TrackingError, match="step must be a non-negative int"):
        tracker.log_metrics(1.5, {"x": 1.0})
    tracker.close("KILLED")

    assert _history(store[0], run_id, "pair/0/return") == [(0, 1.5), (1, 2.5)]
    assert _history(store[0], run_id, "bad name_") == [(0, 2.0)]
    assert MlflowClient(store[0]).get_run(run_id).info.status == "KILLED"


# --- the Hydra sweep callback, run as a real multirun in a subprocess ---------------------------

_APP = """
import hydra
from omegaconf import OmegaConf
from epoet.tracking import MlflowTracker, flatten, parent_run_id

@hydra.main(version_base="1.3", config_path=".", config_name="config")
def main(cfg):
    with MlflowTracker(None, cfg.experiment) as tracker:
        tracker.start(f"x={cfg.x}", params=flatten(OmegaConf.to_container(cfg, resolve=True)),
                      parent_run_id=parent_run_id())
        tracker.log_metrics(0, {"x": cfg.x})
        if cfg.x == cfg.fail_on:
            raise RuntimeError("job failed on purpose")

if __name__ == "__main__":
    main()
"""

_CONFIG = """
x: 0
fail_on: -1
experiment: ???
hydra:
  callbacks:
    mlflow_sweep:
      _target_: epoet.sweep.MlflowSweepCallback
      experiment: ${experiment}
"""


def _sweep(tmp_path: Path, uri: str, *overrides: str) -> subprocess.CompletedProcess:
    (tmp_path / "app.py").write_text(_APP)
    (tmp_path / "config.yaml").write_text(textwrap.dedent(_CONFIG))
    env = {k: v for k, v in os.environ.items() if k != PARENT_RUN_ENV}
    env["MLFLOW_TRACKING_URI"] = uri
    return subprocess.run(
        [sys.executable, "app.py", "-m", *overrides],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def _runs(uri: str, experiment: str) -> tuple[list, list]:
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name(experiment)
    runs = client.search_runs([exp.experiment_id])
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in runs if "mlflow.parentRunId" in r.data.tags]
    return parents, children


def test_sweep_makes_one_parent_with_a_child_per_job(store, tmp_path):
    uri, _ = store
    result = _sweep(tmp_path, uri, "x=1,2", "experiment=sweep_ok")
    assert result.returncode == 0, result.stderr[-2000:]

    parents, children = _runs(uri, "sweep_ok")
    assert len(parents) == 1 and len(children) == 2
    parent = parents[0]
    assert parent.info.status == "FINISHED"
    assert parent.data.tags["sweep_overrides"] == "x=1,2 experiment=sweep_ok"
    assert Path(parent.data.tags["sweep_dir"]).is_relative_to(tmp_path / "multirun")
    assert {c.data.tags["mlflow.parentRunId"] for c in children} == {parent.info.run_id}
    assert sorted(c.data.params["x"] for c in children) == ["1", "2"]
    assert {c.info.status for c in children} == {"FINISHED"}


def test_sweep_with_a_failing_job_marks_the_parent_failed(store, tmp_path):
    uri, _ = store
    result = _sweep(tmp_path, uri, "x=1,2", "fail_on=2", "experiment=sweep_fail")
    assert result.returncode != 0 and "job failed on purpose" in result.stderr

    parents, children = _runs(uri, "sweep_fail")
    assert len(parents) == 1
    assert parents[0].info.status == "FAILED"
    assert sorted((c.data.params["x"], c.info.status) for c in children) == [
        ("1", "FINISHED"),
        ("2", "FAILED"),
    ]


def test_an_agents_mlflow_model_takes_float32_and_float64_observations(store, request, monkeypatch):
    """An ES and a torch agent (the authors', shipped), each logged as its run's MLflow model
    and loaded with `mlflow.pyfunc.load_model`, act on float32 and float64 observations as the
    policy does on the same values; both models have one signature."""
    import mlflow

    from conftest import ACT_DIM, OBS_DIM
    from epoet.eval.agents import file_source

    uri, _ = store
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)  # where load_model("runs:/...") looks
    observations = np.random.default_rng(0).normal(size=(4, OBS_DIM))
    signatures = []
    for agent in ("poet_hexA8/flat.npz", "ppo/0.pt"):
        path = authors("agents", agent)
        with MlflowTracker(uri, request.node.name) as tracker:
            run_id = tracker.start(agent)
            tracker.log_agent(path, "epoet.eval.agent_model", OBS_DIM, ACT_DIM)
        model = mlflow.pyfunc.load_model(f"runs:/{run_id}/agent")
        policy = file_source(path).load()
        for dtype in (np.float32, np.float64):
            given = observations.astype(dtype)
            actions = model.predict(given)
            assert actions.shape == (4, ACT_DIM) and actions.dtype == np.float64, (agent, dtype)
            expected = [policy(obs) for obs in given.astype(np.float64)]
            np.testing.assert_allclose(
                actions, expected, rtol=1e-6, atol=1e-7, err_msg=f"{agent} {dtype.__name__}"
            )
        signatures.append(model.metadata.signature)
    assert signatures[0] == signatures[1]


def test_a_run_started_outside_the_clone_keeps_its_store_beside_its_folder(tmp_path):
    """The default store follows the user, not the installed code: a run started in another
    folder writes its run folder and its MLflow run there, in an experiment tagged as model
    training (docs/runs.md: what MLflow's UI does with the tag)."""
    from conftest import tiny_run

    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    done = subprocess.run(
        [sys.executable, "-m", "epoet", *tiny_run("ppo"), "evaluate=false"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    experiment = client.get_experiment_by_name("epoet")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    (run,) = client.search_runs([experiment.experiment_id])
    assert run.info.status == "FINISHED" and any((tmp_path / "outputs").iterdir())
    assert f"sqlite:///{tmp_path}/mlflow.db" in done.stdout  # the `mlflow ui` line names it
