"""Trained agents, wherever they live: an MLflow run, a run folder or a policy file.

Evaluation and rendering take `run=<spec>` and need three things from it: a policy
(`obs -> action`), the episode rules it was trained with (agent config, the budget's threshold
scale) and, when there is one, the MLflow run to log results to. Two policy formats exist:
- ES parameters (`.npz` with `theta` and `layer_sizes`): ePOET's and ePOET-SAC's pool agents,
  `policies/env<N>.npz` (with their `score`); a run's agent is the pool's best by score;
- exported torch policies (`policy.pt`, `epoet.rl.policy_file`): PPO, SAC and VMPO.
Each records the robot it was trained on (epoet.rollout.agent_files), which must be the robot
it runs with: the run's, or for a bare policy file `agent=<robot>`.
"""

from __future__ import annotations

import atexit
import re
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any, cast

import numpy as np
from omegaconf import OmegaConf

from epoet.core.checkpoint import CHECKPOINT_NAME, CheckpointError, load_checkpoint
from epoet.eval.trained_run import AgentSource, TrainedRun
from epoet.rollout.agent_files import (
    ES_POLICIES,
    EXPORTED_AGENT,
    TORCH_POLICY,
    AgentError,
    bad_agent,
)
from epoet.tracking import TrackingError

RUN_ID = re.compile(r"^[0-9a-f]{32}$")
MODEL_URI = re.compile(r"^runs:/([0-9a-f]{32})/agent/?$")  # the run's MLflow model (agent_model)
RECORD_CONFIG = "config.yaml"  # a record's resolved run config (docs/results/README.md)


def policy_in(folder: Path) -> tuple[AgentSource, str] | None:
    """A run folder's exported agent and its name: the pool agent the run chose (`agent.npz`,
    epoet/open_ended/exported_agent.py), else (a run from before the choice, or one still training
    towards its first snapshot) the best pool agent (highest score), or the exported torch
    policy; None if it has none."""
    if (folder / ES_POLICIES / EXPORTED_AGENT).is_file():
        return AgentSource("es", folder / ES_POLICIES / EXPORTED_AGENT), "agent"
    pool = sorted((folder / ES_POLICIES).glob("env*.npz"))  # none if the folder is absent
    if pool:
        scores = {}
        for path in pool:
            try:
                with np.load(path, allow_pickle=False) as data:
                    scores[path] = float(data["score"]) if "score" in data else -np.inf
            except (OSError, ValueError, TypeError, EOFError, zipfile.BadZipFile):
                raise bad_agent(path, "es", "is not a readable .npz file") from None
        best = max(pool, key=lambda p: (scores[p], -int(p.stem[3:])))
        return AgentSource("es", best), best.stem
    if (folder / TORCH_POLICY).is_file():
        return AgentSource("torch", folder / TORCH_POLICY), "policy"
    return None


def file_source(path: Path) -> AgentSource:
    """A policy file's format, by the name runs give it."""
    if path.suffix == ".npz":
        return AgentSource("es", path)
    if path.suffix == ".pt":
        return AgentSource("torch", path)
    raise AgentError(f"{path} is not a policy file (.npz ES parameters or .pt torch policy).")


def _download_dir() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="epoet-agent-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


def _from_store(run_id: str, tracking_uri: str | None) -> TrainedRun:
    from epoet.tracking import StoredRun  # mlflow only for agents that live in the store

    stored = StoredRun.open(run_id, tracking_uri)
    folder = _download_dir()
    for artifact in (ES_POLICIES, TORCH_POLICY):
        if stored.has_artifact(artifact):
            stored.download(artifact, folder)
            break
    found = policy_in(folder)
    if found is None:
        raise AgentError(
            f"run {run_id} ({stored.name}, {stored.status}) has no policy artifact "
            f"({ES_POLICIES}/ or {TORCH_POLICY}): evaluate a run that finished "
            f"training."
        )
    config = None
    if stored.has_artifact("config.yaml"):
        loaded = OmegaConf.load(stored.download("config.yaml", folder))
        config = cast(dict[str, Any], OmegaConf.to_container(loaded))  # a run's config: a mapping
    source, name = found
    source.check()
    label = stored.name if source.kind == "torch" else f"{stored.name} {name}"
    return TrainedRun(
        source, label, stored, stored.tags.get("algo"), stored.tags.get("seed"), config, None
    )


def _from_folder(folder: Path, tracking_uri: str | None) -> TrainedRun:
    found = policy_in(folder)
    if found is None:
        raise AgentError(
            f"run folder {folder} has no policy ({ES_POLICIES}/env<N>.npz or "
            f"{TORCH_POLICY}) yet: a run writes its agents with its first checkpoint."
        )
    state: dict[str, Any] = {}
    if (folder / CHECKPOINT_NAME).is_file():
        try:
            state = load_checkpoint(folder)
        except CheckpointError as err:
            raise AgentError(str(err)) from err
    elif (folder / RECORD_CONFIG).is_file():  # a record (pipeline.snapshots): the run's config
        loaded = OmegaConf.to_container(OmegaConf.load(folder / RECORD_CONFIG))
        state = {"config": loaded, "algo": cast(dict[str, Any], loaded)["algo"]["name"]}
    config = state.get("config")
    source, name = found
    source.check()
    algo = state.get("algo")
    seed = None if config is None else str(config["seed"])
    base = f"{algo}-s{seed}" if algo else folder.name
    label = base if source.kind == "torch" else f"{base} {name}"
    # The run the checkpoint continues, opened now so a missing store fails before any work.
    from epoet.tracking import StoredRun

    stored = StoredRun.open(state["run_id"], tracking_uri) if state.get("run_id") else None
    return TrainedRun(source, label, stored, algo, seed, config, folder)


def resolve_run(spec: str, tracking_uri: str | None = None) -> TrainedRun:
    """`run=<spec>`: a shipped reference agent `reference:<run>/<agent>`, a policy file, a run
    folder, an MLflow run id or its model URI `runs:/<run id>/agent` (in that order).

    Its policy is checked here (AgentSource.check), so a bad agent file fails before any
    episode and before the store is opened for a run folder.
    """
    if spec.startswith("reference:"):  # the authors' agents, shipped converted
        from epoet.eval.reference import resolve

        try:
            return resolve(spec, tracking_uri)
        except TrackingError as err:
            raise AgentError(str(err)) from err
    path = Path(spec)
    if path.is_file():
        source = file_source(path)
        source.check()
        return TrainedRun(source, path.stem, None, None, None, None, None)
    try:
        if path.is_dir():
            return _from_folder(path, tracking_uri)
        if RUN_ID.match(spec):
            return _from_store(spec, tracking_uri)
        if model := MODEL_URI.match(spec):  # the agent the model was logged from
            return _from_store(model.group(1), tracking_uri)
    except TrackingError as err:
        raise AgentError(str(err)) from err
    raise AgentError(
        f"run={spec}: there is no such file or folder, and it is neither a "
        f"reference:<run>/<agent>, an MLflow run id nor a model URI runs:/<run id>/agent."
    )
