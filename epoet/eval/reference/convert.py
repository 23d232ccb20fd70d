"""`python -m epoet.eval.reference source=<checkout of ml-tue/ePOET_3D> [out=] [check=true]`:
the authors' published agents and evaluation terrains in epoet's formats.

Writes, under `out` (default: the shipped epoet/reference/):
- `agents/<run>/<agent>.npz`: each ES niche agent of the runs in ES_RUNS (`theta` in epoet's
  layout, `layer_sizes`, `score` as their run logged it, `reference_theta` as published, and
  `provenance`, a JSON text);
- `agents/<run>/<seed>.pt`: the PPO, SAC and VMPO policies in epoet's exported-policy format
  (epoet.rl.policy_file), their observation normaliser included, tanh of the mean as the
  authors' `eval_act` squashed it, plus `provenance`;
- `genomes.json`: the 32 CPPN genomes of `cppngenomes_b` as plain data;
- `suite/`: those genomes rendered as the reference's evaluation terrains (`suite=paper`).
Every agent is re-ordered to epoet's observation and action (layout.py) and `manifest.json`
lists each with its source path, the checkout's commit and the score the reference logged.
Nothing of the authors' code is imported (pickles.py); the output is the same bytes each time,
so check=true proves the shipped folder is the checkout's conversion.

Examples:

    git clone https://github.com/ml-tue/ePOET_3D /tmp/ePOET_3D
    python -m epoet.eval.reference source=/tmp/ePOET_3D check=true
    python -m epoet.eval.reference source=/tmp/ePOET_3D out=/tmp/reference
"""

from __future__ import annotations

import csv
import io
import json
import re
import subprocess
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from epoet.cli import KeyValueCommand
from epoet.core.cli import fail
from epoet.core.files import atomic_write
from epoet.core.schema import ConfigError
from epoet.eval.config import ReferenceConfig
from epoet.eval.reference import FOLDER, MANIFEST
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
from epoet.eval.reference.pickles import ReferenceFileError, read_genome, read_normaliser, to_neat
from epoet.eval.suite import load_suite
from epoet.eval.suite_format import SUITE_FORMAT, level_of, quantize
from epoet.rollout.agent_files import POLICY_FORMAT
from epoet.rollout.policy import num_params
from epoet.terrain.cppn import render_reference
from epoet.terrain.reference_rendering import EVAL_HEIGHT

COMMAND = KeyValueCommand("reference", __doc__, ReferenceConfig)

REPOSITORY = "github.com/ml-tue/ePOET_3D"
MODELS = "trained_models"
# run -> (folder under trained_models, algorithm)
ES_RUNS = {
    "poet_hexA8": ("poet/poet_hexA8", "epoet"),
    "poet_twin22": ("poet_sac/poet_twin22", "epoet_sac"),
}
# run -> (activation, has an observation normaliser); the files are model/model_pf_best.pth
TORCH_RUNS = {"ppo/0": ("tanh", True), "sac/42": ("relu", False), "vmpo/42": ("tanh", True)}
CRITIC_RUNS = ("sac/42",)  # their twin Q networks too (model_qf1_best.pth, model_qf2_best.pth)
CRITICS_FORMAT = "epoet-twin-q/1"  # TwinQ's state dict (epoet.rl.sac_loss), plus provenance
_LAYERS = ("base.seq_fcs.0", "base.seq_fcs.2", "seq_append_fcs.0")
ES_SIZES = (OBS_DIM, 40, 40, ACT_DIM)  # their ES agents' MLP (docs/reference.md)
GENOMES = f"{MODELS}/cppngenomes/cppngenomes_b"
NORM_EPS = 1e-4  # their normaliser divides by sqrt(var) + 1e-4
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed, so a conversion is the same bytes every time
# Table 1's denominators in the reference's evaluate_rl_models.py: 9 easy, 14 medium, 9 hard
LEVEL_COUNTS = (("easy", 9), ("medium", 14), ("hard", 9))
_UUID = re.compile(r"^[0-9a-f]{8}-[0-9a-f]{4}-")


def npz_bytes(arrays: Mapping[str, np.ndarray | np.generic]) -> bytes:
    """An .npz (np.load reads it) without the write time numpy's savez puts in it."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, value in arrays.items():
            array = io.BytesIO()
            np.lib.format.write_array(array, np.asanyarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", _ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, array.getvalue())
    return buffer.getvalue()


def _commit(source: Path) -> str:
    try:
        return subprocess.run(
            ["git", "-C", str(source), "rev-parse", "HEAD"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"


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


def convert_suite(source: Path, files: dict[str, bytes]) -> dict[str, Any]:
    """genomes.json and the paper suite: the k-th genome (by file name: the authors' save
    times, so 4 rounds of 8) is terrain r<k // 8>c<k % 8>, its bowl drawn from seed k.

    Levels: the reference bucketed the patch variance under each agent's own path, so its
    levels depended on the agent; its evaluate_rl_models.py then fixed Table 1's counts at 9
    easy, 14 medium and 9 hard. Here the terrains are ranked by their course roughness (the
    same variance along the straight course, epoet.eval.suite) and given those counts; the
    reference's thresholds on that roughness are kept as `threshold_level`."""
    paths = sorted((source / GENOMES).glob("*.pickle"))
    if len(paths) != sum(n for _, n in LEVEL_COUNTS):
        raise ReferenceFileError(
            f"{source / GENOMES} holds {len(paths)} genome pickles, not "
            f"the {sum(n for _, n in LEVEL_COUNTS)} of the paper's suite."
        )
    course = load_suite().course  # the reference's course, as the shipped suite has it
    genomes, heights = {}, {}
    entries: list[dict[str, Any]] = []
    for k, path in enumerate(paths):
        name = f"r{k // 8}c{k % 8}"
        genome = read_genome(path)
        genomes[name] = {"source": str(path.relative_to(source)), **genome}
        heights[name] = quantize(render_reference(to_neat(genome), k, EVAL_HEIGHT))
        rough = course.roughness(heights[name] / 65535.0, EVAL_HEIGHT**2, 40.0)
        entries.append(
            {
                "name": name,
                "roughness": rough,
                "threshold_level": level_of(rough),
                "max_height": EVAL_HEIGHT**2,
                "round": k // 8,
                "child": k % 8,
                "seed": k,
                "genome": path.name,
            }
        )
    ranked = sorted(range(len(entries)), key=lambda k: entries[k]["roughness"])
    bounds = np.cumsum([n for _, n in LEVEL_COUNTS])
    for rank, k in enumerate(ranked):
        entries[k]["level"] = LEVEL_COUNTS[int(np.searchsorted(bounds, rank, side="right"))][0]
    index = {
        "format": SUITE_FORMAT,
        "size": 40.0,
        "grid": 200,
        "course": vars(course),
        "origin": f"{REPOSITORY} {GENOMES}, rendered by epoet.terrain.reference_rendering",
        "terrains": entries,
    }
    files["genomes.json"] = (json.dumps(genomes, indent=1) + "\n").encode()
    files["suite/heights.npz"] = npz_bytes(heights)
    files["suite/suite.json"] = (json.dumps(index, indent=1) + "\n").encode()
    return {e["name"]: e["level"] for e in entries}


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
    levels = convert_suite(source, files)
    manifest = {
        "source": {"repository": REPOSITORY, "commit": _commit(source)},
        "agents": agents,
        "suite_levels": levels,
    }
    files[MANIFEST] = (json.dumps(manifest, indent=1) + "\n").encode()
    return files


def differences(out: Path, files: dict[str, bytes]) -> list[str]:
    return [
        name
        for name, data in files.items()
        if not (out / name).is_file() or (out / name).read_bytes() != data
    ]


def main(argv: list[str] | None = None) -> None:
    cfg: ReferenceConfig = COMMAND.parse(argv)
    try:
        out = FOLDER if cfg.out is None else Path(cfg.out)
        assert cfg.source is not None  # required: ReferenceConfig checks it
        files = convert(Path(cfg.source))
        if cfg.check:
            if found := differences(out, files):
                fail(
                    ReferenceFileError(
                        f"{out} differs from the conversion of {cfg.source} in "
                        f"{len(found)} file(s): {', '.join(found[:5])}."
                    )
                )
            print(f"{out} matches the conversion of {cfg.source} bit for bit ({len(files)} files)")
            return
        for name, data in files.items():
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(out / name) as f:
                f.write(data)
        print(f"wrote {len(files)} files to {out}/")
    except (ConfigError, ReferenceFileError, OSError) as err:
        fail(err)
