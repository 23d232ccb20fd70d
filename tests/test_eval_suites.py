"""One run, several suites: each evaluation is keyed by its suite's name in the run (metrics,
tags, artifacts, local results), tables are per suite, a repeated evaluation logs each metric
once, and runs logged with the old unkeyed names are still read."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import pandas as pd
import pytest

from conftest import new_store, subset_suite
from epoet.config import compose, validate
from epoet.eval import suite as suite_module
from epoet.eval.episodes import COLUMNS
from epoet.eval.evaluate import evaluate_run
from epoet.eval.suite import load_suite

# one ES iteration of a tiny ePOET: an MLflow run with an exported agent, in seconds
SMOKE = [
    "algo=epoet",
    "budget=smoke",
    "workers.num=1",
    "algo.es.hidden=[8]",
    "budget.iterations=1",
    "evaluate=false",
]
STATS = ("success_rate", "return_mean", "forward_distance_mean", "finish_rate")


@pytest.fixture(scope="module")
def trained(tmp_path_factory, empty_store):
    """(store uri, run folder, MLflow run id) of one tiny trained run, not yet evaluated."""
    from epoet.core.checkpoint import load_checkpoint
    from epoet.run import run

    tmp = tmp_path_factory.mktemp("trained")
    uri = new_store(empty_store, tmp)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MLFLOW_TRACKING_URI", uri)
        run(compose(SMOKE), tmp / "run")
        yield uri, tmp / "run", load_checkpoint(tmp / "run" / "checkpoint.pkl")["run_id"]


def evaluate_cfg(uri: str, run_dir: Path, suite: str, episodes: int = 1):
    return validate(
        compose(
            [
                f"run={run_dir}",
                f"suite={suite}",
                f"episodes={episodes}",
                "processes=1",
                f"tracking.uri={uri}",
            ],
            config_name="evaluate",
        )
    )


def test_one_run_keeps_each_suites_evaluation_side_by_side(trained, tmp_path, monkeypatch, capsys):
    from analysis.tables import make_tables
    from epoet.eval.evaluate import main

    uri, run_dir, run_id = trained
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    alpha = subset_suite(tmp_path / "alpha", [("easy", 0), ("medium", 0)])
    # the paper suite (the other engineer's data may or may not be there): other terrains
    monkeypatch.setenv("EPOET_CACHE", str(tmp_path))  # so its folder counts as converted
    paper_data = subset_suite(tmp_path / "paper_data", [("easy", 1), ("medium", 1)])
    monkeypatch.setitem(
        suite_module.SUITES,
        "paper",
        lambda: paper_data,
    )
    printed = {}
    for name, arg in (("alpha", str(alpha)), ("paper", "paper")):
        main([f"run={run_dir}", f"suite={arg}", "episodes=1", "processes=1"])
        printed[name] = capsys.readouterr().out
    suites = {"alpha": load_suite(alpha), "paper": load_suite("paper")}
    assert suites["alpha"].fingerprint != suites["paper"].fingerprint

    client = mlflow.MlflowClient(uri)
    record = client.get_run(run_id).data
    assert not [k for k in record.metrics if k.startswith("suite/success")]  # nothing unkeyed
    assert "eval_suite" not in record.tags
    for name, suite in suites.items():
        terrains = sorted(t.name for t in suite.terrains)
        # the artifacts: this suite's episodes only
        listed = {a.path for a in client.list_artifacts(run_id, f"evaluation/{name}")}
        assert listed == {
            f"evaluation/{name}/{f}" for f in ("episodes.csv", "actions.npz", "summary.json")
        }
        csv = pd.read_csv(
            client.download_artifacts(
                run_id, f"evaluation/{name}/episodes.csv", str(tmp_path / "dl" / name)
            )
        )
        assert sorted(csv.terrain) == terrains
        # the metrics: of this suite's episodes, per level of this suite
        for stat in STATS:
            assert f"suite/{name}/{stat}" in record.metrics, (name, stat)
        assert record.metrics[f"suite/{name}/return_mean"] == pytest.approx(csv["return"].mean())
        assert {k for k in record.metrics if k.startswith(f"suite/{name}/success_rate_")} == {
            f"suite/{name}/success_rate_easy",
            f"suite/{name}/success_rate_medium",
        }
        # the tags
        assert record.tags[f"eval_suite/{name}"] == suite.fingerprint
        assert record.tags[f"eval_episodes/{name}"] == "1"
        assert record.tags[f"eval_course_scale/{name}"] == "0.025"
        # the local results
        summary = json.loads((run_dir / "evaluation" / name / "summary.json").read_text())
        assert summary["suite_name"] == name and summary["suite_fingerprint"] == suite.fingerprint
        # where it writes, said before it starts (and again at the end)
        folder = (run_dir / "evaluation" / name).absolute()
        assert f"  writing to {folder}/ (out=<folder> to choose)" in printed[name].splitlines()
        assert f"  results:  {folder}/ (episodes.csv, actions.npz, summary.json)" in printed[name]
        # the printed summary: which suite, and a render hint on one of its terrains
        render = next(line for line in printed[name].splitlines() if "render:" in line)
        assert printed[name].count(f"suite {name}: success rate") == 1
        assert render.split("terrain=")[1].split()[0] in terrains
    assert render.endswith(" suite=paper")
    assert next(li for li in printed["alpha"].splitlines() if "render:" in li).endswith(
        f" suite={alpha}"
    )

    # the tables of each suite read that suite's episodes
    returns = {}
    for name, arg in (("alpha", str(alpha)), ("paper", "paper")):
        written = make_tables("epoet", tmp_path / "results", arg, [run_id], uri)
        assert tmp_path / "results" / f"table2_{name}.csv" in written
        table2 = pd.read_csv(tmp_path / "results" / f"table2_{name}.csv").iloc[0]
        csv = pd.read_csv(run_dir / "evaluation" / name / "episodes.csv")
        assert table2.episodes == 2
        assert table2.return_mean == pytest.approx(csv["return"].mean())
        assert table2.return_max == pytest.approx(csv["return"].max())
        title = (tmp_path / "results" / f"table1_{name}.md").read_text().splitlines()[0]
        assert f"on suite {name} " in title
        returns[name] = table2.return_mean
    assert returns["alpha"] != returns["paper"]  # other terrains, so other returns


def test_a_repeated_evaluation_logs_each_metric_once(trained, tmp_path):
    """A run killed during its end-of-run evaluation evaluates again on resume: the same
    results are not logged a second time. Another evaluation's results (more episodes) are."""
    uri, run_dir, run_id = trained
    gamma = subset_suite(tmp_path / "gamma", [("hard", 0)])
    client = mlflow.MlflowClient(uri)
    first, _, _ = evaluate_run(evaluate_cfg(uri, run_dir, str(gamma)), progress=False)
    again, _, _ = evaluate_run(evaluate_cfg(uri, run_dir, str(gamma)), progress=False)
    assert again.metrics == first.metrics and len(first.metrics) == 5
    for key, value in first.metrics.items():
        points = client.get_metric_history(run_id, key)
        assert [(p.step, p.value) for p in points] == [(0, value)], key
    more, _, _ = evaluate_run(evaluate_cfg(uri, run_dir, str(gamma), episodes=2), progress=False)
    key = "suite/gamma/return_mean"
    assert more.metrics[key] != first.metrics[key]
    assert sorted(p.value for p in client.get_metric_history(run_id, key)) == sorted(
        [first.metrics[key], more.metrics[key]]
    )
    assert client.get_run(run_id).data.metrics[key] == more.metrics[key]  # the latest wins


def test_runs_logged_with_the_unkeyed_names_are_read_as_before(tmp_path, empty_store):
    """A run evaluated before evaluations were keyed by suite (`eval_suite`,
    `eval_course_scale`, `evaluation/episodes.csv`, `suite/success_rate`) is tabled on the
    suite its `eval_suite` fingerprint names, and on no other."""
    from analysis.store import AnalysisError, unevaluated
    from analysis.tables import make_tables
    from epoet.sweep import job_lines

    delta = load_suite(subset_suite(tmp_path / "delta", [("easy", 0), ("medium", 0)]))
    uri = new_store(empty_store, tmp_path)
    client = mlflow.MlflowClient(uri)
    exp = client.create_experiment("old")
    run_id = client.create_run(exp, tags={"algo": "ppo", "seed": "1"}).info.run_id
    client.set_tag(run_id, "eval_suite", delta.fingerprint)
    client.set_tag(run_id, "eval_course_scale", "0.5")
    client.log_metric(run_id, "suite/success_rate", 0.25, step=0)
    terrains = [t for t in delta.terrains for _ in range(2)]
    episodes = pd.DataFrame(
        [
            [t.name, t.level, t.roughness, k % 2, k, ret, solved, solved, 1.0, 10, 0.0]
            for k, (t, ret, solved) in enumerate(
                zip(terrains, [10.0, 30.0, 50.0, 70.0], [True, False, False, False])
            )
        ],
        columns=COLUMNS,
    )
    (tmp_path / "old").mkdir()
    episodes.to_csv(tmp_path / "old" / "episodes.csv", index=False)
    client.log_artifact(run_id, str(tmp_path / "old" / "episodes.csv"), "evaluation")
    client.set_terminated(run_id, "FINISHED")

    make_tables("old", tmp_path / "results", str(tmp_path / "delta"), tracking_uri=uri)
    table1 = pd.read_csv(tmp_path / "results" / "table1_delta.csv").iloc[0]
    table2 = pd.read_csv(tmp_path / "results" / "table2_delta.csv").iloc[0]
    assert table1.total_mean == 0.25 and table1.easy_mean == 0.5 and table1.medium_mean == 0.0
    assert table2.return_mean == 40.0 and table2.return_max == 70.0
    assert "course scale 0.5" in (tmp_path / "results" / "table1_delta.md").read_text()
    run = client.get_run(run_id)
    assert unevaluated([run], delta) == [] and unevaluated([run], load_suite()) == [run]
    with pytest.raises(AnalysisError, match="have no evaluation on suite shipped"):
        make_tables("old", tmp_path / "results", tracking_uri=uri)
    assert "solved=25%" in job_lines([run])[0]  # the old unkeyed metric, as the shipped suite's
