"""Per level, and where the failed episodes stop: what separates algorithms on a suite's terrains.

The paper suite's terrains carry the reference renderer's step where its CPPN window ends,
6.7 m past the spawn (docs/fidelity.md, `terrain.rendering`); an agent that never met it while
training stops there. For each algorithm, CPU-time mark and seed, from the exported agent's
episodes: the success per level, and on the medium terrains the share of all episodes that end
at the step (not finished, forward distance within `AT_STEP` metres), that share among the
failed episodes, and the mean forward distance of the failed ones.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from analysis.records import EPISODES, read_csv, read_records
from epoet.eval.suite import LEVELS

# Forward distances counted as stopping at the step, which lies 6.7 m past the spawn (where the
# reference's CPPN window ends).
AT_STEP = (5.5, 7.5)


def level_table(records: Path, suite: str) -> pd.DataFrame:
    """One row per algorithm, mark and seed with its exported agent's success per level and
    its medium episodes' stopping points."""
    rows = []
    for info in read_records(records):
        for minutes, snap in info.get("snapshots", {}).items():
            if suite not in snap["evaluations"]:
                continue
            path = Path(records) / info["record"] / f"cpu{minutes}" / snap["best_agent"] / suite
            episodes = read_csv(
                path / EPISODES, ["level", "finished", "solved", "forward_distance"]
            )
            medium = episodes[episodes.level == "medium"]
            failed = medium[~medium.solved]
            at_step = ~medium.finished & medium.forward_distance.between(*AT_STEP)
            rows.append(
                {
                    "algo": info["algo"],
                    "minutes": float(minutes),
                    "seed": info["seed"],
                    **{
                        level: float(episodes[episodes.level == level].solved.mean())
                        for level in LEVELS
                        if (episodes.level == level).any()
                    },
                    "medium at step": float(at_step.mean()),
                    "failed medium at step": float(at_step[~medium.solved].mean())
                    if len(failed)
                    else float("nan"),
                    "failed medium distance (m)": float(failed.forward_distance.mean())
                    if len(failed)
                    else float("nan"),
                }
            )
    return pd.DataFrame(rows)


def level_summary(table: pd.DataFrame) -> pd.DataFrame:
    """The mean over seeds of `level_table`'s columns, per algorithm and mark."""
    numbers = table.drop(columns=["seed"])
    means = numbers.groupby(["algo", "minutes"], sort=False).mean().reset_index()
    runs = table.groupby(["algo", "minutes"], sort=False).size().to_numpy()
    return means.assign(runs=runs)
