"""Evaluation records (pipeline.records writes, analysis.records reads): exported from a real
store of tiny trained and evaluated runs, the tables they rebuild without the store are the
store's; exporting again overwrites a run's record and nothing else."""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

import mlflow
import pandas as pd
import pytest

from analysis.records import read_records, record_episodes
from analysis.store import AnalysisError
from analysis.tables import make_tables, tables_from_records
from conftest import new_store, subset_suite
from epoet.config import compose, validate
from epoet.eval.episodes import COLUMNS
from epoet.eval.evaluate import evaluate_run
from epoet.eval.suite import load_suite
from pipeline.records import export

EXPERIMENT = "records"
RUNS = {
    ("epoet", 1): ["algo.es.hidden=[8]", "budget.iterations=1"],
    ("epoet", 2): ["algo.es.hidden=[8]", "budget.iterations=1"],
    ("ppo", 1): ["budget.frames=200"],
}


@pytest.fixture(scope="module")
def store(tmp_path_factory, empty_store):
    """(uri, suite folder): three tiny runs (ePOET seeds 1-2, PPO seed 1) each evaluated on a
    two-terrain suite, two episodes per terrain."""
    from epoet.run import run

    tmp = tmp_path_factory.mktemp("records")
    uri = new_store(empty_store, tmp)
    suite = subset_suite(tmp / "duo", [("easy", 0), ("medium", 0)])
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MLFLOW_TRACKING_URI", uri)
        for (algo, seed), extra in RUNS.items():
            folder = tmp / f"{algo}_s{seed}"
            run(
                compose(
                    [
                        f"algo={algo}",
                        "budget=smoke",
                        "workers.num=1",
                        f"seed={seed}",
                        "evaluate=false",
                        f"tracking.experiment={EXPERIMENT}",
                        *extra,
                    ]
                ),
                folder,
            )
            evaluate_run(
                validate(
                    compose(
                        [f"run={folder}", f"suite={suite}", "episodes=2", "processes=1"],
                        config_name="evaluate",
                    )
                ),
                progress=False,
            )
    return uri, suite


def files(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_records_rebuild_the_stores_tables(store, tmp_path, capsys):
    uri, suite = store
    written = export(EXPERIMENT, tmp_path / "records", uri)
    assert sorted(p.name for p in written) == ["epoet_s1", "epoet_s2", "ppo_s1"]
    from_store = make_tables(EXPERIMENT, tmp_path / "store", str(suite), tracking_uri=uri)
    from_records = tables_from_records(tmp_path / "records", tmp_path / "from_records", str(suite))
    assert [p.name for p in from_store] == [p.name for p in from_records]
    names = {p.name for p in from_store}
    assert {"table1_duo.csv", "table2_duo.md", "iqm_duo.csv", "iqm_duo.png", "poi_duo.tex"} <= names
    # every file the same, byte for byte: tables, statistics and figures
    assert files(tmp_path / "store") == files(tmp_path / "from_records")

    client = mlflow.MlflowClient(uri)
    runs = {
        (r.data.tags["algo"], int(r.data.tags["seed"])): r
        for r in client.search_runs([client.get_experiment_by_name(EXPERIMENT).experiment_id])
    }
    for (algo, seed), run in runs.items():
        folder = tmp_path / "records" / f"{algo}_s{seed}"
        info = json.loads((folder / "run.json").read_text())
        tags, metrics = run.data.tags, run.data.metrics
        assert (info["algo"], info["seed"], info["budget"]) == (algo, str(seed), "smoke")
        assert info["run_id"] == run.info.run_id and info["run_name"] == f"{algo}-s{seed}"
        assert info["experiment"] == EXPERIMENT
        assert info["commit"] == tags["mlflow.source.git.commit"]
        # not a sweep job: the command is rebuilt from the params, and is the one that ran
        assert info["command_source"] == "params"
        words = shlex.split(info["command"])
        assert words[:6] == [
            "python",
            "-m",
            "epoet",
            f"algo={algo}",
            "budget=smoke",
            f"seed={seed}",
        ]
        assert set(words[6:]) == {
            *RUNS[algo, seed],
            "evaluate=false",
            "workers.num=1",
            f"tracking.experiment={EXPERIMENT}",
        }
        training = info["training"]
        assert training["wall_time_s"] == metrics["elapsed"]
        assert training["env_steps"] == metrics["env_steps"]
        assert training["stop_reason"] == tags["stop_reason"]
        if algo == "epoet":
            assert training["iterations"] == 1
        else:
            assert training["frames"] == metrics["frames"]
        loads = [m.value for m in client.get_metric_history(run.info.run_id, "system/load1")]
        assert info["load"]["points"] == len(loads) >= 1
        assert info["load"]["max"] == max(loads)
        assert info["load"]["mean"] == pytest.approx(sum(loads) / len(loads))
        evaluation = info["evaluations"]["duo"]
        assert evaluation["fingerprint"] == load_suite(suite).fingerprint
        assert evaluation["course_scale"] == tags["eval_course_scale/duo"]
        assert evaluation["episodes_per_terrain"] == 2
        assert evaluation["success_rate"] == metrics["suite/duo/success_rate"]
        assert evaluation["time"] is not None
        for name in ("summary.json", "episodes.csv"):
            logged = Path(
                client.download_artifacts(
                    run.info.run_id,
                    f"evaluation/duo/{name}",
                    str(tmp_path / "dl" / run.info.run_id),
                )
            )
            assert (folder / "duo" / name).read_bytes() == logged.read_bytes()


def test_exporting_again_overwrites_its_runs_and_keeps_other_records(store, tmp_path):
    uri, suite = store
    out = tmp_path / "records"
    export(EXPERIMENT, out, uri)
    first = files(out)
    other = out / "vmpo_s9"
    other.mkdir()
    (other / "run.json").write_text("another experiment's record\n")
    (out / "epoet_s1" / "gone").mkdir()  # a suite folder the run no longer lists
    (out / "epoet_s1" / "gone" / "episodes.csv").write_text("stale\n")
    (out / "ppo_s1" / "duo" / "episodes.csv").write_text("damaged\n")
    export(EXPERIMENT, out, uri)
    again = files(out)
    assert again.pop("vmpo_s9/run.json") == b"another experiment's record\n"
    assert again == first  # the same store gives the same files; the stale folder is gone


def test_records_of_authors_agents_and_of_old_unkeyed_evaluations(tmp_path, empty_store):
    """An authors' agent is named by its agent, with its provenance instead of a command; a run
    logged before evaluations were keyed by suite is exported under its suite's name."""
    uri = new_store(empty_store, tmp_path)
    client = mlflow.MlflowClient(uri)
    shipped, paper = load_suite("shipped"), load_suite("paper")
    episodes = pd.DataFrame(
        [
            [t.name, t.level, t.roughness, 0, 7, 5.0, False, False, 1.0, 10, 0.0]
            for t in shipped.terrains[:2]
        ],
        columns=COLUMNS,
    )
    (tmp_path / "eval").mkdir()
    episodes.to_csv(tmp_path / "eval" / "episodes.csv", index=False)
    (tmp_path / "eval" / "summary.json").write_text("{}\n")

    def finished(
        experiment: str,
        tags: dict[str, str],
        eval_tags: dict[str, str],
        folder: str,
        params: dict[str, str] = {},
    ) -> str:
        exp = client.get_experiment_by_name(experiment) or client.get_experiment(
            client.create_experiment(experiment)
        )
        run_id = client.create_run(exp.experiment_id, tags=tags).info.run_id
        for key, value in {**eval_tags, **params}.items():
            (client.log_param if key in params else client.set_tag)(run_id, key, value)
        for name in ("episodes.csv", "summary.json"):
            client.log_artifact(run_id, str(tmp_path / "eval" / name), folder)
        client.set_terminated(run_id, "FINISHED")
        return run_id

    agent = finished(
        "reference",
        {
            "algo": "epoet_sac",
            "seed": "sac_58",
            "reference": "poet_twin22/sac_58",
            "budget": "paper",
        },
        {
            "eval_suite/paper": paper.fingerprint,
            "eval_course_scale/paper": "1",
            "eval_episodes/paper": "5",
        },
        "evaluation/paper",
        params={"repository": "ml-tue/ePOET_3D", "logged_score": "2806"},
    )
    export("reference", tmp_path / "reference", uri)
    info = json.loads((tmp_path / "reference" / "epoet_sac_sac_58" / "run.json").read_text())
    assert info["run_id"] == agent and info["command"] is None
    assert info["command_source"] == "reference"
    assert info["reference"] == "reference:poet_twin22/sac_58"
    assert info["provenance"] == {"logged_score": "2806", "repository": "ml-tue/ePOET_3D"}
    assert list(info["evaluations"]) == ["paper"]

    old = finished(
        "old",
        {"algo": "ppo", "seed": "3"},
        {"eval_suite": shipped.fingerprint, "eval_course_scale": "0.2", "eval_episodes": "1"},
        "evaluation",
    )
    export("old", tmp_path / "old", uri)
    info = json.loads((tmp_path / "old" / "ppo_s3" / "run.json").read_text())
    assert info["run_id"] == old and info["evaluations"]["shipped"]["course_scale"] == "0.2"
    assert info["evaluations"]["shipped"]["artifacts"] == "evaluation"
    frame, scale, left_out = record_episodes(tmp_path / "old", shipped)
    assert scale == "0.2" and left_out == [] and list(frame.terrain) == list(episodes.terrain)
    with pytest.raises(AnalysisError, match="no record in .* has an evaluation on suite paper"):
        record_episodes(tmp_path / "old", paper)


def write_record(folder: Path, episodes: pd.DataFrame, suites: dict[str, str]) -> None:
    """A hand-made evaluation record `<algo>_s1` on the shipped suite (`suites`: the suites it
    says it was evaluated on, with their fingerprints)."""
    (folder / "shipped").mkdir(parents=True)
    episodes.to_csv(folder / "shipped" / "episodes.csv", index=False)
    record = {
        "format": "epoet-record/1",
        "algo": folder.name.split("_s")[0],
        "seed": "1",
        "run_id": folder.name,
        "evaluations": {s: {"fingerprint": f, "course_scale": "1"} for s, f in suites.items()},
    }
    (folder / "run.json").write_text(json.dumps(record))


def test_make_tables_writes_each_input_to_a_folder_of_its_own(tmp_path, capsys):
    """`make tables RECORDS=A` then `RECORDS=B`: results/A/shipped/ and results/B/shipped/,
    each with its own numbers; neither overwrites the other."""
    from analysis.tables import main

    shipped = load_suite("shipped")
    for name, solved in (("A", True), ("B", False)):
        episodes = pd.DataFrame(
            [
                [t.name, t.level, t.roughness, 0, 7, 5.0, solved, solved, 1.0, 10, 0.0]
                for t in shipped.terrains
            ],
            columns=COLUMNS,
        )
        write_record(tmp_path / name / "ppo_s1", episodes, {"shipped": shipped.fingerprint})
        assert main(["--records", str(tmp_path / name), "--out", str(tmp_path / "results")]) == 0
    capsys.readouterr()
    for name, rate in (("A", 1.0), ("B", 0.0)):
        table = pd.read_csv(tmp_path / "results" / name / "shipped" / "table1_shipped.csv")
        assert table.iloc[0].total_mean == rate, name
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == ["A", "B"]


def test_records_on_other_terrains_are_refused_and_records_without_the_suite_named(
    tmp_path, capsys
):
    shipped = load_suite("shipped")
    episodes = pd.DataFrame(
        [
            [t.name, t.level, t.roughness, 0, 7, 5.0, True, True, 1.0, 10, 0.0]
            for t in shipped.terrains
        ],
        columns=COLUMNS,
    )
    write_record(tmp_path / "ppo_s1", episodes, {"shipped": shipped.fingerprint})
    write_record(tmp_path / "sac_s1", episodes, {})
    written = tables_from_records(tmp_path, tmp_path / "out")
    assert (
        "left out 1 record(s) without an evaluation on suite shipped: sac_s1"
        in capsys.readouterr().out
    )
    assert pd.read_csv(tmp_path / "out" / "table1_shipped.csv").algo.tolist() == ["ppo"]
    assert tmp_path / "out" / "iqm_shipped.png" in written
    info = json.loads((tmp_path / "ppo_s1" / "run.json").read_text())
    info["evaluations"]["shipped"]["fingerprint"] = "0123456789ab"
    (tmp_path / "ppo_s1" / "run.json").write_text(json.dumps(info))
    with pytest.raises(AnalysisError, match="evaluated on other terrains"):
        tables_from_records(tmp_path, tmp_path / "out")
    with pytest.raises(AnalysisError, match="no records folder"):
        tables_from_records(tmp_path / "nowhere", tmp_path / "out")


COMPUTE_RECORD = Path(__file__).resolve().parent.parent / "docs" / "results" / "compute" / "ppo_s1"
# (the file damaged, how, the commands that read it): one sentence naming the file for each
DAMAGES = [
    (
        "run.json",
        lambda text: text[: len(text) // 2],
        ("analysis.tables", "analysis.success_vs_compute"),
    ),
    ("run.json", lambda text: "[1, 2]", ("analysis.tables", "analysis.success_vs_compute")),
    ("paper/episodes.csv", lambda text: "not,the columns\n1,2\n", ("analysis.tables",)),
    ("cpu60/policy/paper/episodes.csv", lambda text: "", ("analysis.success_vs_compute",)),
    ("curves.csv", lambda text: text.replace("cpu_time", "cpu"), ("analysis.success_vs_compute",)),
]


@pytest.mark.parametrize("damaged, damage, commands", DAMAGES)
def test_a_damaged_record_file_is_one_line_naming_it(tmp_path, capsys, damaged, damage, commands):
    """A record cut short or rewritten (a copy of a committed one) ends each command that reads
    it in one line on stderr, naming the file, with exit 2 and nothing written."""
    import importlib

    records = tmp_path / "records"
    shutil.copytree(COMPUTE_RECORD, records / "ppo_s1")
    path = records / "ppo_s1" / damaged
    path.write_text(damage(path.read_text()))
    for command in commands:
        main = importlib.import_module(command).main
        argv = ["--records", str(records), "--suite", "paper", "--out", str(tmp_path / "out")]
        assert main(argv) == 2, command
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"error: record file {path} "), lines
    assert not (tmp_path / "out").exists()


def test_runs_of_different_episodes_per_terrain_are_refused_not_tabled(tmp_path):
    """One protocol per table: a run's end-of-run evaluation (1 episode per terrain) beside
    another's 5 is refused, naming the runs of each, by the tables (records or store: both
    write through `write_tables`) and by success against compute."""
    from analysis.success_vs_compute import compute_table
    from analysis.tables import write_tables

    shipped = load_suite("shipped")
    for name, episodes in (("ppo_s1", 1), ("sac_s1", 5)):
        rows = [
            [t.name, t.level, t.roughness, e, 7, 5.0, True, True, 1.0, 10, 0.0]
            for t in shipped.terrains
            for e in range(episodes)
        ]
        write_record(tmp_path / name, pd.DataFrame(rows, columns=COLUMNS), {"shipped": "x"})
    records = read_records(tmp_path)
    frames = [
        pd.read_csv(tmp_path / r["record"] / "shipped" / "episodes.csv").assign(
            run_id=r["run_id"], algo=r["algo"], seed=r["seed"]
        )
        for r in records
    ]
    mixed = pd.concat(frames, ignore_index=True)
    message = r"different episodes per terrain \(1: ppo s1 \(ppo_s1\); 5: sac s1 \(sac_s1\)\)"
    with pytest.raises(AnalysisError, match=message):
        write_tables(mixed, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    write_tables(mixed[mixed.algo == "sac"], tmp_path / "out")  # one protocol: tabled

    compute = tmp_path / "compute"
    shutil.copytree(COMPUTE_RECORD, compute / "ppo_s1")
    episodes = compute / "ppo_s1" / "cpu60" / "policy" / "paper" / "episodes.csv"
    first = pd.read_csv(episodes)
    first[first.episode == 0].to_csv(episodes, index=False)  # 1 episode per terrain at 60 min
    with pytest.raises(AnalysisError, match=r"\(1: ppo s1 at 60 min; 5: ppo s1 at 15 min"):
        compute_table(compute, "paper")
