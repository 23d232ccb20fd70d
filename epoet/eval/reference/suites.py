"""The authors' CPPN genomes as evaluation suites, rendered as their environment renders an
evaluation terrain (epoet/terrain/reference_rendering.py, S = 1 m) and levelled by rank:

- `suite/` (`suite=paper`): their 32 evaluation genomes (`cppngenomes_b`), the paper's suite;
- `admitted/` (`suite=admitted`): 32 genomes their runs admitted (`cppngenomes_admitted*`), none
  of them one of the 32: the suite settings are decided on, so the paper's suite is read for
  the final table only (docs/evaluation.md, "The validation suite").

Levels: the reference bucketed the patch variance under each agent's own path, so its levels
depended on the agent; its evaluate_rl_models.py then fixed Table 1's counts at 9 easy, 14
medium and 9 hard. Here a suite's terrains are ranked by their course roughness (the same
variance along the straight course, epoet.eval.suite) and given those counts; the reference's
thresholds on that roughness are kept as `threshold_level`.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from epoet.core.files import npz_bytes
from epoet.eval.reference.files import ADMITTED, GENOMES, REPOSITORY, ReferenceFileError
from epoet.eval.reference.pickles import read_genome, to_neat
from epoet.eval.suite_format import SHIPPED, SUITE_FORMAT, Course, level_of, quantize
from epoet.terrain.cppn import render_reference
from epoet.terrain.reference_rendering import EVAL_HEIGHT

# Table 1's denominators in the reference's evaluate_rl_models.py: 9 easy, 14 medium, 9 hard
LEVEL_COUNTS = (("easy", 9), ("medium", 14), ("hard", 9))
SUITE_SIZE = sum(n for _, n in LEVEL_COUNTS)
SIZE, GRID = 40.0, 200  # metres per side and samples: the reference's terrain
ORIGIN = "rendered by epoet.terrain.reference_rendering"


def _course() -> Course:
    """The reference's course, as the shipped suite has it."""
    return Course(**json.loads((SHIPPED / "suite.json").read_text())["course"])


def _terrain(genome: dict[str, Any], seed: int, course: Course) -> tuple[np.ndarray, float]:
    """The genome rendered at S = 1 m (stored heights) and its course roughness."""
    heights = quantize(render_reference(to_neat(genome), seed, EVAL_HEIGHT))
    return heights, course.roughness(heights / 65535.0, EVAL_HEIGHT**2, SIZE)


def _suite(
    folder: str,
    entries: list[dict[str, Any]],
    heights: dict[str, np.ndarray],
    course: Course,
    origin: str,
) -> dict[str, bytes]:
    """suite.json and heights.npz, each entry given its level by its roughness's rank."""
    ranked = sorted(range(len(entries)), key=lambda k: entries[k]["roughness"])
    bounds = np.cumsum([n for _, n in LEVEL_COUNTS])
    for rank, k in enumerate(ranked):
        entries[k]["level"] = LEVEL_COUNTS[int(np.searchsorted(bounds, rank, side="right"))][0]
    index = {
        "format": SUITE_FORMAT,
        "size": SIZE,
        "grid": GRID,
        "course": vars(course),
        "origin": origin,
        "terrains": entries,
    }
    return {
        f"{folder}/heights.npz": npz_bytes(heights),
        f"{folder}/suite.json": (json.dumps(index, indent=1) + "\n").encode(),
    }


def convert_paper(source: Path, files: dict[str, bytes]) -> dict[str, str]:
    """genomes.json and the paper suite: the k-th genome (by file name: the authors' save
    times, so 4 rounds of 8) is terrain r<k // 8>c<k % 8>, its bowl drawn from seed k.
    Returns each terrain's level."""
    paths = sorted((source / GENOMES).glob("*.pickle"))
    if len(paths) != SUITE_SIZE:
        raise ReferenceFileError(
            f"{source / GENOMES} holds {len(paths)} genome pickles, not "
            f"the {SUITE_SIZE} of the paper's suite."
        )
    course = _course()
    genomes, heights = {}, {}
    entries: list[dict[str, Any]] = []
    for k, path in enumerate(paths):
        name = f"r{k // 8}c{k % 8}"
        genome = read_genome(path)
        genomes[name] = {"source": str(path.relative_to(source)), **genome}
        heights[name], rough = _terrain(genome, k, course)
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
    files["genomes.json"] = (json.dumps(genomes, indent=1) + "\n").encode()
    files |= _suite("suite", entries, heights, course, f"{REPOSITORY} {GENOMES}, {ORIGIN}")
    return {e["name"]: e["level"] for e in entries}


def genome_key(genome: dict[str, Any]) -> str:
    """A genome's identity: the SHA-256 of its parsed genes (file names do not say it)."""
    return hashlib.sha256(json.dumps(genome).encode()).hexdigest()


def convert_admitted(source: Path, files: dict[str, bytes]) -> None:
    """The validation suite, `admitted/`, by a rule fixed before any agent was evaluated on it:

    1. every genome pickle of `cppngenomes_admitted*` (in path order), parsed; a genome equal
       to an earlier one, or to one of the paper suite's 32, is dropped (compared by genes);
    2. each rendered as a paper terrain is, its bowl drawn from a seed taken from its genes'
       hash; one whose heights equal a paper terrain's is dropped too;
    3. ranked by course roughness (ties by the genes' hash), the 32 at evenly spaced ranks
       (rank floor((i + 1/2) n / 32) of the n left, i = 0..31) are kept: the admitted
       environments' range of roughness, sampled evenly;
    4. levelled by rank within the 32 as the paper suite is (9 / 14 / 9), named a00..a31 by rank.
    """
    course = _course()
    paper = {genome_key(read_genome(p)) for p in (source / GENOMES).glob("*.pickle")}
    with np.load(io.BytesIO(files["suite/heights.npz"])) as stored:  # convert_paper's
        paper_heights = {hashlib.sha256(stored[name].tobytes()).hexdigest() for name in stored}
    found: dict[str, dict[str, Any]] = {}
    for path in sorted(source.glob(f"{ADMITTED}/*.pickle")):
        genome = read_genome(path)
        key = genome_key(genome)
        if key in paper or key in found:
            continue
        seed = int(key[:8], 16)
        rendered, rough = _terrain(genome, seed, course)
        if hashlib.sha256(rendered.tobytes()).hexdigest() in paper_heights:
            continue
        found[key] = {"path": path, "heights": rendered, "roughness": rough, "seed": seed}
    if len(found) < SUITE_SIZE:
        raise ReferenceFileError(
            f"{source}/{ADMITTED} holds {len(found)} admitted genomes that are not the paper's, "
            f"fewer than the {SUITE_SIZE} of a suite."
        )
    ranked = sorted(found, key=lambda key: (found[key]["roughness"], key))
    picks = [ranked[int((i + 0.5) * len(ranked) / SUITE_SIZE)] for i in range(SUITE_SIZE)]
    entries, heights = [], {}
    for i, key in enumerate(picks):
        name, chosen = f"a{i:02d}", found[key]
        heights[name] = chosen["heights"]
        entries.append(
            {
                "name": name,
                "roughness": chosen["roughness"],
                "threshold_level": level_of(chosen["roughness"]),
                "max_height": EVAL_HEIGHT**2,
                "seed": chosen["seed"],
                "genome": str(chosen["path"].relative_to(source)),
                "genome_sha256": key,
            }
        )
    origin = f"{REPOSITORY} {ADMITTED}, {len(found)} distinct genomes, 32 by rank; {ORIGIN}"
    files |= _suite("admitted", entries, heights, course, origin)
