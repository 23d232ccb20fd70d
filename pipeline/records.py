"""`python -m pipeline.records --experiment <experiment> --out docs/results/<name>`: every
FINISHED run of the experiment that has suite evaluations, as evaluation records: small files
that outlive the MLflow store (`analysis.records` reads them; docs/results/README.md has the
format), so `python -m analysis.tables --records <folder>` rebuilds the tables without it.

Per run, `<out>/<record>/`:
- `run.json`: what the run was (algo, seed, budget, run name and id, experiment, the command
  that trained it, the training commit, why it stopped, its training wall time, iterations or
  frames, environment steps, worker count, the machine's load while it ran) and, per suite it
  was evaluated on, the suite's fingerprint, the course scale, episodes per terrain, the
  headline numbers, when it was evaluated and by which commit (when known);
- `<suite name>/summary.json` and `<suite name>/episodes.csv`: the evaluation's artifacts
  (`evaluation/<suite name>/`, or `evaluation/` for a run logged before evaluations were keyed
  by suite), byte for byte.

The record is named `<algo>_s<seed>` (`epoet_s1`); an authors' agent (experiment `reference`,
`pipeline.reference --records`) `<algo>_<agent>` (`epoet_flat`, `epoet_sac_sac_58`, `ppo_0`).
Two FINISHED runs of one name in the experiment: the later one is exported, and the other
named. Exporting again overwrites each exported run's files, each atomically, writing run.json
last; it never touches other records. The output depends only on the store: the same store
gives the same files.

The command that trained a run, and where it comes from: pipeline.run_header.

Examples:

    python -m pipeline.records --experiment paper-workstation --out docs/results/workstation
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mlflow import MlflowClient
from mlflow.entities import Run

from analysis.records import EPISODES, RUN_FILE, SUMMARY, trained_record
from analysis.store import (
    AnalysisError,
    connect,
    history,
    require_runs,
    run_command,
    seed_of,
    select_runs,
)
from epoet.core.algorithm import ELAPSED, ENV_STEPS
from epoet.core.files import atomic_write
from epoet.core.help import HelpParser
from epoet.eval.keys import (
    EPISODES_TAG,
    PAPER_NAME,
    RESULTS,
    SHIPPED_NAME,
    SUITE_TAG,
    Logged,
    logged_evaluation,
    metric,
)
from epoet.registry import algorithm
from epoet.tracking import StoredRun
from pipeline.run_header import command_of, iso, load_of, run_header

COMMIT_TAG = "eval_commit"  # eval_commit/<suite name>: the commit that evaluated (make paper)


def record_name(run: Run) -> str:
    """`<algo>_s<seed>`; an authors' agent (tag `reference`: <run>/<agent>) `<algo>_<agent>`."""
    tags = run.data.tags
    if "reference" in tags:
        return f"{tags['algo']}_{tags['reference'].split('/', 1)[-1]}"
    return trained_record(tags["algo"], seed_of(run))


def known_fingerprints() -> dict[str, str]:
    """{fingerprint: name} of the named suites, to name a run's unkeyed (old) evaluation."""
    from epoet.eval.suite import SuiteError, load_suite

    found = {}
    for name in (SHIPPED_NAME, PAPER_NAME):
        try:
            found[load_suite(name).fingerprint] = name
        except SuiteError:
            pass
    return found


def evaluations_of(run: Run, named: dict[str, str]) -> dict[str, tuple[Logged, str, str]]:
    """{suite name: (where its files are, fingerprint, episodes tag)} of the run's evaluations:
    each `eval_suite/<name>` tag, and an old unkeyed `eval_suite` of a named suite."""
    tags = run.data.tags
    found: dict[str, tuple[Logged, str, str]] = {}

    def add(name: str, fingerprint: str, episodes_tag: str) -> None:
        logged = logged_evaluation(tags, name, fingerprint)
        if logged is not None:  # always: the fingerprint is the value of the tag it looks up
            found[name] = (logged, fingerprint, episodes_tag)

    for key, fingerprint in tags.items():
        if key.startswith(f"{SUITE_TAG}/"):
            name = key.split("/", 1)[1]
            add(name, fingerprint, f"{EPISODES_TAG}/{name}")
    old = tags.get(SUITE_TAG)
    if old is not None and (old_name := named.get(old)) is not None and old_name not in found:
        add(old_name, old, EPISODES_TAG)
    return found


def last_step(client: MlflowClient, run: Run, key: str) -> int | None:
    points = history(client, run.info.run_id, key)
    return points[-1][0] if points else None


def training_of(client: MlflowClient, run: Run) -> dict[str, Any]:
    """Wall time (`elapsed`: training seconds summed over resumes), the family's budget unit
    (iterations: the last logged iteration + 1; or frames), environment steps, workers."""
    m = run.data.metrics
    training: dict[str, Any] = {
        "wall_time_s": m.get(ELAPSED),
        "env_steps": m.get(ENV_STEPS),
        "workers": run.data.params.get("workers.num"),
        "stop_reason": run.data.tags.get("stop_reason"),
    }
    if algorithm(run.data.tags["algo"]).family.counts == "iterations":
        step = last_step(client, run, ELAPSED)
        training["iterations"] = None if step is None else step + 1
    else:
        training["frames"] = m.get("frames")
    return training


def evaluation_info(
    client: MlflowClient, run: Run, name: str, logged: Logged, fingerprint: str, episodes_tag: str
) -> dict[str, Any]:
    tags, m = run.data.tags, run.data.metrics
    keyed = logged.artifacts != RESULTS
    stat = (lambda s: metric(name, s)) if keyed else (lambda s: f"suite/{s}")
    points = client.get_metric_history(run.info.run_id, stat("success_rate"))
    episodes = tags.get(episodes_tag)
    return {
        "fingerprint": fingerprint,
        "course_scale": logged.course_scale,
        "episodes_per_terrain": int(episodes) if episodes else None,
        "success_rate": m.get(stat("success_rate")),
        "return_mean": m.get(stat("return_mean")),
        "time": iso(max(p.timestamp for p in points)) if points else None,
        "commit": tags.get(f"{COMMIT_TAG}/{name}"),
        "artifacts": logged.artifacts,
    }


def run_info(
    client: MlflowClient, run: Run, name: str, uri: str, evaluations: dict[str, Any]
) -> dict[str, Any]:
    return {
        **run_header(client, run, name, uri, command_of(client, run)),
        "training": training_of(client, run),
        "load": load_of(client, run),
        "evaluations": evaluations,
    }


def write_json(path: Path, obj: Any) -> None:
    with atomic_write(path) as f:
        f.write((json.dumps(obj, indent=1, sort_keys=False) + "\n").encode())


def export_evaluated_run(
    client: MlflowClient, run: Run, name: str, out: Path, uri: str, named: dict[str, str]
) -> Path:
    """The run's record in out/<name>/: each suite's files, then run.json; a suite folder the
    new run.json does not list (an earlier export of another run) is removed."""
    folder = out / name
    stored = StoredRun(client, run)
    evaluations = {}
    with tempfile.TemporaryDirectory(prefix="epoet-records-") as tmp:
        for suite, (logged, fingerprint, episodes_tag) in sorted(
            evaluations_of(run, named).items()
        ):
            for file in (SUMMARY, EPISODES):
                got = stored.download(f"{logged.artifacts}/{file}", Path(tmp) / suite)
                with atomic_write(folder / suite / file) as f:
                    f.write(got.read_bytes())
            evaluations[suite] = evaluation_info(
                client, run, suite, logged, fingerprint, episodes_tag
            )
    write_json(folder / RUN_FILE, run_info(client, run, name, uri, evaluations))
    for stale in folder.iterdir():
        if stale.is_dir() and stale.name not in evaluations:
            shutil.rmtree(stale)
    return folder


def export(
    experiment: str, out: Path, tracking_uri: str | None = None, run_ids: Sequence[str] = ()
) -> list[Path]:
    """Every FINISHED run of `experiment` (or the given runs) with a suite evaluation, as
    records under `out`; their folders."""
    client, uri = connect(tracking_uri)
    runs = require_runs(select_runs(client, uri, experiment, run_ids), experiment, uri)
    named = known_fingerprints()
    evaluated = [r for r in runs if evaluations_of(r, named)]
    if not evaluated:
        raise AnalysisError(
            f"no run of experiment {experiment!r} in {uri} has a suite "
            f"evaluation: evaluate them first (python -m epoet.eval.evaluate "
            f"run=<run id>, or make paper)."
        )
    if skipped := len(runs) - len(evaluated):
        print(
            f"[records] {skipped} finished run(s) without a suite evaluation are not exported",
            flush=True,
        )
    chosen: dict[str, Run] = {}
    for run in evaluated:  # oldest first: a later run of the same name replaces it
        if (earlier := chosen.get(name := record_name(run))) is not None:
            print(
                f"[records] {name}: exporting run {run.info.run_id}, the later of two "
                f"(not {earlier.info.run_id})",
                flush=True,
            )
        chosen[name] = run
    written = [
        export_evaluated_run(client, run, name, Path(out), uri, named)
        for name, run in chosen.items()
    ]
    print(
        f"[records] wrote {len(written)} record(s) of experiment {experiment} to {out}/: "
        f"{', '.join(p.name for p in written)}",
        flush=True,
    )
    return written


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m pipeline.records", __doc__)
    parser.add_argument(
        "--experiment",
        required=True,
        help="MLflow experiment whose FINISHED, evaluated runs are exported",
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="records folder, e.g. docs/results/workstation"
    )
    parser.add_argument(
        "--tracking-uri",
        default=None,
        help="the MLflow store (None: MLFLOW_TRACKING_URI, else epoet's)",
    )
    parser.add_argument(
        "--run",
        nargs="+",
        default=[],
        metavar="RUN_ID",
        help="export these runs instead of the experiment's",
    )
    args = parser.parse_args(argv)
    return run_command(lambda: export(args.experiment, args.out, args.tracking_uri, args.run))


if __name__ == "__main__":
    raise SystemExit(main())
