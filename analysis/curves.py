"""Learning curves in the style of the paper's Figure 2, read from the MLflow store.

Writes to `--out`:
- `epoet_curves.png` / `.csv`: each run of the pool family's (ePOET, ePOET-SAC: an algorithm's
  record says its family, epoet/registry.py) mean ES training return per iteration, one curve
  per environment-agent pair (metric `pair<N>/return_mean`, step = iteration), one panel per run.
  The paper labels pairs "ePOET_gen<generation>"; the generation is not logged per pair, so
  curves are labelled `pair<N>`.
- `baseline_curves.png` / `.csv`: each baseline run's (PPO, SAC, VMPO) evaluation return
  (`score`, which equals `eval/return_mean`; step = frames), one panel per algorithm.

By default the runs are the FINISHED runs of the experiment that carry an `algo` tag (a sweep's
parent run has none and is skipped); `--run` picks runs by id instead, whatever their status.
The CSV files hold exactly the plotted points, so the figures can be redrawn or tabulated
elsewhere. The store is epoet's (`sqlite:///<project root>/mlflow.db`); MLFLOW_TRACKING_URI
overrides it.

Examples:

    python -m analysis.curves
    python -m analysis.curves --experiment paper-laptop --out figures/laptop
    python -m analysis.curves --run <run id> <run id>
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; never need a display

import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402
from mlflow import MlflowClient  # noqa: E402
from mlflow.entities import Run  # noqa: E402

from analysis.store import (  # noqa: E402
    AnalysisError,
    connect,
    default_experiment,
    history,
    in_order,
    run_command,
    select_runs,
)
from analysis.store import seed_of as _seed  # noqa: E402
from epoet.core.algorithm import Family  # noqa: E402
from epoet.core.help import HelpParser  # noqa: E402
from epoet.registry import algorithm, algorithms, names  # noqa: E402

PAIR_KEY = re.compile(r"^pair(\d+)/return_mean$")
EVAL_KEY = Family.BASELINE.curve  # "score": a baseline's evaluation return
EPOET_COLUMNS = ["run_id", "algo", "seed", "pair", "iteration", "return_mean"]
BASELINE_COLUMNS = ["run_id", "algo", "seed", "frames", "return_mean"]


def epoet_table(client: MlflowClient, runs: Sequence[Run]) -> pd.DataFrame:
    """Rows of EPOET_COLUMNS for every pair of every ePOET run, pairs in index order."""
    rows = []
    for run in runs:
        pairs = sorted(int(m.group(1)) for key in run.data.metrics if (m := PAIR_KEY.match(key)))
        for pair in pairs:
            for step, value in history(client, run.info.run_id, f"pair{pair}/return_mean"):
                rows.append((run.info.run_id, run.data.tags["algo"], _seed(run), pair, step, value))
    return pd.DataFrame(rows, columns=EPOET_COLUMNS)


def baseline_table(client: MlflowClient, runs: Sequence[Run]) -> pd.DataFrame:
    """Rows of BASELINE_COLUMNS: each baseline run's evaluation return against frames."""
    rows = []
    for run in runs:
        for step, value in history(client, run.info.run_id, EVAL_KEY):
            rows.append((run.info.run_id, run.data.tags["algo"], _seed(run), step, value))
    return pd.DataFrame(rows, columns=BASELINE_COLUMNS)


def _grid(n: int, ncols: int = 3) -> tuple[plt.Figure, list[plt.Axes]]:
    cols = min(n, ncols)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.5 * cols, 3.4 * rows), squeeze=False)
    flat = list(axes.flat)
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def plot_epoet(table: pd.DataFrame, runs: Sequence[Run], path: Path) -> None:
    """One panel per run (title: name, seed, budget), one curve per environment-agent pair."""
    order = [r for r in runs if r.info.run_id in set(table.run_id)]
    fig, axes = _grid(len(order))
    for ax, run in zip(axes, order):
        rows = table[table.run_id == run.info.run_id]
        for pair, curve in rows.groupby("pair", sort=True):
            ax.plot(curve.iteration, curve.return_mean, label=f"pair{pair}", linewidth=1.2)
        ax.set_title(
            f"{run.info.run_name} (seed {_seed(run) or '?'}, {run.data.tags.get('budget', '?')})",
            fontsize=10,
        )
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel("mean training return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="x-small", ncol=1 + rows.pair.nunique() // 12)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_baselines(table: pd.DataFrame, path: Path) -> None:
    """One panel per algorithm, one curve per run (labelled by seed), coloured by algorithm."""
    algos = in_order(table.algo, Family.BASELINE)
    fig, axes = _grid(len(algos))
    for ax, algo in zip(axes, algos):
        rows = table[table.algo == algo]
        for run_id, curve in rows.groupby("run_id", sort=False):
            ax.plot(
                curve.frames,
                curve.return_mean,
                color=algorithm(algo).colour,
                alpha=0.8,
                marker="." if len(curve) < 20 else None,
                label=f"seed {curve.seed.iloc[0]} ({run_id[:8]})",
            )
        ax.set_title(algorithm(algo).label, fontsize=10)
        ax.set_xlabel("frames")
        ax.set_ylabel("evaluation return")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _labels(family: Family) -> str:
    """The family's algorithms as figures name them, e.g. PPO/SAC/VMPO."""
    return "/".join(r.label for r in algorithms(family))


def write_curves(client: MlflowClient, runs: Sequence[Run], out: Path, source: str) -> list[Path]:
    """Write both figures and their CSV files; skip (and say so) a figure without runs.

    Raises AnalysisError when neither figure has anything to plot.
    """
    epoet_runs = [r for r in runs if r.data.tags.get("algo") in names(Family.OPEN_ENDED)]
    baseline_runs = [r for r in runs if r.data.tags.get("algo") in names(Family.BASELINE)]
    tables = {
        "epoet_curves": (
            epoet_table(client, epoet_runs),
            epoet_runs,
            _labels(Family.OPEN_ENDED),
            "pair<N>/return_mean",
        ),
        "baseline_curves": (
            baseline_table(client, baseline_runs),
            baseline_runs,
            _labels(Family.BASELINE),
            EVAL_KEY,
        ),
    }
    if all(table.empty for table, *_ in tables.values()):
        raise AnalysisError(
            f"{source} has no {_labels(Family.OPEN_ENDED)} runs with pair<N>/return_mean and no "
            f"{_labels(Family.BASELINE)} runs with {EVAL_KEY} to plot."
        )
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, (table, selected, label, key) in tables.items():
        if table.empty:
            print(f"skipped {out / name}.png: {source} has no {label} runs with {key}")
            continue
        for run in selected:
            if run.info.run_id not in set(table.run_id):
                print(f"left out run {run.info.run_id} ({run.info.run_name}): no {key} metric")
        csv, png = out / f"{name}.csv", out / f"{name}.png"
        table.to_csv(csv, index=False)
        if name == "epoet_curves":
            plot_epoet(table, selected, png)
        else:
            plot_baselines(table, png)
        print(f"wrote {png} and {csv} ({table.run_id.nunique()} runs, {len(table)} points)")
        written += [png, csv]
    return written


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = HelpParser("python -m analysis.curves", __doc__)
    parser.add_argument(
        "--experiment",
        default=default_experiment(),
        help="MLflow experiment whose FINISHED runs are plotted (the runs' default, "
        "tracking.experiment)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("figures"),
        help="folder for the PNG and CSV files",
    )
    parser.add_argument(
        "--run",
        nargs="+",
        default=[],
        metavar="RUN_ID",
        help="plot these runs (any status, any experiment) instead",
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry; bad input gives one sentence on stderr and exit code 2."""
    args = parse_args(argv)

    def curves() -> None:
        client, uri = connect()
        runs = select_runs(client, uri, args.experiment, args.run)
        source = (
            f"the selected runs in {uri}"
            if args.run
            else f"experiment {args.experiment!r} in {uri}"
        )
        write_curves(client, runs, args.out, source)

    return run_command(curves)


if __name__ == "__main__":
    raise SystemExit(main())
