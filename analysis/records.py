"""Evaluation records: a run's evaluations as small files that outlive its MLflow store, and the
episodes table that `analysis.tables --records` builds from them (no store needed).

`python -m pipeline.records` writes them (docs/results/README.md has the format):

    <records>/<record>/run.json                   the run: algo, seed, budget, command, commit,
                                                  wall time, load, and its evaluations by suite
    <records>/<record>/<suite name>/summary.json  the evaluation's summary (epoet.eval.evaluate)
    <records>/<record>/<suite name>/episodes.csv  one row per episode (epoet.eval.evaluate)

A record's `run.json` lists the suites it holds (`evaluations`, each with the suite's
fingerprint and the course scale): only those are read, so a folder left over from an earlier
export of another run is never mixed in.
"""

from __future__ import annotations

import contextlib
import json
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pandas as pd

from analysis.store import AnalysisError
from epoet.core.errors import first_line
from epoet.eval.suite import Suite

FORMAT = "epoet-record/1"
RUN_FILE = "run.json"
SUMMARY = "summary.json"
EPISODES = "episodes.csv"
REQUIRED = ("run_id", "algo", "seed")  # what every table reads of a record's run.json
EPISODE_COLUMNS = ["terrain", "level", "return", "solved"]  # what the tables read of episodes.csv


def trained_record(algo: str, seed: int | str) -> str:
    """The record folder's name of a run trained here: `<algo>_s<seed>`."""
    return f"{algo}_s{seed}"


@contextlib.contextmanager
def record_file(path: Path) -> Iterator[None]:
    """Reading a record's file: a damaged or missing one (a run.json cut short, a CSV without
    its columns) is one sentence naming the file and what is wrong, not a parser's traceback."""
    try:
        yield
    except AnalysisError:
        raise
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile, EOFError) as exc:
        raise AnalysisError(
            f"record file {path} is damaged or incomplete ({type(exc).__name__}: "
            f"{first_line(exc).rstrip('.')}): export the record again."
        ) from exc


def read_json(path: Path) -> dict[str, Any]:
    """A record's JSON file, which must hold an object."""
    with record_file(path):
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"it holds a {type(data).__name__}, not an object")
        return data


def read_csv(path: Path, columns: list[str] | None = None, **kwargs: Any) -> pd.DataFrame:
    """A record's CSV file, which must have `columns` (None: any)."""
    with record_file(path):
        frame = pd.read_csv(path, **kwargs)
        if missing := [c for c in columns or [] if c not in frame.columns]:
            raise ValueError(f"no column {', '.join(missing)}")
        return frame


def read_records(folder: Path) -> list[dict[str, Any]]:
    """Every record's run.json under `folder` (each with its `record` folder name), oldest run
    first; AnalysisError when there is none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise AnalysisError(
            f"there is no records folder {folder}: export one with "
            f"`python -m pipeline.records --experiment <experiment> "
            f"--out {folder}`."
        )
    records = []
    for path in sorted(folder.glob(f"*/{RUN_FILE}")):
        info = read_json(path)
        if info.get("format") != FORMAT:
            raise AnalysisError(
                f"{path} is not an epoet record (format {info.get('format')!r}, expected {FORMAT})."
            )
        if missing := [key for key in REQUIRED if key not in info]:
            raise AnalysisError(
                f"record file {path} is incomplete: it has no {', '.join(missing)}."
            )
        records.append({**info, "record": path.parent.name})
    if not records:
        raise AnalysisError(
            f"{folder} holds no records (<record>/{RUN_FILE}): export them "
            f"with `python -m pipeline.records --experiment <experiment> "
            f"--out {folder}`."
        )
    return sorted(records, key=lambda r: (r.get("started") or "", r["record"]))


def one_course_scale(scales: dict[str, str]) -> str:
    """The one course scale of the evaluations ({label: scale}); AnalysisError when they differ
    ("solved" on a fifth of the course is not "solved" on all of it, so scales never mix)."""
    found = set(scales.values())
    if len(found) > 1:
        raise AnalysisError(
            f"the runs were evaluated at different course scales "
            f"({', '.join(sorted(found))}): table one budget's runs at a time "
            f"(one experiment per budget, or --run)."
        )
    return found.pop()


def episodes_per_terrain(episodes: pd.DataFrame) -> dict[str, int]:
    """Each run's episodes per terrain in an episodes table (columns run_id, algo, seed,
    terrain), keyed by a label a reader finds the run by: `<algo> s<seed> (<run id>)`."""
    counts = episodes.groupby(["run_id", "terrain"]).size().groupby(level=0).max()
    runs = episodes.drop_duplicates("run_id").set_index("run_id")
    return {
        f"{runs.at[run, 'algo']} s{runs.at[run, 'seed']} ({run})": int(n)
        for run, n in counts.items()
    }


def one_protocol(counts: dict[str, int]) -> int:
    """The one number of episodes per terrain of the evaluations ({label: episodes per
    terrain}); AnalysisError naming the runs of each number when they differ: a success rate
    over 1 or 3 episodes per terrain (a small budget's end-of-run evaluation) is not one over
    the paper's 5, so a table or figure never sets them side by side."""
    found = sorted(set(counts.values()))
    if len(found) > 1:
        groups = [[label for label, k in counts.items() if k == n] for n in found]
        listed = "; ".join(
            f"{n}: {', '.join(labels[:3])}{f' and {len(labels) - 3} more' if len(labels) > 3 else ''}"
            for n, labels in zip(found, groups)
        )
        raise AnalysisError(
            f"the runs were evaluated with different episodes per terrain ({listed}): evaluate "
            f"them again with one number (python -m epoet.eval.evaluate run=<run> "
            f"suite=<suite> episodes={found[-1]}) or table them apart (--run)."
        )
    return found[0]


def record_episodes(folder: Path, suite: Suite) -> tuple[pd.DataFrame, str, list[str]]:
    """The episodes on `suite` of every record under `folder` that holds an evaluation on it
    (columns run_id, algo, seed, then episodes.csv's), the course scale, and the records left
    out for having none. AnalysisError if no record has one, or one has an evaluation under
    the suite's name on other terrains (another fingerprint)."""
    frames, scales, left_out = [], {}, []
    for info in read_records(folder):
        with record_file(Path(folder) / info["record"] / RUN_FILE):  # its evaluations' entries
            evaluation = info.get("evaluations", {}).get(suite.name)
            if evaluation is None:
                left_out.append(info["record"])
                continue
            if evaluation["fingerprint"] != suite.fingerprint:
                raise AnalysisError(
                    f"record {info['record']} was evaluated on other terrains under the name "
                    f"{suite.name} (fingerprint {evaluation['fingerprint']}, this suite "
                    f"{suite.fingerprint}): its numbers are not this suite's."
                )
            frame = read_csv(Path(folder) / info["record"] / suite.name / EPISODES, EPISODE_COLUMNS)
            frame.insert(0, "run_id", info["run_id"])
            frame.insert(1, "algo", info["algo"])
            frame.insert(2, "seed", str(info["seed"]))
            frames.append(frame)
            scales[info["record"]] = str(evaluation["course_scale"])
    if not frames:
        raise AnalysisError(
            f"no record in {folder} has an evaluation on suite {suite.name} "
            f"({suite.fingerprint}): evaluate the runs on it and export the "
            f"records again (`make paper` does both)."
        )
    return pd.concat(frames, ignore_index=True), one_course_scale(scales), left_out
