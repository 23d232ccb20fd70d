"""The paper's figures from the MLflow store (`make figures`).

Writes into a folder of its input and suite, `<--out>/<input>/<suite name>/` (input: the
experiment, or `runs-<hash>` for `--run`; the tables of the same input go there too), each
figure with the CSV of exactly its plotted points:
- `learning_curves.png`: every algorithm's `score` (ePOET: the best active pair's evaluation
  score; baselines: the evaluation return), mean +- std over seeds, against environment steps
  and against training time (Figure 2a). Seeds are put on a common grid by linear
  interpolation, within the range every seed covers.
- `generations.png`: ePOET's and ePOET-SAC's `gen<g>/score` per iteration, mean over seeds
  (Figure 2b).
- `annecs.png`: ANNECS and the active / archived environments per iteration (ePOET family).
- `tsne.png`: t-SNE of the sampled actions on three suite terrains (the first easy, medium and
  hard one), one panel per algorithm (Figure 5); needs the runs' evaluations on that suite
  (`evaluation/<suite name>/` artifacts; each training run ends with one on the shipped suite;
  `make paper` evaluates its runs).
- `suite_gallery.png`: the evaluation suite by level, as 3D surfaces (Figure 3).
- `admitted_<run>.png`: the terrains a ePOET-family run admitted, in admission order (Figure 4).

Examples:

    python -m analysis.figures                         # results/epoet/shipped/
    python -m analysis.figures --suite paper
    python -m analysis.figures --experiment reference --suite paper --out /tmp/figures
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; never need a display

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from mlflow import MlflowClient  # noqa: E402
from mlflow.entities import Run  # noqa: E402

from analysis.store import (  # noqa: E402
    add_store_arguments,
    connect,
    evaluation_of,
    evaluation_on,
    history,
    in_order,
    output_folder,
    require_runs,
    run_command,
    seed_of,
    select_runs,
)
from epoet.core.algorithm import ELAPSED, ENV_STEPS, SCORE, Family  # noqa: E402
from epoet.core.help import HelpParser  # noqa: E402
from epoet.eval.keys import suite_argument  # noqa: E402
from epoet.eval.suite import LEVELS, Suite, load_suite  # noqa: E402
from epoet.registry import algorithm, names  # noqa: E402
from epoet.terrain import Terrain, plot_terrain  # noqa: E402
from epoet.tracking import StoredRun  # noqa: E402

GEN_KEY = re.compile(r"^gen(\d+)/score$")
GRID_POINTS = 100
TSNE_LEVELS = ("easy", "medium", "hard")


def save(fig: plt.Figure, table: pd.DataFrame, stem: Path) -> list[Path]:
    """The figure as <stem>.png and exactly its points as <stem>.csv."""
    fig.tight_layout()
    fig.savefig(stem.with_suffix(".png"), dpi=120)
    plt.close(fig)
    table.to_csv(stem.with_suffix(".csv"), index=False)
    return [stem.with_suffix(".png"), stem.with_suffix(".csv")]


def curve_table(client: MlflowClient, runs: Sequence[Run]) -> pd.DataFrame:
    """run_id, algo, seed, step, env_steps, elapsed, score: each logged score point with the
    axes logged at the same step."""
    rows = []
    for run in runs:
        rid = run.info.run_id
        steps = dict(history(client, rid, ENV_STEPS))
        elapsed = dict(history(client, rid, ELAPSED))
        for step, score in history(client, rid, SCORE):
            if step in steps and step in elapsed:
                rows.append(
                    (
                        rid,
                        run.data.tags["algo"],
                        seed_of(run),
                        step,
                        steps[step],
                        elapsed[step],
                        score,
                    )
                )
    return pd.DataFrame(rows, columns=["run_id", "algo", "seed", "step", ENV_STEPS, ELAPSED, SCORE])


def mean_std_on_grid(curves: pd.DataFrame, x: str) -> pd.DataFrame:
    """Per algorithm: the seeds' scores interpolated on a common x grid; mean, std, seeds."""
    out = []
    for algo, rows in curves.groupby("algo", sort=False):
        runs = [g.sort_values(x) for _, g in rows.groupby("run_id")]
        lo, hi = max(g[x].min() for g in runs), min(g[x].max() for g in runs)
        if hi <= lo:
            grid = np.array([hi])
        else:
            grid = np.linspace(lo, hi, GRID_POINTS)
        values = np.array([np.interp(grid, g[x], g.score) for g in runs])
        out.append(
            pd.DataFrame(
                {
                    "algo": algo,
                    x: grid,
                    "mean": values.mean(0),
                    "std": values.std(0, ddof=1) if len(runs) > 1 else 0.0,
                    "seeds": len(runs),
                }
            )
        )
    return pd.concat(out, ignore_index=True)


def plot_learning_curves(
    curves: pd.DataFrame, out: Path, time_axis: tuple[str, str] = (ELAPSED, "training time (s)")
) -> list[Path]:
    """Score against environment steps and against `time_axis` (curves' column, label)."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    tables = []
    for ax, x, label in ((axes[0], ENV_STEPS, "environment steps"), (axes[1], *time_axis)):
        table = mean_std_on_grid(curves, x)
        tables.append(table.assign(axis=x).rename(columns={x: "x"}))
        for algo in in_order(table.algo):
            t = table[table.algo == algo]
            record = algorithm(algo)
            colour = record.colour
            ax.plot(
                t[x], t["mean"], color=colour, label=f"{record.label} ({t.seeds.iloc[0]} seeds)"
            )
            ax.fill_between(
                t[x],
                t["mean"] - t["std"],
                t["mean"] + t["std"],
                color=colour,
                alpha=0.2,
                linewidth=0,
            )
        ax.set_xlabel(label)
        ax.set_ylabel("score")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle("Learning curves: mean ± std over seeds")
    return save(fig, pd.concat(tables, ignore_index=True), out / "learning_curves")


def generation_table(client: MlflowClient, runs: Sequence[Run]) -> pd.DataFrame:
    rows = []
    for run in runs:
        for key in run.data.metrics:
            if match := GEN_KEY.match(key):
                for step, value in history(client, run.info.run_id, key):
                    rows.append(
                        (
                            run.info.run_id,
                            run.data.tags["algo"],
                            seed_of(run),
                            int(match.group(1)),
                            step,
                            value,
                        )
                    )
    return pd.DataFrame(
        rows, columns=["run_id", "algo", "seed", "generation", "iteration", "score"]
    )


def plot_generations(table: pd.DataFrame, out: Path) -> list[Path]:
    algos = in_order(table.algo, Family.OPEN_ENDED)
    fig, axes = plt.subplots(1, len(algos), figsize=(6 * len(algos), 4.2), squeeze=False)
    for ax, algo in zip(axes[0], algos):
        rows = table[table.algo == algo]
        for gen, g in rows.groupby("generation"):
            mean = g.groupby("iteration").score.mean()
            ax.plot(mean.index, mean.values, label=f"{algorithm(algo).label}_gen{gen}")
        ax.set_title(f"{algorithm(algo).label} ({rows.run_id.nunique()} runs, mean over seeds)")
        ax.set_xlabel("iteration")
        ax.set_ylabel("score")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="x-small")
    return save(fig, table, out / "generations")


def environments_table(client: MlflowClient, runs: Sequence[Run]) -> pd.DataFrame:
    rows = []
    for run in runs:
        series = {
            key: dict(history(client, run.info.run_id, key))
            for key in ("annecs", "active_envs", "archived_envs")
        }
        for step in sorted(series["annecs"]):
            rows.append(
                (
                    run.info.run_id,
                    run.data.tags["algo"],
                    seed_of(run),
                    step,
                    *(series[k].get(step, np.nan) for k in series),
                )
            )
    return pd.DataFrame(
        rows,
        columns=["run_id", "algo", "seed", "iteration", "annecs", "active_envs", "archived_envs"],
    )


def plot_environments(table: pd.DataFrame, out: Path) -> list[Path]:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for ax, key in zip(axes, ("annecs", "active_envs", "archived_envs")):
        for run_id, rows in table.groupby("run_id", sort=False):
            algo = rows.algo.iloc[0]
            ax.step(
                rows.iteration,
                rows[key],
                where="post",
                color=algorithm(algo).colour,
                alpha=0.8,
                label=f"{algorithm(algo).label} s{rows.seed.iloc[0]}",
            )
        ax.set_title(key.replace("_", " "))
        ax.set_xlabel("iteration")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="x-small")
    return save(fig, table, out / "annecs")


def tsne_table(
    client: MlflowClient, runs: Sequence[Run], terrains: Sequence[str], suite: Suite, seed: int = 0
) -> pd.DataFrame:
    """2-D t-SNE of each algorithm's sampled actions on `terrains` (its first run evaluated on
    `suite`)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="epoet-tsne-") as tmp:
        for algo in in_order(r.data.tags["algo"] for r in runs):
            run = next(
                (
                    r
                    for r in runs
                    if r.data.tags["algo"] == algo and evaluation_on(r, suite) is not None
                ),
                None,
            )
            if run is None:
                print(
                    f"t-SNE: no {algo} run has an evaluation on suite {suite.name} (python -m "
                    f"epoet.eval.evaluate run=<run id> "
                    f"suite={suite_argument(suite.name, suite.folder)} makes one)"
                )
                continue
            stored = StoredRun(client, run)
            folder = Path(tmp) / run.info.run_id
            logged = evaluation_of(run, suite).artifacts
            episodes = pd.read_csv(stored.download(f"{logged}/episodes.csv", folder))
            with np.load(stored.download(f"{logged}/actions.npz", folder)) as data:
                row, action = data["row"], data["action"]
            mask = np.isin(episodes.terrain.to_numpy()[row], terrains)
            if mask.sum() < 5:
                continue
            # sklearn is imported here, not with the module: it takes about as long to import
            # as the rest of the analysis, and every command importing the figures paid it
            from sklearn.manifold import TSNE
            from threadpoolctl import threadpool_limits

            # One OpenMP thread: on a few hundred actions sklearn's threads cost more CPU than
            # they save, and on a busy machine they spin, many times the fit's CPU; the
            # embedding is the same to the bit.
            with threadpool_limits(1):
                points = TSNE(
                    2, perplexity=min(30.0, (mask.sum() - 1) / 3), random_state=seed, init="pca"
                ).fit_transform(action[mask])
            for (x, y), r in zip(points, row[mask]):
                rows.append((algo, run.info.run_id, episodes.terrain[r], x, y))
    return pd.DataFrame(rows, columns=["algo", "run_id", "terrain", "x", "y"])


def plot_tsne(table: pd.DataFrame, terrains: Sequence[str], out: Path) -> list[Path]:
    algos = in_order(table.algo)
    fig, axes = plt.subplots(1, len(algos), figsize=(4 * len(algos), 4), squeeze=False)
    for ax, algo in zip(axes[0], algos):
        rows = table[table.algo == algo]
        for terrain, colour in zip(terrains, ("tab:green", "tab:orange", "tab:red")):
            t = rows[rows.terrain == terrain]
            ax.scatter(t.x, t.y, s=6, color=colour, label=terrain, alpha=0.7)
        ax.set_title(algorithm(algo).label)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0][0].legend(fontsize="x-small", markerscale=2)
    fig.suptitle("t-SNE of actions on three terrains")
    return save(fig, table, out / "tsne")


def _gallery(terrains: Sequence, path: Path, columns: int) -> Path:
    rows = -(-len(terrains) // columns)
    fig = Figure(figsize=(3.4 * columns, 3.2 * rows), dpi=90)
    zmax = max(t.max_height for t in terrains)
    for k, terrain in enumerate(terrains):
        plot_terrain(
            fig.add_subplot(rows, columns, k + 1, projection="3d"),
            terrain,
            zmax=zmax,
            max_facets=60,
        )
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.03, top=0.95, wspace=0.05, hspace=0.2)
    fig.savefig(path)
    return path


def suite_gallery(suite: Suite, out: Path) -> list[Path]:
    ordered = [t for level in LEVELS for t in suite.terrains if t.level == level]
    return [_gallery(ordered, out / "suite_gallery.png", columns=8)]


def admitted_galleries(client: MlflowClient, runs: Sequence[Run], out: Path) -> list[Path]:
    """Each ePOET-family run's environments (root first, then in admission order)."""
    written = []
    with tempfile.TemporaryDirectory(prefix="epoet-terrains-") as tmp:
        for run in runs:
            stored = StoredRun(client, run)
            if not stored.has_artifact("terrains"):
                continue
            folder = stored.download("terrains", Path(tmp) / run.info.run_id)
            files = sorted(folder.glob("env*.npz"), key=lambda p: int(p.stem[3:]))
            terrains = [Terrain.load(p) for p in files]
            path = out / f"admitted_{run.info.run_name}_{run.info.run_id[:8]}.png"
            written.append(_gallery(terrains, path, columns=min(4, len(terrains))))
    return written


def write_figures(
    experiment: str,
    out: Path,
    suite: str | None = None,
    run_ids: Sequence[str] = (),
    tracking_uri: str | None = None,
) -> list[Path]:
    client, uri = connect(tracking_uri)
    runs = require_runs(select_runs(client, uri, experiment, run_ids), experiment, uri)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    curves = curve_table(client, runs)
    if curves.empty:
        print("skipped learning_curves.png: no run logged score with env_steps and elapsed")
    else:
        written += plot_learning_curves(curves, out)
    open_ended = [r for r in runs if r.data.tags["algo"] in names(Family.OPEN_ENDED)]
    if open_ended:  # runs without a training history (the authors' agents) have no curves to draw
        generations, environments = (
            generation_table(client, open_ended),
            environments_table(client, open_ended),
        )
        written += plot_generations(generations, out) if not generations.empty else []
        written += plot_environments(environments, out) if not environments.empty else []
        written += admitted_galleries(client, open_ended, out)
    loaded = load_suite(suite)
    picks = [
        next(t.name for t in loaded.terrains if t.level == level)
        for level in TSNE_LEVELS
        if any(t.level == level for t in loaded.terrains)
    ]
    tsne = tsne_table(client, runs, picks, loaded)
    if not tsne.empty:
        written += plot_tsne(tsne, picks, out)
    written += suite_gallery(loaded, out)
    for path in written:
        print(f"wrote {path}")
    return written


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m analysis.figures", __doc__)
    add_store_arguments(parser, Path("results"))
    args = parser.parse_args(argv)
    return run_command(
        lambda: write_figures(
            args.experiment,
            output_folder(args.out, args.suite, args.experiment, args.run),
            args.suite,
            args.run,
        )
    )


if __name__ == "__main__":
    raise SystemExit(main())
