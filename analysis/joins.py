"""What ePOET-SAC's joins did to the pool, per run, from its record alone (pipeline.snapshots's
curves.csv and the latest snapshot's agent files; analysis.success_vs_compute writes it as
joins.md).

A join makes the SAC actor a new pair: an ES agent mapped from the actor, on a copy of the
environment the actor trained on (its parent), which then crosses over with every other active
agent (Algorithm 3). Per run: each join's iteration, the actor's score and its mapped agent's on
that terrain, the crossover replacements, the transfers out of joined pairs, the niches the
joined pairs founded (the reproduction descendants of a joined environment) and whether the
run's best agent is of a join's lineage, by its score on its own environment (the agent
`evaluate run=<folder>` picks) and by its success on the suite.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from analysis.records import RUN_FILE, read_csv, read_records, record_file
from epoet.rollout.agent_files import ES_POLICIES

# The curves a join leaves (the ePOET-SAC loop's metrics), which pipeline.snapshots keeps.
JOIN_KEYS = (
    "joined",
    "join/env",
    "join/sac_score",
    "join/mapped_score",
    "replaced",
    "transfers/from_joined",
)


def parents(policies: Path) -> dict[int, int | None]:
    """Each agent file's environment and its parent environment (None: the root)."""
    out: dict[int, int | None] = {}
    for path in policies.glob("env*.npz"):
        with record_file(path), np.load(path, allow_pickle=False) as data:
            parent = int(data["parent"])
        out[int(path.stem[3:])] = None if parent < 0 else parent
    return out


def descendants(roots: set[int], parent_of: dict[int, int | None]) -> set[int]:
    """The environments with an ancestor in `roots` (not the roots themselves)."""
    found = set()
    for env in parent_of:
        ancestor = parent_of[env]
        while ancestor is not None:
            if ancestor in roots:
                found.add(env)
                break
            ancestor = parent_of.get(ancestor)
    return found - roots


def _column(curves: pd.DataFrame, key: str) -> pd.Series:
    return curves[key].dropna() if key in curves else pd.Series(dtype=float)


def run_joins(folder: Path, info: dict[str, Any], suite: str) -> dict[str, Any]:
    """One run's joins (see the module's docstring) at its latest snapshot."""
    curves = read_csv(folder / "curves.csv", index_col="step")
    envs = _column(curves, "join/env").astype(int)
    joins = [
        f"it {step}: {curves.at[step, 'join/sac_score']:.0f} -> "
        f"{curves.at[step, 'join/mapped_score']:.0f} (env{env})"
        for step, env in envs.items()
    ]
    minutes, snap = list(info["snapshots"].items())[-1]
    parent_of = parents(folder / f"cpu{minutes}" / ES_POLICIES)
    joined = set(envs) & set(parent_of)
    lineage = joined | descendants(joined, parent_of)
    agents = snap["evaluations"].get(suite, {}).get("agents", {})
    niches = {name: rate for name, rate in agents.items() if name.startswith("env")}
    best_on_suite = max(niches, key=lambda name: niches[name]) if niches else None
    own = snap.get("own_agent", snap["best_agent"])  # the exported `agent` is a niche's copy

    def of_lineage(agent: str | None) -> str:
        if agent is None:
            return "-"
        return f"{agent} ({'yes' if int(agent[3:]) in lineage else 'no'})"

    return {
        "seed": info["seed"],
        "CPU minutes": minutes,
        "joins: actor -> mapped": "; ".join(joins) or "none",
        "crossover replaced": int(_column(curves, "replaced").sum()),
        "transfers out of joined": int(_column(curves, "transfers/from_joined").sum()),
        "niches founded": len(lineage - joined),
        "pairs": len(parent_of),
        "best by own score (a join's?)": of_lineage(own),
        f"best on {suite} (a join's?)": of_lineage(best_on_suite),
    }


def joins_table(records: Path, suite: str, algo: str = "epoet_sac") -> pd.DataFrame:
    """One row per `algo` record with a snapshot (empty when there is none)."""
    rows = []
    for info in read_records(records):
        if info["algo"] == algo and info.get("snapshots"):
            folder = Path(records) / info["record"]
            with record_file(folder / RUN_FILE):  # its snapshots' entries
                rows.append(run_joins(folder, info, suite))
    return pd.DataFrame(rows)
