"""The paper's Tables 1 and 2, and statistics that can separate algorithms, from the evaluations
in the MLflow store or in evaluation records (`make tables`).


- Table 1: success rate per difficulty level (and in total) per algorithm: each run's rate over
  its suite episodes, then mean +- sample std over the algorithm's runs (seeds).
- Table 2: over the easy and medium terrains, the average +- std of the episode returns and the
  maximum return, pooling every episode of the algorithm's runs (the paper: 16 terrains x 5
  runs per agent).
- IQM: per algorithm, the interquartile mean of the success rate and of the return over its
  runs x terrains, with 95 % stratified-bootstrap intervals over runs and terrains; with one
  run, over terrains only (the tables say so).
- Probability of improvement: P(X > Y) for every pair of algorithms, with its 95 % interval.
  `analysis/stats.py` says exactly what each of these numbers is.

The tables are of one suite (`--suite`: "shipped", the default, "paper" or a suite folder; its
name is in their titles), each written as Markdown, LaTeX and CSV into a folder of their input and
suite, `<--out>/<input>/<suite name>/` (input: the experiment, the records folder's name, or
`runs-<hash>` for `--run`; so two inputs never overwrite each other), named per suite
(`table1_<suite name>.md`, ..., `iqm_<suite name>.{md,tex,csv,png}`,
`poi_<suite name>.{md,tex,csv,png}`), and printed. The numbers come from each run's
`evaluation/<suite name>/episodes.csv` artifact (a run logged before evaluations were keyed by
suite: `evaluation/episodes.csv`, when its `eval_suite` tag is the suite's fingerprint), or,
with `--records`, from the records' `<record>/<suite name>/episodes.csv` (`analysis.records`;
records without an evaluation on the suite are named and left out). The tables only read the
store: a FINISHED run without an evaluation on the suite (its `eval_suite/<suite name>` tag is
not the suite's fingerprint) is an error that names the command evaluating it
(pipeline/paper.py evaluates for `make paper`).

Examples:

    python -m analysis.tables                         # results/epoet/shipped/
    python -m analysis.tables --records docs/results/workstation --suite paper
    python -m analysis.tables --experiment reference --suite paper --out /tmp/tables
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Sequence
from pathlib import Path

import pandas as pd
from mlflow import MlflowClient
from mlflow.entities import Run

from analysis.mean_success import mean_interval
from analysis.records import (
    episodes_per_terrain,
    one_course_scale,
    one_protocol,
    record_episodes,
)
from analysis.stats_report import write_stats
from analysis.store import (
    AnalysisError,
    add_store_arguments,
    connect,
    evaluation_of,
    in_order,
    output_folder,
    require_runs,
    run_command,
    seed_of,
    select_runs,
    unevaluated,
)
from epoet.core.help import HelpParser
from epoet.eval.keys import SHIPPED_NAME
from epoet.eval.suite import LEVELS, Suite, load_suite
from epoet.tracking import StoredRun

EASY_MEDIUM = ("easy", "medium")


def require_evaluations(runs: Sequence[Run], loaded: Suite, suite: str | None) -> None:
    """Every run must have its evaluation on this suite (each training run ends with one on the
    shipped suite; `make paper` evaluates its runs); one sentence naming the runs and the
    command otherwise."""
    if missing := unevaluated(runs, loaded):
        names = ", ".join(f"{r.info.run_name} ({r.info.run_id})" for r in missing[:3])
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        suite_arg = f" suite={suite}" if suite else ""
        raise AnalysisError(
            f"{len(missing)} run(s) have no evaluation on suite {loaded.name} "
            f"({loaded.fingerprint}): {names}{more}; "
            f"evaluate each with `python -m epoet.eval.evaluate run=<run id>{suite_arg}`, e.g. "
            f"run={missing[0].info.run_id} (`make paper` evaluates the runs it trains)"
        )


def episodes_of(client: MlflowClient, runs: Sequence[Run], suite: Suite) -> pd.DataFrame:
    """Every run's episodes.csv on `suite` (each run has its evaluation on it), with its algo,
    seed and run id."""
    frames = []
    with tempfile.TemporaryDirectory(prefix="epoet-tables-") as tmp:
        for run in runs:
            folder = evaluation_of(run, suite).artifacts
            path = StoredRun(client, run).download(
                f"{folder}/episodes.csv", Path(tmp) / run.info.run_id
            )
            frame = pd.read_csv(path)
            frame.insert(0, "run_id", run.info.run_id)
            frame.insert(1, "algo", run.data.tags["algo"])
            frame.insert(2, "seed", seed_of(run))
            frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def _mean_std(values: pd.Series) -> tuple[float, float]:
    return float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else float("nan")


def table1(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per algorithm: mean and std over runs of each run's success rate per level and total."""
    rows = []
    for algo in in_order(episodes.algo):
        mine = episodes[episodes.algo == algo]
        per_run = {
            level: mine[mine.level == level].groupby("run_id").solved.mean() for level in LEVELS
        }
        per_run["total"] = mine.groupby("run_id").solved.mean()
        row = {"algo": algo, "runs": mine.run_id.nunique()}
        for column, rates in per_run.items():
            row[f"{column}_mean"], row[f"{column}_std"] = _mean_std(rates)
        rows.append(row)
    return pd.DataFrame(rows)


def table1_seeds(episodes: pd.DataFrame) -> pd.DataFrame:
    """Table 1 run by run: each seed's success rate per level and in total, then per algorithm
    the mean over seeds with its 95 % t interval (analysis.mean_success), the paper's
    statistic with the spread a reader needs to trust it."""
    rows = []
    for algo in in_order(episodes.algo):
        mine = episodes[episodes.algo == algo]
        per_run = mine.groupby(["seed", "level"]).solved.mean().unstack()
        per_run = per_run[[level for level in LEVELS if level in per_run]]
        per_run["total"] = mine.groupby("seed").solved.mean()
        for seed, rates in per_run.iterrows():
            rows.append({"algorithm": algo, "seed": str(seed), **rates.to_dict()})
        rows.append(
            {
                "algorithm": algo,
                "seed": "mean [95 % CI]",
                **{column: mean_interval(per_run[column]) for column in per_run},
            }
        )
    return pd.DataFrame(rows)


def _percent(cell: float | tuple[float, float, float]) -> str:
    """A rate, or a (mean, low, high) interval, in percent (no interval for one run)."""
    if not isinstance(cell, tuple):
        return "" if cell != cell else f"{100 * cell:.1f}"
    mean, low, high = cell
    return (
        f"{100 * mean:.1f}"
        if low != low
        else f"{100 * mean:.1f} [{100 * low:.1f}, {100 * high:.1f}]"
    )


def table2(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per algorithm, over its easy and medium episodes: mean, std and max of the return."""
    rows = []
    for algo in in_order(episodes.algo):
        mine = episodes[(episodes.algo == algo) & episodes.level.isin(EASY_MEDIUM)]
        if mine.empty:
            continue
        returns = mine["return"]
        rows.append(
            {
                "algo": algo,
                "runs": mine.run_id.nunique(),
                "episodes": len(mine),
                "return_mean": float(returns.mean()),
                "return_std": float(returns.std(ddof=1)) if len(mine) > 1 else float("nan"),
                "return_max": float(returns.max()),
            }
        )
    return pd.DataFrame(rows)


def _pm(mean: float, std: float, scale: float, digits: int) -> str:
    text = f"{mean * scale:.{digits}f}"
    return text if std != std else f"{text} ± {std * scale:.{digits}f}"  # std NaN: one run


def formatted(t1: pd.DataFrame, t2: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The tables as shown: success rates in percent, mean ± std; a level the suite has no
    terrain of (the paper suite's extreme) is left out rather than shown as NaN."""
    columns = [c for c in (*LEVELS, "total") if t1[f"{c}_mean"].notna().any()]
    shown1 = pd.DataFrame(
        {
            "algorithm": t1.algo,
            "runs": t1.runs,
            **{
                column: [
                    _pm(m, s, 100, 1) for m, s in zip(t1[f"{column}_mean"], t1[f"{column}_std"])
                ]
                for column in columns
            },
        }
    )
    shown2 = pd.DataFrame(
        {
            "algorithm": t2.algo,
            "runs": t2.runs,
            "episodes": t2.episodes,
            "average return": [_pm(m, s, 1, 1) for m, s in zip(t2.return_mean, t2.return_std)],
            "maximum return": [f"{v:.1f}" for v in t2.return_max],
        }
    )
    return shown1, shown2


def to_markdown(frame: pd.DataFrame) -> str:
    """A pipe table (pandas' own needs the tabulate package)."""
    cells = [list(map(str, frame.columns))] + [list(map(str, row)) for row in frame.values]
    widths = [max(len(row[k]) for row in cells) for k in range(len(frame.columns))]
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |" for row in cells]
    lines.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(lines)


def course_scale(runs: Sequence[Run], suite: Suite) -> str:
    """The one course scale the runs were evaluated at on `suite` (a budget's episodes set it:
    "solved" on a fifth of the course is not "solved" on all of it, so scales are never
    mixed)."""
    return one_course_scale({r.info.run_id: evaluation_of(r, suite).course_scale for r in runs})


def write_tables(
    episodes: pd.DataFrame, out: Path, scale: str = "1", suite: str = SHIPPED_NAME
) -> list[Path]:
    """Tables 1 and 2 of the episodes on the suite named `suite`, as out/table<k>_<suite>.*;
    runs evaluated with different episodes per terrain are refused (`one_protocol`)."""
    one_protocol(episodes_per_terrain(episodes))
    out.mkdir(parents=True, exist_ok=True)
    t1, t2 = table1(episodes), table2(episodes)
    shown1, shown2 = formatted(t1, t2)
    written = []
    at = f" on suite {suite} (course scale {scale})"
    titles = {
        "table1": f"Table 1: success rate (%) by difficulty, mean ± std over runs{at}",
        "table2": f"Table 2: return over the easy and medium terrains{at}",
    }
    for name, raw, shown in (("table1", t1, shown1), ("table2", t2, shown2)):
        stem = f"{name}_{suite}"
        raw.to_csv(out / f"{stem}.csv", index=False)
        markdown = to_markdown(shown)
        (out / f"{stem}.md").write_text(f"{titles[name]}\n\n{markdown}\n")
        (out / f"{stem}.tex").write_text(
            shown.to_latex(index=False, caption=titles[name], label=f"tab:{stem}")
        )
        print(f"\n{titles[name]}\n{markdown}")
        written += [out / f"{stem}.{ext}" for ext in ("csv", "md", "tex")]
    seeds = table1_seeds(episodes)
    stem = f"table1_seeds_{suite}"
    seeds.map(lambda c: c[0] if isinstance(c, tuple) else c).to_csv(
        out / f"{stem}.csv", index=False
    )
    (out / f"{stem}.md").write_text(
        f"Table 1 by seed: success rate (%) by difficulty, each run and the mean over seeds with "
        f"its 95 % t interval{at}\n\n"
        f"{to_markdown(seeds.map(lambda c: c if isinstance(c, str) else _percent(c)))}\n"
    )
    written += [out / f"{stem}.{ext}" for ext in ("csv", "md")]
    written += write_stats(episodes, out, suite, scale, to_markdown)
    print(f"\nwrote {', '.join(str(p) for p in written)}")
    return written


def make_tables(
    experiment: str,
    out: Path,
    suite: str | None = None,
    run_ids: Sequence[str] = (),
    tracking_uri: str | None = None,
) -> list[Path]:
    client, uri = connect(tracking_uri)
    runs = require_runs(select_runs(client, uri, experiment, run_ids), experiment, uri)
    loaded = load_suite(suite)
    require_evaluations(runs, loaded, suite)
    return write_tables(
        episodes_of(client, runs, loaded), out, course_scale(runs, loaded), loaded.name
    )


def tables_from_records(records: Path, out: Path, suite: str | None = None) -> list[Path]:
    """The same tables from evaluation records (`analysis.records`), without a store."""
    loaded = load_suite(suite)
    episodes, scale, left_out = record_episodes(records, loaded)
    if left_out:
        print(
            f"left out {len(left_out)} record(s) without an evaluation on suite "
            f"{loaded.name}: {', '.join(left_out)}"
        )
    return write_tables(episodes, out, scale, loaded.name)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = HelpParser("python -m analysis.tables", __doc__)
    add_store_arguments(parser, Path("results"))
    parser.add_argument(
        "--records",
        type=Path,
        default=None,
        metavar="FOLDER",
        help="table the evaluation records in FOLDER (python -m "
        "pipeline.records writes them) instead of the store",
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry; bad input gives one sentence on stderr and exit code 2."""
    args = parse_args(argv)

    def tables() -> list[Path]:
        out = output_folder(args.out, args.suite, args.experiment, args.run, args.records)
        if args.records is not None:
            return tables_from_records(args.records, out, args.suite)
        return make_tables(args.experiment, out, args.suite, args.run)

    return run_command(tables)


if __name__ == "__main__":
    raise SystemExit(main())
