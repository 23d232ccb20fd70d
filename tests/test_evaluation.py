"""Evaluation, tables, figures and `make paper`, on a store filled by real smoke runs.

One `python -m pipeline.paper --budget smoke` call (every algorithm, one seed, a four-terrain
suite, one episode per terrain) fills a private store; the tests then check what it produced
against the evaluation CSVs, and the bad inputs of each command.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest
from mlflow.types import DataType

from analysis.figures import curve_table
from analysis.tables import formatted, table1, table2
from conftest import (
    ACT_DIM,
    ES_SIZES,
    OBS_DIM,
    authors,
    new_store,
    one_terrain_suite,
    unmet_metrics,
)
from epoet import registry
from epoet.eval.agents import resolve_run
from epoet.eval.suite import LEVELS, SHIPPED, load_suite

ROOT = Path(__file__).resolve().parents[1]

# The module's first test also pays for the `make paper` fixture (every algorithm trained and
# evaluated), which outlasts the default timeout when training runs share the cores.
pytestmark = pytest.mark.timeout(900)


def small_suite(folder: Path) -> Path:
    """The shipped suite's first terrain of each level, in the same format."""
    suite = load_suite()
    picks = [next(t for t in suite.terrains if t.level == level) for level in LEVELS]
    index = json.loads((SHIPPED / "suite.json").read_text())
    index["terrains"] = [e for e in index["terrains"] if e["name"] in {t.name for t in picks}]
    folder.mkdir(parents=True)
    (folder / "suite.json").write_text(json.dumps(index))
    with np.load(SHIPPED / "heights.npz") as heights:
        np.savez(folder / "heights.npz", **{t.name: heights[t.name] for t in picks})
    return folder


@pytest.fixture(scope="module")
def paper(tmp_path_factory, empty_store):
    """A smoke `make paper` into a private store; (store uri, results folder, stdout)."""
    tmp = tmp_path_factory.mktemp("paper")
    uri = new_store(empty_store, tmp)
    suite = small_suite(tmp / "suite")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pipeline.paper",
            "--budget",
            "smoke",
            "--seeds",
            "1",
            "--suite",
            str(suite),
            "--episodes",
            "1",
            "--out",
            str(tmp / "results"),
            "--records",
            str(tmp / "records"),
        ],
        capture_output=True,
        text=True,
        cwd=tmp,
        env={**os.environ, "MLFLOW_TRACKING_URI": uri},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return uri, tmp / "results", proc.stdout, suite


def finished_runs(uri: str) -> dict[str, mlflow.entities.Run]:
    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("paper-smoke")
    runs = client.search_runs([exp.experiment_id], "attributes.status = 'FINISHED'")
    return {r.data.tags["algo"]: r for r in runs if "algo" in r.data.tags}


def test_every_algorithm_is_trained_evaluated_and_logged(paper):
    uri, _, stdout, suite = paper
    runs = finished_runs(uri)
    assert sorted(runs) == sorted(registry.names())
    assert "evaluating 5 run(s) that have no evaluation" in stdout
    client = mlflow.MlflowClient(uri)
    name = load_suite(suite).name
    assert name == "suite"  # a folder's suite is named by its basename
    for algo, run in runs.items():
        metrics = run.data.metrics
        for stat in (
            "success_rate",
            "return_mean",
            "forward_distance_mean",
            "finish_rate",
            *(f"success_rate_{level}" for level in LEVELS),
        ):
            assert f"suite/{name}/{stat}" in metrics, (algo, stat)
        assert not [k for k in metrics if k.startswith("suite/success")]  # never unkeyed
        assert run.data.tags[f"eval_suite/{name}"] == load_suite(suite).fingerprint
        assert "eval_suite" not in run.data.tags
        assert run.data.tags[f"eval_episodes/{name}"] == "1"
        # its family's metrics contract, so MLflow charts and the learning curves compare
        # every algorithm
        assert unmet_metrics(client, run.info.run_id, registry.algorithm(algo).family) == []
        assert not curve_table(client, [run]).empty
        elapsed = [
            m.value
            for m in sorted(
                client.get_metric_history(run.info.run_id, "elapsed"), key=lambda m: m.step
            )
        ]
        assert elapsed == sorted(elapsed)
        names = {a.path for a in client.list_artifacts(run.info.run_id, f"evaluation/{name}")}
        assert names == {
            f"evaluation/{name}/episodes.csv",
            f"evaluation/{name}/actions.npz",
            f"evaluation/{name}/summary.json",
        }
        csv = pd.read_csv(
            client.download_artifacts(run.info.run_id, f"evaluation/{name}/episodes.csv")
        )
        assert len(csv) == 4 and sorted(csv.level) == sorted(LEVELS)
        assert metrics[f"suite/{name}/return_mean"] == pytest.approx(csv["return"].mean())
        assert metrics[f"suite/{name}/forward_distance_mean"] == pytest.approx(
            csv.forward_distance.mean()
        )
        # the suite's episodes: 2.5 x the smoke budget's 50 steps
        assert (csv.length <= 125).all() and (csv.length > 0).all()
        # solved: finished with the paper's 2000 x the smoke budget's score scale
        assert (csv.solved == (csv.finished & (csv["return"] >= 2000 * 0.025))).all()


def test_tables_match_the_evaluation_csvs(paper):
    uri, results, _, _ = paper
    client = mlflow.MlflowClient(uri)
    frames = []
    for algo, run in finished_runs(uri).items():
        csv = pd.read_csv(
            client.download_artifacts(run.info.run_id, "evaluation/suite/episodes.csv")
        )
        frames.append(csv.assign(algo=algo, run_id=run.info.run_id))
    episodes = pd.concat(frames)
    t1 = pd.read_csv(results / "table1_suite.csv").set_index("algo")  # the suite named "suite"
    t2 = pd.read_csv(results / "table2_suite.csv").set_index("algo")
    for algo, rows in episodes.groupby("algo"):
        assert t1.loc[algo, "total_mean"] == pytest.approx(rows.solved.mean())
        for level in LEVELS:
            assert t1.loc[algo, f"{level}_mean"] == pytest.approx(
                rows[rows.level == level].solved.mean()
            )
        easy = rows[rows.level.isin(["easy", "medium"])]["return"]
        assert t2.loc[algo, "return_mean"] == pytest.approx(easy.mean())
        assert t2.loc[algo, "return_max"] == pytest.approx(easy.max())
        assert t2.loc[algo, "episodes"] == 2
    table1_md = (results / "table1_suite.md").read_text()
    assert "| epoet_sac |" in table1_md and "on suite suite" in table1_md.splitlines()[0]
    assert "\\begin{tabular}" in (results / "table2_suite.tex").read_text()


def test_table_statistics_are_over_runs_and_pooled_episodes():
    # two runs of one algorithm: Table 1 averages the per-run rates, Table 2 pools episodes
    episodes = pd.DataFrame(
        {
            "algo": ["ppo"] * 4,
            "run_id": ["a", "a", "b", "b"],
            "level": ["easy", "hard", "easy", "hard"],
            "solved": [True, True, False, True],
            "return": [10.0, 0.0, 30.0, 5.0],
        }
    )
    t1, t2 = table1(episodes).iloc[0], table2(episodes).iloc[0]
    assert t1.easy_mean == 0.5 and t1.easy_std == pytest.approx(np.std([1, 0], ddof=1))
    assert t1.total_mean == pytest.approx(0.75) and t1.runs == 2
    assert t2.return_mean == 20.0 and t2.return_max == 30.0 and t2.episodes == 2
    # the suite has no medium or extreme terrain: those columns are left out, not shown as NaN
    shown, _ = formatted(table1(episodes), table2(episodes))
    assert list(shown.columns) == ["algorithm", "runs", "easy", "hard", "total"]
    assert shown.iloc[0].hard == "100.0 ± 0.0"


def test_figures_are_drawn_from_the_store(paper):
    _, results, _, _ = paper
    figures = results / "figures"
    for name in ("learning_curves", "generations", "annecs", "tsne"):
        assert (figures / f"{name}.png").stat().st_size > 10_000, name
    curves = pd.read_csv(figures / "learning_curves.csv")
    assert set(curves.algo) == set(registry.names()) and set(curves.axis) == {
        "env_steps",
        "elapsed",
    }
    assert set(pd.read_csv(figures / "generations.csv").algo) == {"epoet", "epoet_sac"}
    assert set(pd.read_csv(figures / "tsne.csv").algo) == set(registry.names())
    assert (figures / "suite_gallery.png").is_file()
    assert len(list(figures.glob("admitted_*.png"))) == 2


def one_line_error(capsys, call, *words: str) -> None:
    """`call()` exits with code 2 and one `error:` line on stderr naming `words`."""
    try:
        code = call()
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2, err[-2000:]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-2000:]
    for word in words:
        assert word in lines[0], lines[0]


def test_bad_inputs_are_one_line_errors(paper, tmp_path, monkeypatch, capsys):
    from analysis import tables
    from epoet.eval import evaluate
    from pipeline import paper as paper_cli

    uri, _, _, suite = paper
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.chdir(tmp_path)
    runs = finished_runs(uri)
    one_line_error(
        capsys,
        lambda: evaluate.main(["run=0123456789abcdef0123456789abcdef"]),
        "is not in the MLflow store",
    )
    (tmp_path / "empty_run").mkdir()
    one_line_error(
        capsys, lambda: evaluate.main([f"run={tmp_path / 'empty_run'}"]), "has no policy"
    )
    broken = tmp_path / "broken_suite"
    shutil.copytree(suite, broken)
    (broken / "heights.npz").unlink()
    one_line_error(
        capsys,
        lambda: evaluate.main([f"run={runs['epoet'].info.run_id}", f"suite={broken}"]),
        "has no heights.npz",
    )
    one_line_error(
        capsys, lambda: evaluate.main(["run=nothing-here"]), "there is no such file or folder"
    )
    one_line_error(capsys, lambda: evaluate.main(["episodes=0", "run=x"]), "episodes")
    empty = f"sqlite:///{tmp_path}/empty.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", empty)
    one_line_error(capsys, lambda: tables.main([]), "no MLflow store")
    mlflow.MlflowClient(empty).create_experiment("epoet")
    capsys.readouterr()  # MLflow's own log lines from creating the store
    one_line_error(capsys, lambda: tables.main([]), "no finished runs", "make paper")
    one_line_error(capsys, lambda: paper_cli.main(["--budget", "huge"]), "unknown budget")
    # nothing was written to the runs by the failed calls
    after = finished_runs(uri)
    assert {a: r.data.metrics for a, r in after.items()} == {
        a: r.data.metrics for a, r in runs.items()
    }


def flat_course(folder: Path) -> Path:
    """A suite of one flat terrain whose course is 2 m, walked in at most 500 steps by an agent
    of the paper's 2000-step episodes."""
    return one_terrain_suite(
        folder, 2000, 0.25, name="flat", heights=np.zeros((40, 40)), finish_x=-4.0, max_height=0.01
    )


def test_an_episode_is_solved_when_it_finishes_with_the_scaled_return(mlflow_uri, tmp_path):
    """ "Solved" is the paper's: the finish line reached with a return of at least solve_score x
    the run's score scale. The authors' ePOET agent, in a run folder whose budget scales scores
    by 0.5, finishes the flat 2 m course every time (returns of about 800-900, the finish bonus
    of 500 included); an agent that stands still never finishes."""
    from epoet.config import compose, load, validate
    from epoet.core.checkpoint import save_checkpoint
    from epoet.eval.evaluate import evaluate_run
    from epoet.rollout.policy import init_params

    suite = flat_course(tmp_path / "suite")
    walker = tmp_path / "walker"
    (walker / "policies").mkdir(parents=True)
    shutil.copy(authors("agents", "poet_hexA8", "flat.npz"), walker / "policies" / "env0.npz")
    config = load(["budget=paper", "budget.score_scale=0.5"])  # the paper's agent: RK4
    save_checkpoint(
        walker / "checkpoint.pkl", {"algo": "epoet", "config": dataclasses.asdict(config)}
    )
    standing = tmp_path / "standing.npz"
    np.savez(
        standing, theta=np.zeros_like(init_params(0, ES_SIZES)), layer_sizes=np.array(ES_SIZES)
    )

    def episodes(run: Path, solve_score: float) -> pd.DataFrame:
        result, _, _ = evaluate_run(
            validate(
                compose(
                    [
                        f"run={run}",
                        f"suite={suite}",
                        "episodes=3",
                        "processes=1",
                        f"solve_score={solve_score}",
                        f"out={tmp_path / 'out'}",
                    ],
                    config_name="evaluate",
                )
            ),
            progress=False,
        )
        assert result.metrics["suite/suite/success_rate"] == result.episodes.solved.mean()
        return result.episodes

    low = episodes(walker, 1400.0)  # the bar: 0.5 x 1400 = 700
    assert low.finished.all() and (low["return"] > 700).all() and low.solved.all()
    high = episodes(walker, 2000.0)  # the bar: 1000, above every return
    assert high.finished.all() and (high["return"] < 1000).all() and not high.solved.any()
    still = episodes(standing, -1e9)  # every return clears the bar; none finishes
    assert not still.finished.any() and not still.solved.any()


def test_evaluating_a_run_of_another_store_leaves_no_store_behind(tmp_path, monkeypatch, capsys):
    """A run folder's checkpoint names its MLflow run. Looked for in a store that does not exist
    (the default, the project's mlflow.db, here moved into tmp), the command fails in one line
    and leaves no empty store there or in the cwd; with tracking.uri naming the run's store it
    evaluates the run and logs to it."""
    from epoet.config import load
    from epoet.core.checkpoint import save_checkpoint
    from epoet.eval import evaluate
    from epoet.rollout.policy import init_params
    from epoet.tracking import MlflowTracker

    elsewhere = f"sqlite:///{tmp_path / 'elsewhere' / 'mlflow.db'}"
    (tmp_path / "elsewhere").mkdir()
    with MlflowTracker(elsewhere, "epoet") as tracker:
        run_id = tracker.start("epoet-s0")
    folder = tmp_path / "run"
    (folder / "policies").mkdir(parents=True)
    np.savez(
        folder / "policies" / "env0.npz",
        theta=init_params(0, ES_SIZES),
        layer_sizes=np.array(ES_SIZES),
    )
    save_checkpoint(
        folder / "checkpoint.pkl",
        {"run_id": run_id, "algo": "epoet", "config": dataclasses.asdict(load([]))},
    )
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    default = cwd / "mlflow.db"  # the default store: where the command started
    capsys.readouterr()  # MLflow's own log lines from creating the run's store
    one_line_error(
        capsys,
        lambda: evaluate.main([f"run={folder}"]),
        f"run {run_id} is not in the MLflow store sqlite:///{default}",
    )
    assert not default.exists() and list(cwd.iterdir()) == []

    suite = flat_course(tmp_path / "suite")
    evaluate.main(
        [
            f"run={folder}",
            f"tracking.uri={elsewhere}",
            f"suite={suite}",
            "episodes=1",
            "processes=1",
        ]
    )
    assert "suite/suite/success_rate" in mlflow.MlflowClient(elsewhere).get_run(run_id).data.metrics
    assert not default.exists() and list(cwd.iterdir()) == []


def test_resume_auto_skips_a_finished_job_and_continues_an_interrupted_or_extended_one(
    compose, mlflow_uri, tmp_path, monkeypatch
):
    from epoet.core.checkpoint import load_checkpoint
    from epoet.core.lifecycle import Stopped
    from epoet.run import run
    from epoet.run_state import DONE
    from epoet.tracking.writer import MlflowTracker

    overrides = ["algo=epoet", "budget=smoke", "workers.num=1", "resume=auto"]
    finished, interrupted = tmp_path / "finished", tmp_path / "interrupted"
    first = run(compose(overrides), finished)
    assert first is not None and (finished / DONE).is_file()
    assert run(compose(overrides), finished) is None  # finished: skipped

    # The other job gets a Ctrl-C in its first iteration (when that iteration's metrics are
    # logged): it stops at the iteration's end with a checkpoint, as `make paper` interrupted.
    log_metrics, trained, finished_marked = MlflowTracker.log_metrics, [], []

    def log_and_interrupt(self, step, metrics):
        log_metrics(self, step, metrics)
        trained.append(step)
        finished_marked.append((finished / DONE).exists())
        if trained == [0]:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(MlflowTracker, "log_metrics", log_and_interrupt)
    with pytest.raises(Stopped):
        run(compose(overrides), interrupted)
    stopped = load_checkpoint(interrupted)
    assert stopped["open_ended"]["iteration"] == 1 < first.iteration  # work left to do
    assert not (interrupted / DONE).exists()

    again = run(compose(overrides), interrupted)  # continues from iteration 1
    assert again is not None and again.iteration == first.iteration
    assert trained == list(range(first.iteration))  # iterations 1.. trained once
    assert (interrupted / DONE).is_file()
    done, straight = load_checkpoint(interrupted), load_checkpoint(finished)
    assert done["run_id"] == stopped["run_id"]  # the resume continued its run
    assert (
        done["open_ended"]["env_steps"] == straight["open_ended"]["env_steps"]
    )  # as if never stopped
    assert len(done["open_ended"]["active"]) == len(straight["open_ended"]["active"])
    for a, b in zip(done["open_ended"]["active"], straight["open_ended"]["active"]):
        np.testing.assert_array_equal(a["es"]["theta"], b["es"]["theta"])
    client = mlflow.MlflowClient(mlflow_uri)
    runs = client.search_runs([client.get_experiment_by_name("epoet").experiment_id])
    assert len(runs) == 2 and {r.info.status for r in runs} == {"FINISHED"}
    steps = client.get_metric_history(stopped["run_id"], "best_score")
    assert sorted(m.step for m in steps) == list(range(first.iteration))  # each once

    # Asked for more than it finished on, a finished job continues from its final state; its
    # DONE is gone while it trains (an interruption would leave it to continue), then back.
    trained.clear()
    finished_marked.clear()
    longer = [*overrides, f"budget.iterations={first.iteration + 1}"]
    more = run(compose(longer), finished)
    assert more is not None and more.iteration == first.iteration + 1
    assert trained == [first.iteration] and finished_marked == [False]
    assert (finished / DONE).is_file()
    assert load_checkpoint(finished)["run_id"] == straight["run_id"]  # the same MLflow run
    assert run(compose(longer), finished) is None  # that budget reached: skipped again
    # A DONE from before it recorded the budget (the run id alone) stays finished.
    (finished / DONE).write_text(f"{straight['run_id']}\n")
    assert run(compose([*overrides, f"budget.iterations={first.iteration + 2}"]), finished) is None


def test_a_training_run_ends_with_its_evaluation(compose, mlflow_uri: str, tmp_path: Path) -> None:
    """Without a second command the run's MLflow record carries the suite's metrics, at the
    budget's episode count and the run's course scale; evaluate=false skips it."""
    from epoet.core.checkpoint import load_checkpoint
    from epoet.run import run

    smoke = ["budget=smoke", "workers.num=1", "algo.es.hidden=[8]", "budget.iterations=1"]
    run(compose([*smoke, "evaluate=true"]), tmp_path / "run")
    run_id = load_checkpoint(tmp_path / "run" / "checkpoint.pkl")["run_id"]
    record = mlflow.MlflowClient(mlflow_uri).get_run(run_id).data
    assert "suite/shipped/success_rate" in record.metrics  # keyed by the shipped suite's name
    assert record.tags["eval_suite/shipped"] == load_suite().fingerprint
    assert record.tags["eval_episodes/shipped"] == "1"
    assert record.tags["eval_course_scale/shipped"] == "0.025"
    assert (tmp_path / "run" / "evaluation" / "shipped" / "episodes.csv").is_file()
    run(compose([*smoke, "evaluate=false"]), tmp_path / "plain")
    run_id = load_checkpoint(tmp_path / "plain" / "checkpoint.pkl")["run_id"]
    assert not [
        k
        for k in mlflow.MlflowClient(mlflow_uri).get_run(run_id).data.metrics
        if k.startswith("suite/")
    ]


def test_every_agent_loads_as_an_mlflow_model_and_acts_as_the_product(paper, monkeypatch):
    """`mlflow.pyfunc.load_model("runs:/<id>/agent")` is each run's exported agent: the same
    actions as the policy `epoet.eval.evaluate run=<id>` resolves, on the same observations; and
    `run=runs:/<id>/agent` resolves to that agent too."""
    uri, _, _, _ = paper
    observations = np.random.default_rng(0).normal(size=(5, OBS_DIM))
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)  # where load_model("runs:/...") looks
    for algo, run in finished_runs(uri).items():
        model = mlflow.pyfunc.load_model(f"runs:/{run.info.run_id}/agent")
        # one double column per observation entry (float32 or float64 arrays: test_tracking)
        assert model.metadata.get_input_schema().input_types() == [DataType.double] * OBS_DIM
        assert model.metadata.get_output_schema().inputs[0].shape == (-1, ACT_DIM), algo
        actions = model.predict(observations)
        policy = resolve_run(run.info.run_id, uri).agent.load()
        assert actions.shape == (5, ACT_DIM)
        np.testing.assert_allclose(actions, [policy(o) for o in observations], err_msg=algo)
        via_uri = resolve_run(f"runs:/{run.info.run_id}/agent", uri)
        assert (
            via_uri.run_id == run.info.run_id
            and via_uri.label == resolve_run(run.info.run_id, uri).label
        )
    models = mlflow.MlflowClient(uri).search_logged_models(
        [mlflow.MlflowClient(uri).get_experiment_by_name("paper-smoke").experiment_id]
    )
    assert sorted(m.source_run_id for m in models) == sorted(
        r.info.run_id for r in finished_runs(uri).values()
    )  # the UI's Models column


# --- what the smoke sweep left in MLflow, read back from the store: one meaning per metric, the
# params the jobs ran with and only those that apply to them, a parent run that reads as the
# sweep's result.


def _history(uri: str, run: mlflow.entities.Run, key: str) -> list[float]:
    points = mlflow.MlflowClient(uri).get_metric_history(run.info.run_id, key)
    return [p.value for p in sorted(points, key=lambda p: p.step)]


def test_best_score_is_the_running_best_of_score(paper) -> None:
    uri = paper[0]
    for algo, run in finished_runs(uri).items():
        score, best = _history(uri, run, "score"), _history(uri, run, "best_score")
        assert len(best) == len(score) >= 2, algo
        assert best == list(np.maximum.accumulate(score)), algo


def test_time_metrics_have_one_meaning(paper) -> None:
    """`elapsed` is cumulative training seconds everywhere; per-step times have their own names."""
    uri = paper[0]
    for algo, run in finished_runs(uri).items():
        step_time = "time/iteration" if algo.startswith("epoet") else "time/batch"
        assert "wall_time" not in run.data.metrics and step_time in run.data.metrics, algo
        elapsed = _history(uri, run, "elapsed")
        assert elapsed == sorted(elapsed) and elapsed[-1] > 0, algo


def test_params_are_the_values_the_run_used_and_only_those_it_reads(paper) -> None:
    uri = paper[0]
    runs = {algo: run.data.params for algo, run in finished_runs(uri).items()}
    for algo, params in runs.items():
        # make paper's default: one job per core, each with the cores it leaves it
        assert params["workers.num"] == "1", algo  # not "None"
        assert params["tracking.uri"] == uri and "resume" not in params, algo
    sac, epoet = runs["sac"], runs["epoet"]
    assert sac["terrain.kind"] == "bowl"
    assert not [k for k in sac if k.startswith(("terrain.cppn", "terrain.mutation"))]
    assert "budget.iterations" not in sac and "budget.frames" in sac
    assert "terrain.cppn.activation_options" in epoet and "terrain.mutation.max_tries" in epoet
    assert "budget.iterations" in epoet and "budget.frames" not in epoet
    assert "algo.frames_per_iteration" not in epoet
    assert "algo.frames_per_iteration" in runs["epoet_sac"]


def test_the_sweep_parent_reads_as_the_sweep(paper) -> None:
    uri, _, stdout, _ = paper
    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("paper-smoke")
    (parent,) = [
        r
        for r in client.search_runs([exp.experiment_id])
        if "mlflow.parentRunId" not in r.data.tags
    ]
    runs = finished_runs(uri)
    assert (
        parent.data.tags["algos"] == ",".join(registry.names()) and parent.data.tags["seeds"] == "1"
    )
    assert parent.data.tags["budget"] == "smoke"
    assert len(parent.data.tags["mlflow.source.git.commit"]) == 40
    assert (
        parent.data.params["algo"] == ",".join(registry.names())
        and parent.data.params["seed"] == "1"
    )
    for algo, run in runs.items():
        assert parent.data.metrics[f"sweep/{algo}/finished"] == 1
        assert parent.data.metrics[f"sweep/{algo}/score_mean"] == run.data.metrics["score"]
        line = next(li for li in stdout.splitlines() if li.startswith(f"[sweep] {algo} seed=1"))
        assert "FINISHED" in line and run.info.run_id in line


def test_make_paper_writes_the_statistics_and_records_that_rebuild_its_tables(paper, tmp_path):
    """The IQM and probability-of-improvement tables and figures beside Tables 1-2, and the
    evaluation records (`--records`) rebuild every table without the store."""
    from analysis.tables import tables_from_records

    uri, results, stdout, suite = paper
    for stem in ("iqm_suite", "poi_suite"):
        for ext in ("csv", "md", "tex", "png"):
            assert (results / f"{stem}.{ext}").stat().st_size > 0, (stem, ext)
    iqm = pd.read_csv(results / "iqm_suite.csv")
    assert sorted(iqm.algo.unique()) == sorted(registry.names()) and set(iqm.score) == {
        "success",
        "return",
    }
    assert (iqm.ci_low <= iqm.iqm).all() and (iqm.iqm <= iqm.ci_high).all()
    assert set(iqm.resampled) == {"terrains only (1 run)"}  # one seed: said in the output
    assert "intervals come from the terrains only" in (results / "iqm_suite.md").read_text()
    poi = pd.read_csv(results / "poi_suite.csv")
    assert len(poi) == 2 * 10  # every pair of the five algorithms, success and return
    assert ((poi.ci_low <= poi.poi) & (poi.poi <= poi.ci_high)).all()

    records = results.parent / "records"
    runs = finished_runs(uri)
    assert sorted(p.name for p in records.iterdir()) == sorted(f"{a}_s1" for a in registry.names())
    for algo, run in runs.items():
        info = json.loads((records / f"{algo}_s1" / "run.json").read_text())
        assert info["run_id"] == run.info.run_id and info["experiment"] == "paper-smoke"
        # a sweep job: the command is its job folder's Hydra overrides
        assert info["command_source"] == "overrides", info
        assert f"algo={algo}" in info["command"] and "budget=smoke" in info["command"]
        assert info["sweep"]["command"].startswith("python -m epoet -m ")
        evaluation = info["evaluations"]["suite"]
        assert evaluation["commit"] == run.data.tags["eval_commit/suite"]  # make paper's
        assert evaluation["episodes_per_terrain"] == 1
    rebuilt = tmp_path / "rebuilt"
    tables_from_records(records, rebuilt, str(suite))
    for name in (
        "table1_suite.csv",
        "table2_suite.csv",
        "iqm_suite.csv",
        "poi_suite.csv",
        "table1_suite.md",
        "iqm_suite.md",
    ):
        assert (rebuilt / name).read_bytes() == (results / name).read_bytes(), name
