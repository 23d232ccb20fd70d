"""The authors' published agents and evaluation terrains (github.com/ml-tue/ePOET_3D,
`trained_models/`), read where the user keeps them and converted into epoet's formats on use
(files.py: where, and the cache; convert.py: how).

`reference:<run>/<agent>` (e.g. `reference:poet_hexA8/flat`, `reference:ppo/0`) names one of
their agents wherever a run is accepted. It runs with the paper budget's agent config (RK4, 2000-step
training episodes: as the authors trained it) and the paper's score scale; its results go to an
MLflow run of its own in the experiment `reference` (made on first use, with the agent as its
MLflow model), so `make tables EXPERIMENT=reference` tables the authors' agents like any runs.
`python -m epoet.eval.reference` (convert.py) converts by hand and says where.
"""

from __future__ import annotations

import dataclasses
import json
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from epoet.eval.trained_run import TrainedRun
    from epoet.tracking import StoredRun

PREFIX = "reference:"
EXPERIMENT = "reference"


def folder() -> Path:
    """The converted files (made on first use); ReferenceFileError says what is missing."""
    from epoet.eval.reference.convert import converted

    return converted()


@cache
def manifest() -> dict[str, Any]:
    """The conversion's manifest: the source's commit and every converted agent's entry."""
    from epoet.eval.reference.files import MANIFEST

    return json.loads((folder() / MANIFEST).read_text())


def names() -> list[str]:
    return list(manifest()["agents"])


def resolve(spec: str, tracking_uri: str | None) -> TrainedRun:
    """`reference:<run>/<agent>` as a TrainedRun; AgentError naming their agents if there is no
    such agent or their files are missing."""
    from epoet.config import load
    from epoet.envs.config import HEXAPOD
    from epoet.envs.spaces import robot_sizes
    from epoet.eval.reference.files import ReferenceFileError
    from epoet.eval.trained_run import AgentSource, TrainedRun
    from epoet.rollout.agent_files import AgentError

    name = spec.removeprefix(PREFIX)
    try:
        entry = manifest()["agents"].get(name)
    except ReferenceFileError as err:
        raise AgentError(f"run={spec}: {err}") from None
    if entry is None:
        raise AgentError(
            f"run={spec} names no agent of the authors'; there are "
            f"{', '.join(PREFIX + n for n in names())}."
        )
    source = AgentSource(entry["kind"], folder() / entry["file"])
    source.check()
    # how the authors trained: their hexapod, RK4, 2000-step episodes
    paper = load(["budget=paper", f"agent={HEXAPOD}"])
    config = {
        "agent": dataclasses.asdict(paper.agent),
        "budget": {"score_scale": paper.budget.score_scale},
    }
    stored = _stored_run(name, entry, source.path, robot_sizes(paper.agent), tracking_uri)
    return TrainedRun(source, spec, stored, entry["algo"], name.split("/", 1)[1], config, None)


def _stored_run(
    name: str,
    entry: dict[str, Any],
    path: Path,
    sizes: tuple[int, int],
    tracking_uri: str | None,
) -> StoredRun:
    """The agent's run in the experiment `reference`, made (with its MLflow model of `sizes`
    observations and actions) on first use."""
    from epoet.tracking import MlflowTracker, StoredRun, open_store, resolve_tracking_uri

    uri = resolve_tracking_uri(tracking_uri)
    client = open_store(uri)
    experiment = client.get_experiment_by_name(EXPERIMENT)
    if experiment is not None:
        found = client.search_runs(
            [experiment.experiment_id], f"tags.reference = '{name}'", max_results=1
        )
        if found:
            return StoredRun(client, found[0], uri)
    provenance = {**manifest()["source"], **{k: v for k, v in entry.items() if k != "layout"}}
    with MlflowTracker(uri, EXPERIMENT) as tracker:
        run_id = tracker.start(
            f"{PREFIX}{name}",
            params=provenance,
            tags={
                "algo": entry["algo"],
                "seed": name.split("/", 1)[1],
                "reference": name,
                "budget": "paper",
            },
        )
        tracker.log_agent(path, "epoet.eval.agent_model", *sizes)
    return StoredRun.open(run_id, uri)
