"""The two agent file formats a rollout can run, read and checked: ES parameters (an .npz of
`theta` and `layer_sizes`) and exported torch policies (`policy.pt`, written by
epoet.rl.policy_file). Evaluation (epoet.eval.agents) and the torch policy's loader both check
files here, so a bad file gets the same one-line error everywhere.

Both record the layout of the robot they were trained on (`layout`: epoet.envs.spaces.layout_of;
in an .npz as JSON text), which `check_robot` holds against the robot they are run with. A file
from before robots were parts records none: it is the hexapod's. Both also record the physics
integrator they were trained with (`integrator`), which a bare file is run with: a gait learned
under one integrator can fall over under another (the ant's does). A file that records none
(the authors' agents, trained with the paper's RK4) runs with `agent.integrator`.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from epoet.core.files import atomic_write, savez
from epoet.envs.config import HEXAPOD, AgentConfig
from epoet.envs.spaces import layout_of, robot_sizes
from epoet.rollout.config import RL_ACTIVATIONS
from epoet.rollout.policy import num_params

TORCH_POLICY = "policy.pt"
ES_POLICIES = "policies"
# in policies/: the pool's agent a run exports (open_ended/exported_agent.py)
EXPORTED_AGENT = "agent.npz"
# beside a baseline's exported policy when that is not its last (rl/candidates.py)
LAST_POLICY = "policy_last.pt"


POLICY_FORMAT = "epoet-policy/1"
LAYOUT = "layout"  # the key of the recorded robot layout in both formats
INTEGRATOR = "integrator"  # the key of the recorded physics integrator in both formats


class AgentError(ValueError):
    """A run spec that names no usable agent; one sentence."""


VALID = {
    "es": "an .npz of ES parameters (theta: the flat finite parameter vector, layer_sizes: "
    "its observations, hidden sizes and actions)",
    "torch": f"a {TORCH_POLICY} that a PPO, SAC or VMPO run exported",
}


def bad_agent(path: Path, kind: str, problem: str) -> AgentError:
    """One sentence: the file, what is wrong with it and what a valid one is."""
    return AgentError(f"{path} {problem}: a valid agent file is {VALID[kind]}.")


def check_network(path: Path, kind: str, params: Iterable[tuple[str, np.ndarray]]) -> None:
    """The check every policy format shares: all its parameters are finite (NaN weights would
    act NaN and crash the episode)."""
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
        raise bad_agent(
            path,
            "es",
            f"has layer_sizes {sizes.tolist()}, not a list of at least two positive integers",
        )
    sizes_tuple = tuple(int(n) for n in sizes)
    if theta.ndim != 1 or theta.dtype.kind not in "fiu" or len(theta) != num_params(sizes_tuple):
        raise bad_agent(
            path,
            "es",
            f"has theta of shape {theta.shape} ({theta.dtype}), but "
            f"layer_sizes {list(sizes_tuple)} take "
            f"{num_params(sizes_tuple)} numbers",
        )
    theta = theta.astype(np.float64)
    check_network(path, "es", [("theta", theta)])
    return theta, sizes_tuple


def read_torch_policy(path: Path) -> dict[str, Any]:
    """An exported torch policy's checked plain data (epoet.rl.policy_file), or AgentError."""
    import torch  # only when a torch policy is used

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
    expected: dict[str, tuple[int, ...]] = {}
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
    if (
        len(norm) not in (0, 2)
        or (norm and not isinstance(clip, (int, float)))
        or any(not isinstance(v, torch.Tensor) or tuple(v.shape) != (sizes[0],) for _, v in norm)
    ):
        raise bad_agent(
            path,
            "torch",
            f"has an observation normaliser that is not obs_loc and "
            f"obs_scale of shape ({sizes[0]},) with an obs_clip",
        )
    check_network(
        path, "torch", [(k, v.detach().double().numpy()) for k, v in [*weights.items(), *norm]]
    )
    return spec


def write_es_policy(
    path: Path,
    theta: np.ndarray,
    score: float,
    layer_sizes: Sequence[int],
    agent: AgentConfig,
    **extra: Any,
) -> Path:
    """An ES agent file as `read_es_policy` and `recorded_layout` read it (theta, its score, the
    layer sizes, the layout and integrator of the robot it was trained on), with `extra` arrays
    beside them (a run's bookkeeping), written atomically: the one writer of the format,
    whichever algorithm trained the agent."""
    arrays = {
        "theta": theta,
        "score": np.float64(score),
        "layer_sizes": np.array(layer_sizes),
        LAYOUT: np.array(json.dumps(layout_of(agent))),  # JSON text: no pickle to load
        INTEGRATOR: np.array(agent.integrator),
    }
    with atomic_write(path) as file:
        savez(file, {**arrays, **extra})
    return path


def recorded_layout(path: Path, kind: str) -> tuple[tuple[int, int], dict[str, Any] | None]:
    """A checked policy file's observation and action sizes and the layout it records (None:
    none, the hexapod's)."""
    if kind == "torch":
        spec = read_torch_policy(path)
        return (int(spec["obs_dim"]), int(spec["act_dim"])), spec.get(LAYOUT)
    _, layer_sizes = read_es_policy(path)
    with np.load(path, allow_pickle=False) as data:
        text = str(data[LAYOUT]) if LAYOUT in data else None
    try:
        layout = None if text is None else json.loads(text)
    except ValueError:
        raise bad_agent(path, kind, f"has a {LAYOUT} that is not JSON text") from None
    return (layer_sizes[0], layer_sizes[-1]), layout


def recorded_integrator(path: Path, kind: str) -> str | None:
    """The physics integrator a checked policy file was trained with (None: it records none)."""
    if kind == "torch":
        recorded = read_torch_policy(path).get(INTEGRATOR)
    else:
        read_es_policy(path)
        with np.load(path, allow_pickle=False) as data:
            recorded = str(data[INTEGRATOR]) if INTEGRATOR in data else None
    return None if recorded is None else str(recorded)


def robot_mismatch(
    sizes: tuple[int, int], layout: dict[str, Any] | None, agent: AgentConfig
) -> tuple[str, bool] | None:
    """Why a policy of these observation and action sizes, recording `layout`, cannot run on
    `agent`'s robot, and whether it names another robot (None: it can run)."""
    robot = HEXAPOD if layout is None else layout.get("robot")
    if robot != agent.name:
        return f"was trained on the {robot}, not on the {agent.name}", True
    if layout is not None and layout != layout_of(agent):
        return (
            f"was trained on a {robot} whose observation or action layout (its joints or "
            f"feet) differs from agent={agent.name}'s",
            True,
        )
    want = robot_sizes(agent)
    if sizes != want:
        return (
            f"maps {sizes[0]} observations to {sizes[1]} actions, but the {agent.name} has "
            f"{want[0]} observations and {want[1]} actions",
            False,
        )
    return None


def check_robot(path: Path, kind: str, agent: AgentConfig) -> None:
    """AgentError unless the file was trained on `agent`'s robot, with its layout and sizes."""
    mismatch = robot_mismatch(*recorded_layout(path, kind), agent)
    if mismatch is None:
        return
    problem, other_robot = mismatch
    if not other_robot:
        raise bad_agent(path, kind, problem)
    raise AgentError(
        f"{path} {problem}: it runs on the robot it records (for a policy file: agent=<robot>)."
    )
