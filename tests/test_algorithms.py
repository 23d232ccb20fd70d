"""The algorithm as the unit: every algorithm is one record (epoet/core/algorithm.py) that
composition, the run, `make paper` and analysis read (epoet/registry.py), and nothing else lists
the algorithms. A toy algorithm registered from outside epoet/ (tests/toy_algorithm.py) composes,
trains on the smoke budget, is evaluated and appears in the tables, with no repository file
naming it.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from analysis.figures import curve_table
from conftest import new_store, subset_suite, unmet_metrics
from epoet.config import CONF_DIR, compose
from epoet.core.algorithm import SCORE, Algorithm, Family
from epoet.core.checkpoint import CheckpointError, load_checkpoint
from epoet.ppo.config import PPO, PpoConfig
from epoet.registry import DECLARED, algorithm, algorithms, names, register

ROOT = Path(__file__).resolve().parent.parent
TOY = Path(__file__).with_name("toy_algorithm.py")
ADDING = ROOT / "docs" / "algorithms" / "adding.md"  # the toy, as the page's random_search
# What `python -m epoet algo=<algo> budget=<budget>` composes to, every value resolved (first
# written at commit 54618cf); `python tests/test_algorithms.py` writes it again, for a change to
# the configs that is meant (its diff is the change).
COMPOSED = Path(__file__).with_name("configs_by_algo_and_budget.json")
BUDGETS = sorted(p.stem for p in (CONF_DIR / "budget").glob("*.yaml"))
CODE = ("epoet", "analysis", "pipeline", "bench")


def composed(key: str) -> dict:
    return OmegaConf.to_container(compose(key.split()), resolve=True)  # type: ignore[return-value]


def test_the_records_are_listed_in_table_order() -> None:
    """Every record the registry imports is listed, baselines first, then by name; each runs
    from its own package (`runner` imports it) and no two share a label or a colour."""
    records = algorithms()
    assert set(DECLARED) <= set(records)
    order = list(Family)
    assert records == sorted(records, key=lambda r: (order.index(r.family), r.name))
    for record in DECLARED:
        runner = record.runner()
        assert runner.__module__.split(".")[:2] == record.schema.__module__.split(".")[:2]
    assert len({r.label for r in records}) == len({r.colour for r in records}) == len(records)
    assert algorithm("ppo").schema is PpoConfig and algorithm("ppo").family.counts == "frames"
    assert algorithm("epoet").family.counts == "iterations"
    with pytest.raises(ValueError, match="two algorithms are named 'ppo'"):
        register(Algorithm("ppo", Family.OPEN_ENDED, PpoConfig, PPO.runner, "PPO", "red"))


@pytest.mark.parametrize("key", sorted(json.loads(COMPOSED.read_text())))
def test_every_algorithm_and_budget_composes_as_before(key: str) -> None:
    assert composed(key) == json.loads(COMPOSED.read_text())[key]


def test_algo_budget_files_are_a_family_or_an_algorithm_on_a_budget() -> None:
    """An algorithm's own file is optional, so a misnamed one would be skipped silently: every
    file is <family or algorithm>/<budget>.yaml, and every family has every budget."""
    root = CONF_DIR / "algo_budget"
    folders = {f.value for f in Family} | set(names())
    files = [p.relative_to(root) for p in root.rglob("*") if p.is_file()]
    wrong = [
        f
        for f in files
        if len(f.parts) != 2 or f.parts[0] not in folders or f.suffix != ".yaml"
        or f.stem not in BUDGETS
    ]  # fmt: skip
    assert files and not wrong, wrong
    for family in Family:
        assert sorted(p.stem for p in (root / family.value).iterdir()) == BUDGETS


def _name_lists(path: Path, known: set[str]) -> list[str]:
    """Each tuple, list, set or dict literal in `path` with two or more algorithm names among
    its elements, keys or values (a record holds one name; a list of them is a second registry)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            groups = [node.elts]
        elif isinstance(node, ast.Dict):
            groups = [[k for k in node.keys if k is not None], node.values]
        else:
            continue
        for group in groups:
            hits = [e.value for e in group if isinstance(e, ast.Constant) and e.value in known]
            if len(hits) >= 2:
                found.append(
                    f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{node.lineno} {hits}"
                )
    return found


def test_no_list_of_algorithm_names_outside_the_records(tmp_path: Path) -> None:
    known = set(names())
    found = [
        hit
        for d in CODE
        for path in sorted((ROOT / d).rglob("*.py"))
        for hit in _name_lists(path, known)
    ]
    assert not found, "\n".join(found)
    # it sees one, in any of the literals it reads
    lists = tmp_path / "lists.py"
    lists.write_text("A = {'ppo': 1, 'sac': 2}\nB = [x for x in ('epoet', 'vmpo')]\n")
    assert len(_name_lists(lists, known)) == 2


def test_the_adding_page_shows_the_toys_runner() -> None:
    """docs/algorithms/adding.md's runner is the one the toy test trains, its names aside."""
    toy = TOY.read_text()
    runner = toy[toy.index("def train(") : toy.index("\n\n\ndef register()")]
    shown = runner.replace("ToyConfig", "RandomSearchConfig").replace('"toy"', '"random_search"')
    assert shown in ADDING.read_text()


# What a run does at its boundaries: the driver's (epoet/driver.py) and no algorithm's.
DRIVER = ROOT / "epoet" / "driver.py"
BOUNDARIES = {
    "take_snapshots",
    "save_run_state",
    "report_stop",
    "raise_if_stopped",
    "stop_requested",
}


def test_only_the_driver_snapshots_checkpoints_and_stops_a_run() -> None:
    """No module of the product (nor the toy) names the snapshot, checkpoint or stop functions
    but the driver: every algorithm gets them by giving the driver its steps."""
    modules = [p for d in ("epoet", "pipeline", "analysis") for p in (ROOT / d).rglob("*.py")]
    found = {}
    for path in [*modules, TOY]:
        if path in (DRIVER, ROOT / "epoet" / "core" / "lifecycle.py"):
            continue
        tree = ast.parse(path.read_text())
        names_used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        names_used |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
        names_used |= {
            a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names
        }
        if names_used & BOUNDARIES:
            found[str(path.relative_to(ROOT))] = sorted(names_used & BOUNDARIES)
    assert found == {}


def test_the_toy_resumes_exactly_after_sigkill_through_the_driver(
    tmp_path: Path, empty_store
) -> None:
    """The toy writes no checkpoint, handles no signal and reads no resume flag itself: killed
    with SIGKILL after a checkpoint, `resume=auto` continues it to the same final state and
    metric points as a run never interrupted."""
    uri = new_store(empty_store, tmp_path)
    args = [str(TOY), "epoet", "algo=toy", "budget=smoke", "budget.frames=4000", "seed=3",
            "workers.num=1", "evaluate=false", "checkpoint_every=1", "tracking.experiment=toy"]  # fmt: skip
    killed, straight = tmp_path / "killed", tmp_path / "straight"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MLFLOW_TRACKING_URI": uri}
    proc = subprocess.Popen(
        [sys.executable, *args, f"hydra.run.dir={killed}"], cwd=tmp_path, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    checkpoint = killed / "checkpoint.pkl"
    while proc.poll() is None and not (checkpoint.is_file() and _toy_steps(checkpoint) >= 2):
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    assert not (killed / "DONE").exists(), "the run ended before it was killed: a larger budget"
    stopped = _toy_steps(checkpoint)
    _run([*args, "resume=auto", f"hydra.run.dir={killed}"], tmp_path, uri)
    _run([*args, f"hydra.run.dir={straight}"], tmp_path, uri)
    resumed, whole = (load_checkpoint(d / "checkpoint.pkl") for d in (killed, straight))
    assert resumed["run_id"] == load_checkpoint(checkpoint)["run_id"]  # the same MLflow run
    assert whole["toy"]["steps"] > stopped >= 2
    for key in ("steps", "frames", "best"):
        assert resumed["toy"][key] == whole["toy"][key], key
    np.testing.assert_array_equal(resumed["toy"]["theta"], whole["toy"]["theta"])
    client = mlflow.MlflowClient(uri)
    points = [
        sorted(m.step for m in client.get_metric_history(d["run_id"], SCORE))
        for d in (resumed, whole)
    ]
    assert points[0] == points[1]  # every step once: none lost, none twice


def _toy_steps(checkpoint: Path) -> int:
    try:
        return int(load_checkpoint(checkpoint)["toy"]["steps"])
    except CheckpointError:  # written atomically, but not there yet
        return 0


def _run(args: list[str], cwd: Path, uri: str) -> subprocess.CompletedProcess:
    """A command as a user runs it, on this worktree's code and the test's store."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MLFLOW_TRACKING_URI": uri}
    proc = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def test_a_toy_algorithm_trains_is_evaluated_and_tabled(tmp_path: Path, empty_store) -> None:
    """The toy's record, schema, runner and YAML are tests/toy_algorithm.py's only: it trains
    through `python -m epoet`, takes the baselines family's smoke frames (algo_budget/
    baselines/smoke.yaml) without a file of its own, its agent is evaluated by the plain
    `python -m epoet.eval.evaluate`, and `make tables` (analysis.tables) reads it from MLflow."""
    assert not [p for p in (*CONF_DIR.rglob("*toy*"), *(ROOT / "epoet").rglob("*toy*"))]
    uri = new_store(empty_store, tmp_path)
    run_dir, suite = (
        tmp_path / "run",
        subset_suite(tmp_path / "suite", [("easy", 0), ("medium", 0)]),
    )
    _run(
        [str(TOY), "epoet", "algo=toy", "budget=smoke", "seed=1", "workers.num=1",
         "evaluate=false", "tracking.experiment=toy", f"hydra.run.dir={run_dir}"],
        tmp_path,
        uri,
    )  # fmt: skip
    (run,) = mlflow.MlflowClient(uri).search_runs(
        [mlflow.MlflowClient(uri).get_experiment_by_name("toy").experiment_id]
    )
    assert run.data.tags["algo"] == "toy" and run.info.status == "FINISHED"
    assert run.data.params["algo.name"] == "toy"
    assert run.data.params["budget.frames"] == "400" and run.data.metrics["env_steps"] >= 400
    assert (run_dir / "policies" / "env0.npz").is_file()
    client = mlflow.MlflowClient(uri)
    assert unmet_metrics(client, run.info.run_id, Family.BASELINE) == []  # it gets its curve
    assert not curve_table(client, [run]).empty

    _run(
        ["-m", "epoet.eval.evaluate", f"run={run_dir}", f"suite={suite}", "episodes=1"],
        tmp_path,
        uri,
    )
    out = tmp_path / "tables"
    printed = _run(
        [
            str(TOY),
            "analysis.tables",
            "--experiment",
            "toy",
            "--suite",
            str(suite),
            "--out",
            str(out),
        ],
        tmp_path,
        uri,
    ).stdout
    table1 = pd.read_csv(out / "toy" / "suite" / "table1_suite.csv")
    assert list(table1.algo) == ["toy"] and table1.runs.tolist() == [1]
    assert "| toy " in printed


if __name__ == "__main__":
    configs = {
        f"algo={a} budget={b}": composed(f"algo={a} budget={b}") for a in names() for b in BUDGETS
    }
    COMPOSED.write_text(json.dumps(configs, indent=1, sort_keys=True) + "\n")
