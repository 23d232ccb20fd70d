"""Trained agents, wherever they live: an MLflow run, a run folder or a policy file.

Evaluation and rendering take `run=<spec>` and need three things from it: a policy
(`obs -> action`), the episode rules it was trained with (agent config, the budget's threshold
scale) and, when there is one, the MLflow run to log results to. Two policy formats exist:
- ES parameters (`.npz` with `theta` and `layer_sizes`): ePOET's and ePOET-SAC's pool agents,
  `policies/env<N>.npz` (with their `score`); a run's agent is the pool's best by score;
- exported torch policies (`policy.pt`, `epoet.rl.policy_file`): PPO, SAC and VMPO.
"""
from __future__ import annotations

import atexit
import re
import shutil
import tempfile
import zipfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from epoet.core.checkpoint import CHECKPOINT_NAME, CheckpointError, load_checkpoint
from epoet.envs.config import AgentConfig
from epoet.rl.config import RL_ACTIVATIONS
from epoet.rollout.policy import LAYER_SIZES, forward, num_params
from epoet.tracking import StoredRun, TrackingError

Policy = Callable[[np.ndarray], np.ndarray]
RUN_ID = re.compile(r"^[0-9a-f]{32}$")
MODEL_URI = re.compile(r"^runs:/([0-9a-f]{32})/agent/?$")  # the run's MLflow model (agent_model)
TORCH_POLICY = "policy.pt"
ES_POLICIES = "policies"


class AgentError(ValueError):
    """A run spec that names no usable agent; one sentence."""


VALID = {"es": "an .npz of ES parameters (theta: the flat finite parameter vector, layer_sizes: "
                "{obs}, ..., {act})",
         "torch": f"a {TORCH_POLICY} that a PPO, SAC or VMPO run exported"}


def task_sizes() -> tuple[int, int]:
    """The task's observation and action sizes (epoet.envs.task.OBS_DIM, ACT_DIM).

    Read from the ES layer sizes' ends, which are those numbers (tests/test_bad_agents.py checks
    it), because epoet.envs imports MuJoCo, and rendering must resolve its run before MuJoCo
    picks its OpenGL backend (epoet.eval.render.open_gl).
    """
    return LAYER_SIZES[0], LAYER_SIZES[-1]


def bad_agent(path: Path, kind: str, problem: str) -> AgentError:
    """One sentence: the file, what is wrong with it and what a valid one is."""
    obs, act = task_sizes()
    return AgentError(f"{path} {problem}: a valid agent file is "
                      f"{VALID[kind].format(obs=obs, act=act)}.")


def check_network(path: Path, kind: str, sizes: Sequence[int],
                  params: Iterable[tuple[str, np.ndarray]]) -> None:
    """The check every policy format shares: it maps the task's observations to its actions
    and all its parameters are finite (NaN weights would act NaN and crash the episode)."""
    obs, act = task_sizes()
    if sizes[0] != obs or sizes[-1] != act:
        raise bad_agent(path, kind, f"maps {sizes[0]} observations to {sizes[-1]} actions, but "
                                    f"the task has {obs} observations and {act} actions")
    for name, values in params:
        if not np.isfinite(values).all():
            raise bad_agent(path, kind, f"has non-finite parameters (NaN or inf) in {name}")


def read_es_policy(path: Path) -> tuple[np.ndarray, tuple[int, ...]]:
    """An ES policy file's checked (theta, layer_sizes), or AgentError."""
    try:
        with np.load(path, allow_pickle=False) as data:
            if not isinstance(data, np.lib.npyio.NpzFile):
                raise TypeError  # a bare .npy array
            arrays = {key: data[key] for key in ("theta", "layer_sizes") if key in data}
    except (OSError, ValueError, EOFError, TypeError, zipfile.BadZipFile):
        raise bad_agent(path, "es", "is not a readable .npz file") from None
    missing = [key for key in ("theta", "layer_sizes") if key not in arrays]
    if missing:
        raise bad_agent(path, "es", f"has no {' and no '.join(missing)}")
    theta, sizes = arrays["theta"], arrays["layer_sizes"]
    if sizes.ndim != 1 or len(sizes) < 2 or sizes.dtype.kind not in "iu" or sizes.min() < 1:
        raise bad_agent(path, "es", f"has layer_sizes {sizes.tolist()}, not a list of at least "
                                    f"two positive integers")
    sizes_tuple = tuple(int(n) for n in sizes)
    check_network(path, "es", sizes_tuple, [])
    if theta.ndim != 1 or theta.dtype.kind not in "fiu" or len(theta) != num_params(sizes_tuple):
        raise bad_agent(path, "es", f"has theta of shape {theta.shape} ({theta.dtype}), but "
                                    f"layer_sizes {list(sizes_tuple)} take "
                                    f"{num_params(sizes_tuple)} numbers")
    theta = theta.astype(np.float64)
    check_network(path, "es", sizes_tuple, [("theta", theta)])
    return theta, sizes_tuple


def read_torch_policy(path: Path) -> dict[str, Any]:
    """An exported torch policy's checked plain data (epoet.rl.policy_file), or AgentError."""
    import torch  # only when a torch policy is used

    from epoet.rl.policy_file import POLICY_FORMAT
    try:
        spec = torch.load(path, weights_only=True, map_location="cpu")
    except Exception:  # torch raises many types (UnpicklingError, RuntimeError, ...)
        raise bad_agent(path, "torch", "is not a readable torch file") from None
    if not isinstance(spec, dict) or spec.get("format") != POLICY_FORMAT:
        raise bad_agent(path, "torch", f"is not an epoet policy ({POLICY_FORMAT})")
    try:
        hidden = [int(n) for n in spec["hidden"]]
        sizes = [int(spec["obs_dim"]), *hidden, int(spec["act_dim"])]
        weights = {k: v for k, v in spec["state_dict"].items() if isinstance(v, torch.Tensor)}
        norm = [(k, spec[k]) for k in ("obs_loc", "obs_scale") if spec[k] is not None]
        clip = spec["obs_clip"]
        activation = spec["activation"]
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise bad_agent(path, "torch", f"lacks a field of {POLICY_FORMAT} ({err})") from None
    if activation not in RL_ACTIVATIONS:
        raise bad_agent(path, "torch", f"has an unknown activation {activation!r}")
    expected = {}
    for layer, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        expected[f"{2 * layer}.weight"] = (n_out, n_in)
        expected[f"{2 * layer}.bias"] = (n_out,)
    last = f"{2 * len(hidden)}"  # the output layer may also hold the scales: >= act_dim rows
    if f"{last}.weight" in weights and weights[f"{last}.weight"].shape[0] >= sizes[-1]:
        rows = weights[f"{last}.weight"].shape[0]
        expected[f"{last}.weight"], expected[f"{last}.bias"] = (rows, sizes[-2]), (rows,)
    shapes = {k: tuple(v.shape) for k, v in weights.items()}
    if shapes != expected or set(weights) != set(spec["state_dict"]):
        raise bad_agent(path, "torch", f"has weights that do not fit its layer sizes {sizes}")
    if len(norm) not in (0, 2) or (norm and not isinstance(clip, (int, float))) or any(
            not isinstance(v, torch.Tensor) or tuple(v.shape) != (sizes[0],) for _, v in norm):
        raise bad_agent(path, "torch", f"has an observation normaliser that is not obs_loc and "
                                       f"obs_scale of shape ({sizes[0]},) with an obs_clip")
    check_network(path, "torch", sizes,
                  [(k, v.detach().double().numpy()) for k, v in [*weights.items(), *norm]])
    return spec


@dataclass(frozen=True)
class AgentSource:
    """A policy file and its format; picklable, so worker processes load it themselves."""

    kind: str    # "es" | "torch"
    path: Path

    def check(self) -> None:
        """AgentError unless the file is a usable policy for the task; cheap, and imports no
        MuJoCo, so commands check it before any other work."""
        if self.kind == "es":
            read_es_policy(self.path)
        else:
            read_torch_policy(self.path)

    def load(self) -> Policy:
        """The checked policy (AgentError for a bad file)."""
        if self.kind == "es":
            theta, sizes = read_es_policy(self.path)
            return lambda obs: forward(theta, obs, sizes)
        from epoet.rl.policy_file import load_policy  # torch only when a torch policy is used
        return load_policy(self.path)


@dataclass(frozen=True)
class TrainedRun:
    """What `run=<spec>` resolved to."""

    agent: AgentSource
    label: str                       # e.g. "epoet-s1 env3" or a file's stem
    stored: StoredRun | None         # the MLflow run to log results to, when known
    algo: str | None
    seed: str | None
    config: dict[str, Any] | None    # the run's resolved config, when known
    folder: Path | None              # the run folder, when given one

    @property
    def run_id(self) -> str | None:
        return None if self.stored is None else self.stored.run_id

    def agent_config(self, default: AgentConfig) -> AgentConfig:
        """The episode rules the agent was trained with (a bare policy file: `default`)."""
        if self.config is None:
            return default
        merged = OmegaConf.merge(OmegaConf.structured(AgentConfig), self.config["agent"])
        return OmegaConf.to_object(merged)

    @property
    def score_scale(self) -> float:
        """The run's budget scales the paper's score thresholds (README, Budgets)."""
        if self.config is None:
            return 1.0
        return float(self.config["budget"]["score_scale"])


def policy_in(folder: Path) -> tuple[AgentSource, str] | None:
    """A run folder's exported agent and its name: the best pool agent (highest score) or the
    exported torch policy; None if it has neither."""
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
    stored = StoredRun.open(run_id, tracking_uri)
    folder = _download_dir()
    for artifact in (ES_POLICIES, TORCH_POLICY):
        if stored.has_artifact(artifact):
            stored.download(artifact, folder)
            break
    found = policy_in(folder)
    if found is None:
        raise AgentError(f"run {run_id} ({stored.name}, {stored.status}) has no policy artifact "
                         f"({ES_POLICIES}/ or {TORCH_POLICY}): evaluate a run that finished "
                         f"training.")
    config = None
    if stored.has_artifact("config.yaml"):
        config = OmegaConf.to_container(OmegaConf.load(stored.download("config.yaml", folder)))
    source, name = found
    source.check()
    label = stored.name if source.kind == "torch" else f"{stored.name} {name}"
    return TrainedRun(source, label, stored, stored.tags.get("algo"), stored.tags.get("seed"),
                      config, None)


def _from_folder(folder: Path, tracking_uri: str | None) -> TrainedRun:
    found = policy_in(folder)
    if found is None:
        raise AgentError(f"run folder {folder} has no policy ({ES_POLICIES}/env<N>.npz or "
                         f"{TORCH_POLICY}): evaluate a run that finished training.")
    state: dict[str, Any] = {}
    if (folder / CHECKPOINT_NAME).is_file():
        try:
            state = load_checkpoint(folder)
        except CheckpointError as err:
            raise AgentError(str(err)) from err
    config = state.get("config")
    source, name = found
    source.check()
    algo = state.get("algo")
    seed = None if config is None else str(config["seed"])
    base = f"{algo}-s{seed}" if algo else folder.name
    label = base if source.kind == "torch" else f"{base} {name}"
    # The run the checkpoint continues, opened now so a missing store fails before any work.
    stored = StoredRun.open(state["run_id"], tracking_uri) if state.get("run_id") else None
    return TrainedRun(source, label, stored, algo, seed, config, folder)


def resolve_run(spec: str, tracking_uri: str | None = None) -> TrainedRun:
    """`run=<spec>`: a policy file, a run folder, an MLflow run id or its model URI
    `runs:/<run id>/agent` (in that order).

    Its policy is checked here (AgentSource.check), so a bad agent file fails before any
    episode and before the store is opened for a run folder.
    """
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
    raise AgentError(f"run={spec} is neither a policy file, a run folder, an MLflow run id nor "
                     f"a model URI runs:/<run id>/agent.")
