"""`algo.sac_init`: where ePOET-SAC's SAC learner starts.

- null: cold (random weights, the first `algo.sac.init_random_frames` frames uniform actions);
- `reference:sac/42`: the authors' SAC actor and twin critics, converted from their files
  (epoet.eval.reference: agents/sac/42.pt, agents/sac/42.critics.pt; already in epoet's
  observation and action order), as the reference's ePOET-SAC loaded its finished SAC baseline:
  a head start of their 24 hours of compute, which no budget counts;
- a SAC run of ours: its run folder (the exported `policy.pt`, and `critics.pt` or, for a run
  from before SAC runs exported their critics, the checkpoint's) or its MLflow run id (the
  `policy.pt` and `critics.pt` artifacts).

A warm start loads the actor's MLP and the critics as they are (the target critics a copy; the
optimiser's state stays fresh) with the temperature the source finished at (`alpha`: the
authors' from their log, ours from the run's checkpoint or its last `train/alpha`; the loop
takes `algo.warm.alpha` instead when set), so the layer sizes and activation must be
`algo.sac`'s, the weights must be the run's robot's (the authors' are the hexapod's: other robots
take only their `agent.published_sac`) and act on raw observations (a SAC run with `algo.obs_norm=true`
reads clipped normalised observations, which do not fold into a layer). The actor keeps the
scale mapping it was trained with: TorchRL's biased softplus for ours, the authors'
exp(clamp(log_std, -20, 2)) for theirs (epoet/rl/nets.py says why no weights convert one into
the other). Anything else is refused in one sentence (ConfigError) before the run starts:
its schema's `check_inputs` (epoet/epoet_sac/config.py) calls this module before the tracker opens.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import torch

from epoet.core.checkpoint import CHECKPOINT_NAME, CheckpointError, load_checkpoint
from epoet.core.schema import ConfigError
from epoet.envs.config import AgentConfig
from epoet.envs.spaces import robot_sizes
from epoet.epoet_sac.config import WarmConfig
from epoet.rl.nets import LOG_STD_SCALE, SOFTPLUS_SCALE
from epoet.rl.policy_file import CRITICS_FILE, POLICY_FILE, read_critics
from epoet.rollout.agent_files import LAYOUT, AgentError, read_torch_policy, robot_mismatch
from epoet.sac.config import SacLearnerConfig

REFERENCE = "reference:"
RUN_ID = re.compile(r"^[0-9a-f]{32}$")
CRITIC_PREFIX = "critics."  # the critics' keys in a SAC checkpoint's loss state
# The authors' SAC temperature when their shipped weights were saved: their files hold no
# log_alpha, but their log does. model_pf_best.pth is the epoch of the best running average
# (1370.43, epoch 154 of trained_models/sac/42/log.csv), whose Alpha_Mean is 0.00920 (0.0091-0.0094
# from epoch 80 to the end); their twin SAC scaled rewards by 5 (twin_sac_q.py `scale_reward`),
# as algo.sac.reward_scale does, so the value carries over unchanged.
REFERENCE_ALPHA = {"sac/42": 0.0092}


@dataclass(frozen=True)
class WarmStart:
    """Trained SAC weights on raw observations: the actor's MLP (the exported policy's state
    dict) and the twin critics (TwinQ's)."""

    source: str
    actor: dict[str, torch.Tensor]
    critics: dict[str, torch.Tensor]
    scale_mapping: str
    alpha: float | None  # the source's final temperature (None: not recorded)


class _Found(NamedTuple):
    """A source's files, read and checked as files (`load_warm_start` checks the layout)."""

    actor: dict[str, Any]  # the exported policy's plain data
    critics: dict[str, Any]  # the critics file's plain data
    scale_mapping: str
    alpha: float | None


def scale_mapping_for(sac_init: str | None) -> str:
    """The actor's scale head for a start (a function of the setting alone, so a resumed run
    builds the same network without reading the source again)."""
    return LOG_STD_SCALE if sac_init and sac_init.startswith(REFERENCE) else SOFTPLUS_SCALE


def _fail(spec: str, problem: str) -> ConfigError:
    return ConfigError(f"algo.sac_init={spec} {problem}.")


def _reference(spec: str) -> _Found:
    from epoet.eval.reference import folder, manifest
    from epoet.eval.reference.files import ReferenceFileError

    try:
        agents = manifest()["agents"]
    except ReferenceFileError as err:
        raise _fail(spec, f"needs the authors' files: {str(err).rstrip('.')}") from None
    usable = [f"{REFERENCE}{n}" for n, e in agents.items() if e.get("critics")]
    entry = agents.get(spec.removeprefix(REFERENCE))
    if entry is None or not entry.get("critics"):
        what = (
            "names no agent of the authors'"
            if entry is None
            else f"is the authors' {entry['algo']} agent"
        )
        raise _fail(
            spec, f"{what}; a warm start takes a SAC actor with its critics ({', '.join(usable)})"
        )
    actor = folder() / entry["file"]
    name = spec.removeprefix(REFERENCE)
    critics = folder() / entry["critics"]
    return _from_files(spec, actor, critics, LOG_STD_SCALE, REFERENCE_ALPHA.get(name))


def _from_files(
    spec: str,
    policy: Path,
    critics: Path | dict[str, Any],
    scale_mapping: str,
    alpha: float | None,
) -> _Found:
    try:
        actor = read_torch_policy(policy)
        critic_spec = read_critics(critics) if isinstance(critics, Path) else critics
    except (AgentError, ValueError) as err:
        raise _fail(spec, f"has no usable SAC weights ({str(err).rstrip('.')})") from None
    if actor["obs_loc"] is not None:
        raise _fail(
            spec,
            "reads clipped normalised observations (its algo.obs_norm=true), "
            "which do not fold into a layer; a warm start takes a SAC run on raw "
            "observations",
        )
    last = f"{2 * len(actor['hidden'])}.weight"
    if actor["state_dict"][last].shape[0] != 2 * int(actor["act_dim"]):
        raise _fail(
            spec, "has no SAC actor (its output layer is not a mean and a scale per action)"
        )
    return _Found(actor, critic_spec, scale_mapping, alpha)


def _from_folder(spec: str, folder: Path) -> _Found:
    try:
        state = load_checkpoint(folder / CHECKPOINT_NAME)
    except CheckpointError as err:
        raise _fail(
            spec, f"is not a run folder with a readable {CHECKPOINT_NAME} ({str(err).rstrip('.')})"
        ) from None
    algo = state.get("algo")
    if algo != "sac":
        raise _not_sac(spec, algo)
    if not (folder / POLICY_FILE).is_file():
        raise _fail(spec, f"has no {POLICY_FILE}: the SAC run has not finished")
    critics_file = folder / CRITICS_FILE
    critics: Path | dict[str, Any] = critics_file
    loss = state["learner"]["loss"]
    alpha = float(torch.as_tensor(loss["log_alpha"]).exp()) if "log_alpha" in loss else None
    if not critics_file.is_file():  # a run from before SAC runs exported their critics
        config = state["config"]["algo"]
        critics = {
            "activation": config["activation"],
            "hidden": list(config["hidden"]),
            "state_dict": {
                k.removeprefix(CRITIC_PREFIX): v
                for k, v in loss.items()
                if k.startswith(CRITIC_PREFIX)
            },
        }
    return _from_files(spec, folder / POLICY_FILE, critics, SOFTPLUS_SCALE, alpha)


def _not_sac(spec: str, algo: str | None) -> ConfigError:
    return _fail(
        spec,
        f"is an algo={algo} run; a warm start takes the actor and critics of an "
        f"algo=sac run (its folder or MLflow run id) or of reference:sac/42",
    )


def _from_store(spec: str, tracking_uri: str | None) -> _Found:
    from epoet.tracking import StoredRun, TrackingError  # mlflow: only for a run in the store

    try:
        stored = StoredRun.open(spec, tracking_uri)
    except TrackingError as err:
        raise _fail(spec, f"is not a usable MLflow run ({str(err).rstrip('.')})") from None
    if stored.tags.get("algo") != "sac":
        raise _not_sac(spec, stored.tags.get("algo"))
    for name in (POLICY_FILE, CRITICS_FILE):
        if not stored.has_artifact(name):
            raise _fail(
                spec,
                f"has no {name} artifact (SAC runs log their critics from this "
                f"version on); give its run folder, whose checkpoint holds them",
            )
    with tempfile.TemporaryDirectory(prefix="epoet-sac-init-") as tmp:
        policy = stored.download(POLICY_FILE, Path(tmp))
        critics = stored.download(CRITICS_FILE, Path(tmp))
        alpha = stored.metrics.get("train/alpha")  # the last logged value
        return _from_files(spec, policy, critics, SOFTPLUS_SCALE, alpha)


@lru_cache(maxsize=4)
def _resolve(spec: str, tracking_uri: str | None) -> _Found:
    if spec.startswith(REFERENCE):
        return _reference(spec)
    if Path(spec).is_dir():
        return _from_folder(spec, Path(spec))
    if RUN_ID.match(spec):
        return _from_store(spec, tracking_uri)
    if not Path(spec).exists():
        raise ConfigError(
            f"algo.sac_init={spec}: there is no such folder, and it is neither "
            "reference:sac/42 nor an MLflow run id."
        )
    raise _fail(spec, "is neither reference:sac/42, a SAC run folder nor an MLflow run id")


def load_warm_start(
    spec: str, sac: SacLearnerConfig, agent: AgentConfig, tracking_uri: str | None = None
) -> WarmStart:
    """The start `spec` names, checked against the learner's layout and the run's robot;
    ConfigError in one sentence for anything that cannot start this learner."""
    start = _resolve(spec, tracking_uri)
    if spec.startswith(REFERENCE) and spec != agent.published_sac:
        published = agent.published_sac or "none"
        raise _fail(
            spec, f"is not this robot's published SAC agent ({published}); null starts cold"
        )
    actor, critics = start.actor, start.critics
    actor_sizes = (int(actor["obs_dim"]), int(actor["act_dim"]))
    mismatch = robot_mismatch(actor_sizes, actor.get(LAYOUT), agent)
    if mismatch is not None:
        raise _fail(spec, f"{mismatch[0]} (algo.sac_init=null starts cold)")
    mine = (list(sac.hidden), sac.activation)
    for what, spec_of in (("actor", actor), ("critics", critics)):
        theirs = ([int(n) for n in spec_of["hidden"]], spec_of["activation"])
        if theirs != mine:
            raise _fail(
                spec,
                f"has a {theirs[0]} {theirs[1]} {what}, but algo.sac.hidden="
                f"{mine[0]} and algo.sac.activation={mine[1]}: a warm start loads "
                f"the weights as they are, so they must match",
            )
    obs_dim, act_dim = robot_sizes(agent)
    sizes = [obs_dim + act_dim, *mine[0], 1]
    expected = {
        **{f"weights.{i}": (2, a, b) for i, (a, b) in enumerate(zip(sizes, sizes[1:]))},
        **{f"biases.{i}": (2, 1, b) for i, b in enumerate(sizes[1:])},
    }
    got = {k: tuple(v.shape) for k, v in critics["state_dict"].items()}
    if got != expected:
        raise _fail(
            spec,
            f"has critics whose weights {got} are not twin Q networks of "
            f"{obs_dim} observations and {act_dim} actions",
        )
    return WarmStart(
        spec,
        dict(actor["state_dict"]),
        dict(critics["state_dict"]),
        start.scale_mapping,
        start.alpha,
    )


def warm_start_alpha(start: WarmStart, warm: WarmConfig) -> float:
    """The temperature a warm-started learner resumes with: `algo.warm.alpha`, else the
    source's final one; ConfigError when neither is known."""
    if warm.alpha is not None:
        return warm.alpha
    if start.alpha is None:
        raise _fail(
            start.source,
            "records no final temperature; set algo.warm.alpha (the temperature its actor was "
            "trained with)",
        )
    return start.alpha
