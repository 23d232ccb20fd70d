"""Algorithms compared at each CPU-time mark of their records, the way the paper's claims are
read: the paired difference of mean success with its interval over seeds, and the probability
of improvement with the ceiling its ties allow (analysis.mean_success says what each is)."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import pandas as pd

from analysis.mean_success import difference_interval, ties_ceiling
from analysis.stats import poi_interval
from analysis.store import in_order
from epoet.registry import algorithms


def comparisons(
    table: pd.DataFrame, pairs: Sequence[tuple[str, str]] | None = None
) -> pd.DataFrame:
    """For each pair (X, Y) of `pairs` (None: every pair of algorithms, X after Y in table
    order; `claims()`: the paper's) at every mark both reached, each run read by its exported agent: the difference of
    mean success X - Y on the same terrains with its 95 % interval over seeds, and P(X > Y),
    rliable's probability of improvement, with its interval and its ties ceiling."""
    rows = []
    for minutes, at in table[table.reading == "best"].groupby("minutes"):
        matrices = {
            algo: np.stack([t.to_numpy() for t in runs.terrains])
            for algo, runs in at.groupby("algo")
        }
        every = [(x, y) for y, x in itertools.combinations(in_order(matrices), 2)]
        for x, y in every if pairs is None else pairs:
            if x not in matrices or y not in matrices:
                continue
            diff, diff_low, diff_high = difference_interval(matrices[x], matrices[y])
            point, low, high = poi_interval(matrices[x], matrices[y])
            rows.append(
                {
                    "minutes": minutes,
                    "x": x,
                    "y": y,
                    "runs": f"{len(matrices[x])} / {len(matrices[y])}",
                    "X - Y (mean success, pts)": f"{100 * diff:+.1f} "
                    f"[{100 * diff_low:+.1f}, {100 * diff_high:+.1f}]",
                    "P(X > Y)": f"{point:.2f} [{low:.2f}, {high:.2f}]",
                    "P ceiling (ties)": f"{ties_ceiling(matrices[x], matrices[y]):.2f}",
                }
            )
    return pd.DataFrame(rows)


def claims() -> list[tuple[str, str]]:
    """The paper's claims as (X, Y), X claimed to beat Y (each record's `beats`), in the
    paper's order: the open-ended algorithms' first (reverse table order)."""
    return [(r.name, r.beats) for r in reversed(algorithms()) if r.beats is not None]
