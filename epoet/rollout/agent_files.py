"""The two agent file formats a rollout can run, read and checked: ES parameters (an .npz of
`theta` and `layer_sizes`) and exported torch policies (`policy.pt`, written by
epoet.rl.policy_file). Evaluation (epoet.eval.agents) and the torch policy's loader both check
files here, so a bad file gets the same one-line error everywhere."""

from __future__ import annotations

import zipfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from epoet.envs.spaces import ACT_DIM, OBS_DIM
from epoet.rl.config import RL_ACTIVATIONS
from epoet.rollout.policy import num_params

TORCH_POLICY = "policy.pt"
ES_POLICIES = "policies"


POLICY_FORMAT = "epoet-policy/1"


class AgentError(ValueError):
    """A run spec that names no usable agent; one sentence."""


VALID = {
    "es": "an .npz of ES parameters (theta: the flat finite parameter vector, layer_sizes: "
    "{obs}, ..., {act})",
    "torch": f"a {TORCH_POLICY} that a PPO, SAC or VMPO run exported",
}


def bad_agent(path: Path, kind: str, problem: str) -> AgentError:
    """One sentence: the file, what is wrong with it and what a valid one is."""
    return AgentError(
        f"{path} {problem}: a valid agent file is {VALID[kind].format(obs=OBS_DIM, act=ACT_DIM)}."
    )


def check_network(
    path: Path, kind: str, sizes: Sequence[int], params: Iterable[tuple[str, np.ndarray]]
) -> None:
    """The check every policy format shares: it maps the task's observations to its actions
    and all its parameters are finite (NaN weights would act NaN and crash the episode)."""
    if sizes[0] != OBS_DIM or sizes[-1] != ACT_DIM:
        raise bad_agent(
            path,
            kind,
            f"maps {sizes[0]} observations to {sizes[-1]} actions, but "
            f"the task has {OBS_DIM} observations and {ACT_DIM} actions",
        )
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
    check_network(path, "es", sizes_tuple, [])
    if theta.ndim != 1 or theta.dtype.kind not in "fiu" or len(theta) != num_params(sizes_tuple):
        raise bad_agent(
            path,
            "es",
            f"has theta of shape {theta.shape} ({theta.dtype}), but "
            f"layer_sizes {list(sizes_tuple)} take "
            f"{num_params(sizes_tuple)} numbers",
        )
    theta = theta.astype(np.float64)
    check_network(path, "es", sizes_tuple, [("theta", theta)])
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
        path,
        "torch",
        sizes,
        [(k, v.detach().double().numpy()) for k, v in [*weights.items(), *norm]],
    )
    return spec
