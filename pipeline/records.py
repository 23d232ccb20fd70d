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

The command: a sweep's job (`make paper`) is found through its parent run's `sweep_dir` tag (the
job folder whose DONE file holds the run id), and its `.hydra/overrides.yaml` gives the command
(`command_source: overrides`); otherwise the command is rebuilt from the run's params: the
settings that differ from the config composed from its algo, budget and seed
(`command_source: params`; a setting equal to that default is left out even if it was given).

Examples:

    python -m pipeline.records --experiment paper-workstation --out docs/results/workstation
"""

from __future__ import annotations

import json
import shlex
import shutil
import tempfile
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

import yaml
from mlflow import MlflowClient
from mlflow.entities import Run
from mlflow.exceptions import MlflowException
from mlflow.utils.mlflow_tags import MLFLOW_GIT_COMMIT, MLFLOW_PARENT_RUN_ID

from analysis.records import EPISODES, FORMAT, RUN_FILE, SUMMARY
from analysis.store import (
    AnalysisError,
    connect,
    history,
    require_runs,
    run_command,
    seed_of,
    select_runs,
)
from epoet.core.errors import first_line
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
from epoet.tracking.writer import LOAD_METRIC

COMMIT_TAG = "eval_commit"  # eval_commit/<suite name>: the commit that evaluated (make paper)
DONE = "DONE"  # epoet.run.DONE: a finished job folder, holding its run id


def record_name(run: Run) -> str:
    """`<algo>_s<seed>`; an authors' agent (tag `reference`: <run>/<agent>) `<algo>_<agent>`."""
    tags = run.data.tags
    if "reference" in tags:
        return f"{tags['algo']}_{tags['reference'].split('/', 1)[-1]}"
    return f"{tags['algo']}_s{seed_of(run)}"


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


def iso(ms: int | None) -> str | None:
    if ms is None:
        return None
    return datetime.fromtimestamp(ms / 1000, timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def parent_tags(client: MlflowClient, run: Run) -> dict[str, str] | None:
    """The tags of the run's sweep parent; None for a run outside a sweep (or a parent gone
    from the store)."""
    parent = run.data.tags.get(MLFLOW_PARENT_RUN_ID)
    if parent is None:
        return None
    try:
        return dict(client.get_run(parent).data.tags)
    except MlflowException:
        return None


def job_folder(run: Run, sweep: dict[str, str] | None) -> Path | None:
    """The Hydra job folder of a sweep's run: under its parent's `sweep_dir`, the folder whose
    DONE file holds the run id; None when it cannot be found (not a sweep job, or the folder is
    gone)."""
    sweep_dir = (sweep or {}).get("sweep_dir")
    if not sweep_dir or not Path(sweep_dir).is_dir():
        return None
    for done in sorted(Path(sweep_dir).glob(f"*/{DONE}")):
        if done.read_text().strip() == run.info.run_id:
            return done.parent
    return None


def override_value(value: str) -> str:
    """A param's value (Python's str()) as a Hydra override value."""
    return {"None": "null", "True": "true", "False": "false"}.get(value, value)


def command_from_params(run: Run) -> str:
    """`python -m epoet` with the run's algo, budget and seed and every param that differs from
    the config they compose to (the store and worker count as it ran)."""
    from omegaconf import OmegaConf

    from epoet.config import compose
    from epoet.tracking import flatten

    tags, params = run.data.tags, run.data.params
    base = [f"algo={tags['algo']}", f"budget={tags['budget']}", f"seed={seed_of(run)}"]
    composed = flatten(cast(dict[str, Any], OmegaConf.to_container(compose(base), resolve=True)))
    changed = [
        f"{key}={override_value(value)}"
        for key, value in sorted(params.items())
        if key in composed and composed[key] != value and key != "tracking.uri"
    ]
    return shlex.join(["python", "-m", "epoet", *base, *changed])


def command_of(client: MlflowClient, run: Run) -> dict[str, Any]:
    """The command that trained the run, and where it comes from."""
    tags = run.data.tags
    if "reference" in tags:
        return {
            "command": None,
            "command_source": "reference",
            "reference": f"reference:{tags['reference']}",
            "provenance": dict(sorted(run.data.params.items())),
        }
    found: dict[str, Any] = {}
    if (sweep := parent_tags(client, run)) is not None:
        found["sweep"] = {
            "run_id": tags[MLFLOW_PARENT_RUN_ID],
            "dir": sweep.get("sweep_dir"),
            "command": shlex.join(
                ["python", "-m", "epoet", "-m", *shlex.split(sweep.get("sweep_overrides", ""))]
            ),
        }
    folder = job_folder(run, sweep)
    overrides = folder / ".hydra" / "overrides.yaml" if folder is not None else None
    if overrides is not None and overrides.is_file():
        listed = yaml.safe_load(overrides.read_text()) or []
        return {
            "command": shlex.join(["python", "-m", "epoet", *map(str, listed)]),
            "command_source": "overrides",
            "job_dir": str(folder),
            **found,
        }
    if not {"algo", "budget", "seed"} <= tags.keys():
        return {"command": None, "command_source": None, **found}
    try:
        command = command_from_params(run)
    except Exception as exc:  # noqa: BLE001 - any composition error of today's config
        return {
            "command": None,
            "command_source": None,
            "command_note": f"the run's algo, budget and seed do not compose with the "
            f"config of the exporting commit: {first_line(exc)}",
            **found,
        }
    return {"command": command, "command_source": "params", **found}


def last_step(client: MlflowClient, run: Run, key: str) -> int | None:
    points = history(client, run.info.run_id, key)
    return points[-1][0] if points else None


def training_of(client: MlflowClient, run: Run) -> dict[str, Any]:
    """Wall time (`elapsed`: training seconds summed over resumes), the family's budget unit
    (iterations: the last logged iteration + 1; or frames), environment steps, workers."""
    m = run.data.metrics
    training: dict[str, Any] = {
        "wall_time_s": m.get("elapsed"),
        "env_steps": m.get("env_steps"),
        "workers": run.data.params.get("workers.num"),
        "stop_reason": run.data.tags.get("stop_reason"),
    }
    if algorithm(run.data.tags["algo"]).family.counts == "iterations":
        step = last_step(client, run, "elapsed")
        training["iterations"] = None if step is None else step + 1
    else:
        training["frames"] = m.get("frames")
    return training


def load_of(client: MlflowClient, run: Run) -> dict[str, Any] | None:
    """The machine's 1-minute load average over the run (`system/load1`), or None (runs
    before it was logged)."""
    values = [v for _, v in history(client, run.info.run_id, LOAD_METRIC)]
    if not values:
        return None
    return {
        "metric": LOAD_METRIC,
        "mean": sum(values) / len(values),
        "max": max(values),
        "points": len(values),
    }


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
    tags = run.data.tags
    return {
        "format": FORMAT,
        "record": name,
        "algo": tags["algo"],
        "seed": seed_of(run),
        "budget": tags.get("budget"),
        "run_name": run.info.run_name,
        "run_id": run.info.run_id,
        "experiment": client.get_experiment(run.info.experiment_id).name,
        "store": uri,
        **command_of(client, run),
        "commit": tags.get(MLFLOW_GIT_COMMIT),
        "started": iso(run.info.start_time),
        "ended": iso(run.info.end_time),
        "training": training_of(client, run),
        "load": load_of(client, run),
        "evaluations": evaluations,
    }


def write_json(path: Path, obj: Any) -> None:
    with atomic_write(path) as f:
        f.write((json.dumps(obj, indent=1, sort_keys=False) + "\n").encode())


def export_run(
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
    written = [export_run(client, run, name, Path(out), uri, named) for name, run in chosen.items()]
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
