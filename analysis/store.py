"""Reading the MLflow store: the one place analysis/ connects, selects runs and reads metrics.

The store is epoet's (`sqlite:///<project root>/mlflow.db`); MLFLOW_TRACKING_URI overrides it.
An analysis never writes training data: a missing store is an error, not a new empty one.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from mlflow import MlflowClient
from mlflow.entities import Run
from mlflow.exceptions import MlflowException
from omegaconf import OmegaConf

from epoet.config import CONF_DIR
from epoet.core.algorithm import Family
from epoet.core.errors import first_line
from epoet.envs.config import HEXAPOD
from epoet.eval.agents import AgentError
from epoet.eval.keys import SHIPPED_NAME, Logged, logged_evaluation
from epoet.eval.suite import Suite, SuiteError, load_suite
from epoet.registry import names
from epoet.tracking import TrackingError, open_store, resolve_tracking_uri, sqlite_path


def default_experiment() -> str:
    """The experiment a run logs to unless told otherwise (conf/tracking/mlflow.yaml)."""
    return str(OmegaConf.load(CONF_DIR / "tracking" / "mlflow.yaml").experiment)


def add_store_arguments(parser: argparse.ArgumentParser, out: Path) -> None:
    """The options of every command that reads runs from the store: which experiment (or which
    runs), which suite's evaluations, and the output root (`output_folder` names the rest)."""
    parser.add_argument(
        "--experiment",
        default=default_experiment(),
        help="MLflow experiment whose FINISHED runs are read (the runs' default, "
        "tracking.experiment)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=out,
        help="output root: files go to OUT/<input>/<suite>/, <input> being the experiment, "
        "the records folder's name or runs-<id hash> for --run",
    )
    parser.add_argument(
        "--suite",
        default=SHIPPED_NAME,
        help="suite name (shipped, paper) or suite folder whose evaluations are read",
    )
    parser.add_argument(
        "--run",
        nargs="+",
        default=[],
        metavar="RUN_ID",
        help="read these runs instead of the experiment's",
    )


def output_folder(
    out: Path, suite: str, experiment: str, run_ids: Sequence[str] = (), records: Path | None = None
) -> Path:
    """`out/<input>/<suite name>/`: a folder of its own for each input (the records folder's
    name, the chosen runs or the experiment) and suite, so that tables and figures of one input
    never overwrite another's."""
    if records is not None:
        source = records.resolve().name
    elif run_ids:
        source = f"runs-{hashlib.sha1(' '.join(sorted(run_ids)).encode()).hexdigest()[:8]}"
    else:
        source = experiment
    return out / source / load_suite(suite).name


def in_order(present: Iterable[str], family: Family | None = None) -> list[str]:
    """The registered algorithms (of `family`) among `present`, in table and legend order."""
    present = set(present)
    return [algo for algo in names(family) if algo in present]


class AnalysisError(ValueError):
    """Input an analysis command cannot use (no store, no runs, unknown run id); one sentence."""


def connect(tracking_uri: str | None = None) -> tuple[MlflowClient, str]:
    """Open an existing store; a missing sqlite file is an error, not a new empty store.

    MLflow would silently create the database, and an analysis must never write to the store.
    """
    uri = resolve_tracking_uri(tracking_uri)
    db = sqlite_path(uri)
    if db is not None and not db.is_file():
        raise AnalysisError(
            f"there is no MLflow store at {db}: train a run first "
            "or point MLFLOW_TRACKING_URI at a store."
        )
    return open_store(uri), uri


def select_runs(
    client: MlflowClient,
    uri: str,
    experiment: str,
    run_ids: Sequence[str] = (),
    algos: Sequence[str] | None = None,
) -> list[Run]:
    """The given runs, else the experiment's FINISHED runs of `algos` (None: every registered
    algorithm), oldest first.

    A sweep's parent run has no algo tag and is never selected.
    """
    algos = names() if algos is None else algos
    if run_ids:
        runs = []
        for run_id in run_ids:
            try:
                runs.append(client.get_run(run_id))
            except MlflowException as exc:
                raise AnalysisError(f"run {run_id} is not in the MLflow store {uri}.") from exc
        for run in runs:
            algo = run.data.tags.get("algo")
            if algo not in algos:
                raise AnalysisError(
                    f"run {run.info.run_id} has algo tag {algo!r}; expected "
                    f"one of {', '.join(algos)}."
                )
        return runs
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        raise AnalysisError(
            f"the MLflow store {uri} has no experiment named {experiment!r}: "
            f"train first (e.g. make paper BUDGET=smoke SEEDS=1)."
        )
    report_orphans(client, exp.experiment_id, experiment)
    runs, token = [], None
    while True:
        page = client.search_runs(
            [exp.experiment_id],
            "attributes.status = 'FINISHED'",
            max_results=1000,
            order_by=["attributes.start_time ASC"],
            page_token=token,
        )
        runs.extend(r for r in page if r.data.tags.get("algo") in algos)
        token = page.token
        if not token:
            return runs


def report_orphans(client: MlflowClient, experiment_id: str, experiment: str) -> None:
    """Say which of the experiment's runs are RUNNING with no live process (killed: SIGKILL, a
    power cut); the tables leave them out, as every unfinished run."""
    from epoet.run_state import HOST_TAG, PID_TAG, process_alive

    running = client.search_runs([experiment_id], "attributes.status = 'RUNNING'")
    dead = [
        r.info.run_id
        for r in running
        if PID_TAG in r.data.tags
        and process_alive(r.data.tags.get(HOST_TAG, ""), int(r.data.tags[PID_TAG])) is False
    ]
    if dead:
        print(
            f"note: {len(dead)} run(s) of experiment {experiment!r} are RUNNING with no live "
            f"process (killed): {', '.join(dead)}; the next run in their folder marks them KILLED",
            file=sys.stderr,
        )


def evaluation_on(run: Run, suite: Suite) -> Logged | None:
    """The run's evaluation on `suite`: its `eval_suite/<name>` tag is the suite's fingerprint
    (or, for a run logged before evaluations were keyed by suite, its `eval_suite` tag:
    `epoet.eval.keys`); None without one."""
    return logged_evaluation(run.data.tags, suite.name, suite.fingerprint)


def evaluation_of(run: Run, suite: Suite) -> Logged:
    """`evaluation_on` of a run known to have one (`unevaluated` left out those without)."""
    logged = evaluation_on(run, suite)
    if logged is None:
        raise ValueError(f"run {run.info.run_id} has no evaluation on suite {suite.name}.")
    return logged


def unevaluated(runs: Sequence[Run], suite: Suite) -> list[Run]:
    """The runs with no evaluation on `suite` (`evaluation_on`)."""
    return [r for r in runs if evaluation_on(r, suite) is None]


def require_runs(runs: list[Run], experiment: str, uri: str) -> list[Run]:
    """The runs, all of one robot, or AnalysisError saying what to run first (or apart)."""
    if not runs:
        raise AnalysisError(
            f"experiment {experiment!r} in {uri} has no finished runs: train "
            f"first, e.g. `python -m epoet algo=epoet` or "
            f"`make paper BUDGET=smoke SEEDS=1`."
        )
    robots = sorted({r.data.tags.get("agent", HEXAPOD) for r in runs})
    if len(robots) > 1:
        raise AnalysisError(
            f"experiment {experiment!r} in {uri} holds runs of several robots "
            f"({', '.join(robots)}), which one table would mix: give each robot its own "
            f"experiment (tracking.experiment=<name>) or choose runs with --run."
        )
    return runs


def history(client: MlflowClient, run_id: str, key: str) -> list[tuple[int, float]]:
    """(step, value) of a metric, one point per step: the last logged value wins.

    A resumed run re-logs the steps between its last checkpoint and the kill; the later values
    are the ones that led to the final state.
    """
    points = sorted(client.get_metric_history(run_id, key), key=lambda m: (m.step, m.timestamp))
    return sorted({m.step: m.value for m in points}.items())


def seed_of(run: Run) -> str:
    return run.data.tags.get("seed", "")


def run_command(action: Callable[[], object]) -> int:
    """Run an analysis command: bad input (store, runs, suite, agent) ends in one sentence on
    stderr and exit code 2."""
    try:
        action()
    except (AnalysisError, TrackingError, SuiteError, AgentError) as exc:
        print(f"error: {first_line(exc)}", file=sys.stderr)
        return 2
    except MlflowException as exc:
        print(f"error: cannot read the MLflow store: {first_line(exc)}", file=sys.stderr)
        return 2
    return 0
