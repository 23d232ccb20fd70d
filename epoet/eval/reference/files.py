"""Where the authors' published files are read from, and their conversion, made on use.

The files of github.com/ml-tue/ePOET_3D carry no licence: this repository holds none of them and
nothing converted from them. A user points the product at a copy of that repository (one
setting: the config value `epoet_3d` or the environment variable EPOET_3D; by default
`../shared/ePOET_3D` beside the project, when it exists), and the first command that needs an
agent or a terrain of theirs converts the files into a cache folder outside the source tree.

The inputs are checked against the SHA-256 of each file at the commit the records were made
with (`SOURCE.json`, ours: hashes, not their data; it also holds the hash of each file the
conversion makes, which tests/test_authors_files.py checks), so every number in docs/results/
stays reproducible; the cache folder is keyed by the inputs' hashes and the converter's version
and is rebuilt when either changes. The conversion is deterministic (convert.py), so two machines build
the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

ENV = "EPOET_3D"  # the environment variable; the config value `epoet_3d` sets it
CACHE_ENV = "EPOET_CACHE"  # where converted files go (default: $XDG_CACHE_HOME/epoet)
PROJECT = Path(__file__).resolve().parents[3]
BESIDE = PROJECT.parent / "shared" / "ePOET_3D"  # the default, when it exists
REPOSITORY = "github.com/ml-tue/ePOET_3D"
MODELS = "trained_models"
# What the conversion reads (convert.py), by where it is in their repository:
# run -> (folder under trained_models, algorithm): the ES runs' niche agents, <run>.*.best.json
ES_RUNS = {
    "poet_hexA8": ("poet/poet_hexA8", "epoet"),
    "poet_twin22": ("poet_sac/poet_twin22", "epoet_sac"),
}
# run -> (activation, has an observation normaliser); the files are model/model_pf_best.pth
TORCH_RUNS = {"ppo/0": ("tanh", True), "sac/42": ("relu", False), "vmpo/42": ("tanh", True)}
CRITIC_RUNS = ("sac/42",)  # their twin Q networks too (model_qf1_best.pth, model_qf2_best.pth)
GENOMES = f"{MODELS}/cppngenomes/cppngenomes_b"  # the paper suite's 32 genomes
ADMITTED = f"{MODELS}/cppngenomes/cppngenomes_admitted*"  # the validation suite's (a glob)
SOURCE = Path(__file__).with_name("SOURCE.json")  # the commit and its inputs' SHA-256
MANIFEST = "manifest.json"  # the conversion's index, written last (convert.py)


class ReferenceFileError(ValueError):
    """An authors' file that is missing, cannot be read or is not what it should be; one line."""


class MissingReferenceFiles(ReferenceFileError):
    """No copy of the authors' files where the setting points; the message says how to get one."""


def _how() -> str:
    commit = json.loads(SOURCE.read_text())["commit"]
    return (
        f"clone github.com/ml-tue/ePOET_3D at {commit[:7]} and set {ENV}=<its folder> "
        f"(or epoet_3d=<its folder>)"
    )


def configure(path: str | None) -> None:
    """Take the config value `epoet_3d` (None: leave the environment's); set in the
    environment, so worker processes and subcommands read the same files."""
    if path:
        os.environ[ENV] = str(Path(path).expanduser().resolve())


def source() -> Path:
    """The copy of ePOET_3D the setting names; MissingReferenceFiles (one line) if none."""
    given = os.environ.get(ENV)
    if given:
        folder = Path(given).expanduser()
        if not (folder / MODELS).is_dir():
            raise MissingReferenceFiles(
                f"{ENV}={given} is not a copy of the authors' ePOET_3D (it has no {MODELS}/): "
                + _how()
                + "."
            )
        return folder
    if (BESIDE / MODELS).is_dir():
        return BESIDE
    raise MissingReferenceFiles(
        f"the authors' files (ePOET_3D) are needed and not found ({ENV} is unset and "
        f"{BESIDE} does not exist): {_how()}."
    )


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def inputs(source: Path) -> list[Path]:
    """Every file of the checkout the conversion reads, in a fixed order (files.py hashes them)."""
    models = source / MODELS
    found = [
        p
        for run, (folder, _) in ES_RUNS.items()
        for p in (models / folder).glob(f"{run}.*.best.json")
    ]
    for name, (_, normalised) in TORCH_RUNS.items():
        found += [models / name / "model" / "model_pf_best.pth", models / name / "log.csv"]
        if normalised:
            found.append(models / name / "model" / "_obs_normalizer_best.pkl")
        if name in CRITIC_RUNS:
            found += [models / name / "model" / f"model_{q}_best.pth" for q in ("qf1", "qf2")]
    found += (source / GENOMES).glob("*.pickle")
    found += source.glob(f"{ADMITTED}/*.pickle")
    return sorted(p for p in found if p.is_file())


def checked_inputs(folder: Path) -> dict[str, str]:
    """Each input the converter reads, by its path under `folder`, with its SHA-256, checked
    against the committed hashes; ReferenceFileError names the first that differs."""
    expected: dict[str, str] = json.loads(SOURCE.read_text())["inputs"]
    found = {str(p.relative_to(folder)): sha256(p) for p in inputs(folder)}
    missing = sorted(set(expected) - set(found))
    if missing:
        raise ReferenceFileError(
            f"{folder} lacks {len(missing)} of the authors' files ({missing[0]}, ...): "
            + _how()
            + "."
        )
    differ = sorted(name for name in found if expected.get(name) != found[name])
    if differ:
        raise ReferenceFileError(
            f"{folder / differ[0]} is not the file of ePOET_3D at the commit the results were "
            f"made with ({len(differ)} file(s) differ): " + _how() + "."
        )
    return found


def cache_root() -> Path:
    if given := os.environ.get(CACHE_ENV):
        return Path(given).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "epoet"
