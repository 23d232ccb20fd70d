"""`python -m epoet.eval.reference [source=<copy of ml-tue/ePOET_3D>] [out=] [check=true]`:
the authors' published agents and evaluation terrains in epoet's formats.

Every command that needs them converts on use (files.py: into a cache folder, keyed by the
inputs' hashes and `CONVERTER_VERSION`); this command does the same conversion by hand and
prints the folder, or writes it to `out`, or with check=true compares `out` with it. Writes:
- `agents/<run>/<agent>.npz`: each ES niche agent of the runs in ES_RUNS (`theta` in epoet's
  layout, `layer_sizes`, `score` as their run logged it, `reference_theta` as published, and
  `provenance`, a JSON text);
- `agents/<run>/<seed>.pt`: the PPO, SAC and VMPO policies in epoet's exported-policy format
  (epoet.rl.policy_file), their observation normaliser included, tanh of the mean as the
  authors' `eval_act` squashed it, plus `provenance`;
- `genomes.json`: the 32 CPPN genomes of `cppngenomes_b` as plain data;
- `suite/`: those genomes rendered as the reference's evaluation terrains (`suite=paper`).
Every agent is re-ordered to epoet's observation and action (layout.py) and `manifest.json`
lists each with its source path, the source's commit and the score the reference logged.
Nothing of the authors' code is imported (pickles.py); the output is the same bytes each time.

Examples:

    python -m epoet.eval.reference                            # convert (once) and print where
    python -m epoet.eval.reference source=/tmp/ePOET_3D out=/tmp/reference
    python -m epoet.eval.reference out=/tmp/reference check=true
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import re
import shutil
import sys
import tempfile
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from epoet.cli import KeyValueCommand
from epoet.core.cli import fail
from epoet.core.files import atomic_write, npz_bytes
from epoet.core.schema import ConfigError
from epoet.eval.config import ReferenceConfig
from epoet.eval.reference.files import (
    CRITIC_RUNS,
    ES_RUNS,
    MANIFEST,
    MODELS,
    REPOSITORY,
    SOURCE,
    TORCH_RUNS,
    ReferenceFileError,
    cache_root,
    checked_inputs,
    configure,
    source,
)
from epoet.eval.reference.layout import (
    ACT_DIM,
    CONTACTS,
    LAYOUT,
    OBS_DIM,
    es_theta,
    fold_critic_input,
    fold_input,
    fold_output_rows,
    observation_source,
)
from epoet.eval.reference.pickles import read_normaliser
from epoet.eval.reference.suites import convert_admitted, convert_paper
from epoet.rollout.agent_files import POLICY_FORMAT
from epoet.rollout.policy import num_params

COMMAND = KeyValueCommand("reference", __doc__, ReferenceConfig)

# Bump when the output changes for the same inputs: every cache folder is made anew.
CONVERTER_VERSION = 2  # 2: the validation suite, admitted/

CRITICS_FORMAT = "epoet-twin-q/1"  # TwinQ's state dict (epoet.sac.loss), plus provenance
_LAYERS = ("base.seq_fcs.0", "base.seq_fcs.2", "seq_append_fcs.0")
ES_SIZES = (OBS_DIM, 40, 40, ACT_DIM)  # their ES agents' MLP (docs/reference.md)
NORM_EPS = 1e-4  # their normaliser divides by sqrt(var) + 1e-4
_UUID = re.compile(r"^[0-9a-f]{8}-[0-9a-f]{4}-")


def _es_agent(path: Path) -> tuple[np.ndarray, float]:
    try:
        theta, score = json.loads(path.read_text())
        theta = np.asarray(theta, dtype=np.float64)
        score = float(score)
    except (OSError, ValueError, TypeError) as err:
        raise ReferenceFileError(
            f"{path} is not a niche agent ([theta, score] JSON): {err}."
        ) from None
    if theta.shape != (num_params(ES_SIZES),):
        raise ReferenceFileError(
            f"{path} holds {theta.size} parameters, not the "
            f"{num_params(ES_SIZES)} of a {'-'.join(map(str, ES_SIZES))} agent."
        )
    return theta, score


def convert_es(source: Path, files: dict[str, bytes], agents: dict[str, Any]) -> None:
    sizes = ES_SIZES
    for run, (folder, algo) in ES_RUNS.items():
        found = sorted((source / MODELS / folder).glob(f"{run}.*.best.json"))
        if not found:
            raise ReferenceFileError(f"{source / MODELS / folder} holds no {run}.*.best.json.")
        for path in found:
            niche = path.name[len(run) + 1 : -len(".best.json")]
            name = f"{run}/{niche[:8] if _UUID.match(niche) else niche}"
            theta, score = _es_agent(path)
            entry: dict[str, Any] = {
                "algo": algo,
                "kind": "es",
                "file": f"agents/{name}.npz",
                "source": str(path.relative_to(source)),
                "logged_score": score,
                "layout": LAYOUT,
            }
            files[entry["file"]] = npz_bytes(
                {
                    "theta": es_theta(theta, sizes),
                    "layer_sizes": np.array(sizes),
                    "score": np.float64(score),
                    "reference_theta": theta,
                    "provenance": np.array(json.dumps(entry)),
                }
            )
            agents[name] = entry


def _best_logged(path: Path) -> float | None:
    """The best running-average evaluation return in the run's log.csv (None without one)."""
    try:
        with path.open() as f:
            values = [float(row["Running_Average_Rewards"]) for row in csv.DictReader(f)]
    except (OSError, KeyError, ValueError):
        return None
    return max(values) if values else None


def _f32(array: np.ndarray) -> Any:
    import torch

    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32))


def convert_torch(source: Path, files: dict[str, bytes], agents: dict[str, Any]) -> None:
    import torch

    for name, (activation, normalised) in TORCH_RUNS.items():
        folder = source / MODELS / name
        path = folder / "model" / "model_pf_best.pth"
        try:
            weights = {
                k: v.double().numpy()
                for k, v in torch.load(path, map_location="cpu", weights_only=True).items()
            }
            first, second, last = (weights[f"{k}.weight"] for k in _LAYERS)
            biases = [weights[f"{k}.bias"] for k in _LAYERS]
        except Exception as err:  # torch raises many types; a missing layer is a KeyError
            raise ReferenceFileError(
                f"{path} is not the authors' policy state dict ({type(err).__name__}: {err})."
            ) from None
        loc, scale, clip, contact = np.zeros(first.shape[1]), np.ones(first.shape[1]), None, None
        if normalised:
            norm_path = folder / "model" / "_obs_normalizer_best.pkl"
            mean, var, clip = read_normaliser(norm_path)
            loc, scale = mean, np.sqrt(var) + NORM_EPS
            contact = np.clip((0.0 - loc) / scale, -clip, clip)[CONTACTS]
        w0, b0 = fold_input(first, biases[0], contact)
        w2, b2 = fold_output_rows(last, biases[2])
        if normalised:  # the normaliser in epoet's order; contacts read as 0 (weight 0 anyway)
            loc, scale = loc[observation_source()], scale[observation_source()]
            loc[CONTACTS], scale[CONTACTS] = 0.0, 1.0
        entry: dict[str, Any] = {
            "algo": name.split("/")[0],
            "kind": "torch",
            "file": f"agents/{name}.pt",
            "source": str(path.relative_to(source)),
            "logged_score": _best_logged(folder / "log.csv"),
            "layout": LAYOUT,
        }
        spec = {
            "format": POLICY_FORMAT,
            "obs_dim": int(w0.shape[1]),
            "act_dim": ACT_DIM,
            "hidden": [int(first.shape[0]), int(second.shape[0])],
            "activation": activation,
            "obs_loc": _f32(loc) if normalised else None,
            "obs_scale": _f32(scale) if normalised else None,
            "obs_clip": clip if normalised else None,
            "state_dict": {
                "0.weight": _f32(w0),
                "0.bias": _f32(b0),
                "2.weight": _f32(second),
                "2.bias": _f32(biases[1]),
                "4.weight": _f32(w2),
                "4.bias": _f32(b2),
            },
            "provenance": json.dumps(entry),
        }
        buffer = io.BytesIO()
        torch.save(spec, buffer)
        files[entry["file"]] = buffer.getvalue()
        agents[name] = entry
        if name in CRITIC_RUNS:
            entry["critics"] = f"agents/{name}.critics.pt"
            files[entry["critics"]] = _critics(folder / "model", activation)


def _critics(folder: Path, activation: str) -> bytes:
    """Their two Q networks (obs, action -> Q) as one TwinQ state dict in epoet's layout."""
    import torch

    layers: list[list[tuple[np.ndarray, np.ndarray]]] = []
    for q in ("qf1", "qf2"):
        path = folder / f"model_{q}_best.pth"
        try:
            sd = {
                k: v.double().numpy()
                for k, v in torch.load(path, map_location="cpu", weights_only=True).items()
            }
            net = [(sd[f"{k}.weight"], sd[f"{k}.bias"]) for k in _LAYERS]
        except Exception as err:  # torch raises many types; a missing layer is a KeyError
            raise ReferenceFileError(
                f"{path} is not the authors' Q network state dict ({type(err).__name__}: {err})."
            ) from None
        net[0] = fold_critic_input(*net[0])
        layers.append(net)
    state = {}
    for i in range(len(_LAYERS)):  # TwinQ: weights (2, in, out), biases (2, 1, out)
        state[f"weights.{i}"] = torch.from_numpy(
            np.stack([net[i][0].T for net in layers]).astype(np.float32)
        )
        state[f"biases.{i}"] = torch.from_numpy(
            np.stack([net[i][1][None, :] for net in layers]).astype(np.float32)
        )
    buffer = io.BytesIO()
    torch.save(
        {
            "format": CRITICS_FORMAT,
            "activation": activation,
            "hidden": [int(layers[0][0][0].shape[0]), int(layers[0][1][0].shape[0])],
            "state_dict": state,
        },
        buffer,
    )
    return buffer.getvalue()


def convert(source: Path) -> dict[str, bytes]:
    """Every output file's bytes, by its path under the output folder."""
    if not (source / MODELS).is_dir():
        raise ReferenceFileError(
            f"{source} is not a checkout of {REPOSITORY}: it has no {MODELS}/ folder."
        )
    files: dict[str, bytes] = {}
    agents: dict[str, Any] = {}
    convert_es(source, files, agents)
    convert_torch(source, files, agents)
    levels = convert_paper(source, files)
    convert_admitted(source, files)
    manifest = {
        "source": {"repository": REPOSITORY, "commit": json.loads(SOURCE.read_text())["commit"]},
        "agents": agents,
        "suite_levels": levels,
    }
    files[MANIFEST] = (json.dumps(manifest, indent=1) + "\n").encode()
    return files


@cache
def converted() -> Path:
    """The folder of the conversion every command reads, made on first use under the cache
    (files.py), keyed by the inputs' hashes and CONVERTER_VERSION; ReferenceFileError (one
    line) when the inputs are missing or not the recorded ones."""
    folder = source()
    found = checked_inputs(folder)
    key = hashlib.sha256(json.dumps([CONVERTER_VERSION, sorted(found.items())]).encode())
    out = cache_root() / "reference" / key.hexdigest()[:16]
    if not (out / MANIFEST).is_file():
        build(folder, out)
    return out


def build(folder: Path, out: Path) -> None:
    """Convert into a temporary folder beside `out`, then rename it into place, so a reader
    (another process converting at the same time, too) sees a whole conversion or none."""
    print(f"[epoet] converting the authors' files from {folder} into {out}", file=sys.stderr)
    files = convert(folder)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}."))
    try:
        for name, data in sorted(files.items(), key=lambda item: item[0] == MANIFEST):
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_bytes(data)
        try:
            tmp.rename(out)
        except OSError:  # another process finished the same conversion first
            if not (out / MANIFEST).is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def differences(out: Path, files: dict[str, bytes]) -> list[str]:
    return [
        name
        for name, data in files.items()
        if not (out / name).is_file() or (out / name).read_bytes() != data
    ]


def main(argv: list[str] | None = None) -> None:
    cfg: ReferenceConfig = COMMAND.parse(argv)
    try:
        configure(cfg.source)
        folder = source()
        checked_inputs(folder)
        if cfg.out is None and not cfg.check:
            print(f"the authors' files from {folder}, converted: {converted()}/")
            return
        out = converted() if cfg.out is None else Path(cfg.out)
        files = convert(folder)
        if cfg.check:
            if found := differences(out, files):
                fail(
                    ReferenceFileError(
                        f"{out} differs from the conversion of {folder} in "
                        f"{len(found)} file(s): {', '.join(found[:5])}."
                    )
                )
            print(f"{out} matches the conversion of {folder} bit for bit ({len(files)} files)")
            return
        for name, data in files.items():
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(out / name) as f:
                f.write(data)
        print(f"wrote {len(files)} files to {out}/")
    except (ConfigError, ReferenceFileError, OSError) as err:
        fail(err)
