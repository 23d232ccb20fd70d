"""What every record's run.json says first of the run that made it (pipeline.records, from the
MLflow store; pipeline.snapshots, from a run folder): which run, the command that trained it,
its commit and times; and the machine's load while it ran.

The command: a sweep's job (`make paper`) is found through its parent run's `sweep_dir` tag (the
job folder whose DONE file holds the run id), and its `.hydra/overrides.yaml` gives the command
(`command_source: overrides`); otherwise the command is rebuilt from the run's params: the
settings that differ from the config composed from its algo, budget and seed
(`command_source: params`; a setting equal to that default is left out even if it was given).
"""

from __future__ import annotations

import shlex
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

import yaml
from mlflow import MlflowClient
from mlflow.entities import Run
from mlflow.exceptions import MlflowException
from mlflow.utils.mlflow_tags import MLFLOW_GIT_COMMIT, MLFLOW_PARENT_RUN_ID

from analysis.records import FORMAT
from analysis.store import history, seed_of
from epoet.core.errors import first_line
from epoet.tracking.writer import LOAD_METRIC

DONE = "DONE"  # epoet.run_state.DONE: a finished job folder, its first line the run id


def run_header(
    client: MlflowClient,
    run: Run,
    record: str,
    uri: str,
    command: dict[str, Any],
    status: bool = False,
) -> dict[str, Any]:
    """run.json's first entries, in order: the record's format and name, the run (its algo,
    seed and budget tags, name, id, experiment and store; `status` where the record may be of
    a run still training), `command` (`command_of`'s entries), its commit and times."""
    tags = run.data.tags
    return {
        "format": FORMAT,
        "record": record,
        "algo": tags["algo"],
        "seed": seed_of(run),
        "budget": tags.get("budget"),
        "run_name": run.info.run_name,
        "run_id": run.info.run_id,
        "experiment": client.get_experiment(run.info.experiment_id).name,
        "store": uri,
        **({"status": run.info.status} if status else {}),
        **command,
        "commit": tags.get(MLFLOW_GIT_COMMIT),
        "started": iso(run.info.start_time),
        "ended": iso(run.info.end_time),
    }


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
        if done.read_text().partition("\n")[0].strip() == run.info.run_id:
            return done.parent
    return None


def overrides_command(folder: Path) -> str | None:
    """`python -m epoet` with the overrides Hydra saved in a job folder, if it saved them."""
    overrides = folder / ".hydra" / "overrides.yaml"
    if not overrides.is_file():
        return None
    listed = yaml.safe_load(overrides.read_text()) or []
    return shlex.join(["python", "-m", "epoet", *map(str, listed)])


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
    if folder is not None and (command := overrides_command(folder)) is not None:
        return {
            "command": command,
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
