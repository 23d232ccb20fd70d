"""The statistics of analysis/stats.py as files: per suite the IQM and probability-of-improvement
tables (CSV of every number, Markdown and LaTeX as shown, with what the numbers are) and their
figures, each interval drawn as a bar (`write_stats`, called by `analysis.tables`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; never need a display

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from analysis.stats import LABELS, METRICS, REPS, SEED, iqm_table, poi_table  # noqa: E402
from analysis.store import in_order  # noqa: E402
from epoet.registry import algorithm  # noqa: E402


def _interval(value: float, low: float, high: float, scale: float, digits: int) -> str:
    return f"{value * scale:.{digits}f} [{low * scale:.{digits}f}, {high * scale:.{digits}f}]"


def shown_iqm(table: pd.DataFrame) -> pd.DataFrame:
    """One row per algorithm: runs, success IQM (%) and return IQM, each with its interval."""
    rows = []
    for algo in in_order(table.algo):
        mine = table[table.algo == algo].set_index("score")
        row = {"algorithm": algo, "runs": int(mine.runs.iloc[0])}
        for score, scale, digits in (("success", 100, 1), ("return", 1, 1)):
            r = mine.loc[score]
            row[f"{LABELS[score]} IQM [95 % CI]"] = _interval(
                r.iqm, r.ci_low, r.ci_high, scale, digits
            )
        row["interval over"] = mine.resampled.iloc[0]
        rows.append(row)
    return pd.DataFrame(rows)


def shown_poi(table: pd.DataFrame) -> pd.DataFrame:
    """One row per pair: P(X > Y) of the success rate and of the return, with intervals."""
    rows = []
    for (x, y), pair in table.groupby(["x", "y"], sort=False):
        pair = pair.set_index("score")
        row = {"X": x, "Y": y, "runs": f"{pair.runs_x.iloc[0]} vs {pair.runs_y.iloc[0]}"}
        for score in METRICS:
            r = pair.loc[score]
            row[f"P(X > Y), {score} [95 % CI]"] = _interval(r.poi, r.ci_low, r.ci_high, 1, 2)
        row["interval over"] = pair.resampled.iloc[0]
        rows.append(row)
    return pd.DataFrame(rows)


def notes(iqm_rows: pd.DataFrame, reps: int, seed: int) -> list[str]:
    """What the numbers are, and where one run leaves the intervals to the terrains alone."""
    terrains = int(iqm_rows.terrains.max()) if len(iqm_rows) else 0
    lines = [
        f"IQM: interquartile mean over runs x {terrains} terrains (each entry a run's mean "
        f"over its episodes on one terrain); 95 % CI: percentile stratified bootstrap over "
        f"runs (within each terrain) and terrains, {reps} resamples, seeded by {seed} and "
        f"each interval's own scores "
        f"(rliable, Agarwal et al. 2021; analysis/stats.py)."
    ]
    single = in_order(iqm_rows[iqm_rows.runs == 1].algo)
    if single:
        lines.append(
            f"One run only ({', '.join(single)}): its intervals come from the terrains "
            f"only (how the score varies over this suite's terrains), not from seeds."
        )
    return lines


def _plot(
    table: pd.DataFrame,
    labels: list[str],
    value: str,
    colours: list[str],
    ax,
    scale: float,
    reference: float | None = None,
) -> None:
    y = np.arange(len(labels))[::-1]
    values = table[value].to_numpy() * scale
    low, high = table.ci_low.to_numpy() * scale, table.ci_high.to_numpy() * scale
    ax.errorbar(
        values,
        y,
        xerr=[values - low, high - values],
        fmt="none",
        ecolor=colours,
        elinewidth=6,
        alpha=0.5,
    )
    ax.scatter(values, y, color=colours, zorder=3, marker="|", s=200, linewidths=2)
    if reference is not None:
        ax.axvline(reference, color="grey", linestyle="--", linewidth=1)
    ax.set_yticks(y, labels)
    ax.grid(axis="x", alpha=0.3)


def plot_iqm(table: pd.DataFrame, title: str, path: Path) -> Path:
    """Per score, each algorithm's IQM with its 95 % interval as a bar."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 0.6 * table.algo.nunique() + 1.6))
    for ax, score in zip(axes, METRICS):
        rows = table[table.score == score]
        algos = list(rows.algo)
        _plot(
            rows,
            [f"{algorithm(a).label} ({r})" for a, r in zip(algos, rows.runs)],
            "iqm",
            [algorithm(a).colour for a in algos],
            ax,
            100 if score == "success" else 1,
        )
        ax.set_xlabel(f"IQM of the {LABELS[score]}")
    fig.suptitle(title, fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_poi(table: pd.DataFrame, title: str, path: Path) -> Path:
    """Per score, P(X > Y) of each pair with its 95 % interval; 0.5 marked."""
    pairs = table[["x", "y"]].drop_duplicates()
    fig, axes = plt.subplots(1, 2, figsize=(10, 0.5 * len(pairs) + 1.6))
    for ax, score in zip(axes, METRICS):
        rows = table[table.score == score]
        _plot(
            rows,
            [f"{algorithm(x).label} > {algorithm(y).label}" for x, y in zip(rows.x, rows.y)],
            "poi",
            [algorithm(x).colour for x in rows.x],
            ax,
            1,
            reference=0.5,
        )
        ax.set_xlim(-0.02, 1.02)
        ax.set_xlabel(f"P(X > Y), {LABELS[score].removesuffix(' (%)')}")
    fig.suptitle(title, fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def latex_text(text: str) -> str:
    """Plain text (no backslashes, tildes or carets) for a LaTeX caption."""
    for char in "&%$#_{}":
        text = text.replace(char, f"\\{char}")
    return text


def write_stats(
    episodes: pd.DataFrame,
    out: Path,
    suite: str,
    scale: str,
    to_markdown: Callable[[pd.DataFrame], str],
    reps: int = REPS,
    seed: int = SEED,
) -> list[Path]:
    """out/iqm_<suite>.{csv,md,tex,png} and out/poi_<suite>.{csv,md,tex,png} (no PoI files for
    one algorithm); prints the Markdown."""
    out.mkdir(parents=True, exist_ok=True)
    at = f" on suite {suite} (course scale {scale})"
    iqm_rows = iqm_table(episodes, reps, seed)
    said = notes(iqm_rows, reps, seed)
    outputs = [
        (
            "iqm",
            iqm_rows,
            shown_iqm(iqm_rows),
            f"IQM of the success rate and of the return, 95 % CI{at}",
            plot_iqm,
        )
    ]
    if iqm_rows.algo.nunique() > 1:
        poi_rows = poi_table(episodes, reps, seed)
        outputs.append(
            (
                "poi",
                poi_rows,
                shown_poi(poi_rows),
                f"Probability of improvement P(X > Y), 95 % CI{at}",
                plot_poi,
            )
        )
    written = []
    for name, raw, shown, title, plot in outputs:
        stem = out / f"{name}_{suite}"
        raw.to_csv(stem.with_suffix(".csv"), index=False)
        markdown = to_markdown(shown)
        text = "\n".join(said)
        stem.with_suffix(".md").write_text(f"{title}\n\n{markdown}\n\n{text}\n")
        latex = shown.to_latex(
            index=False,
            escape=True,
            caption=latex_text(f"{title}. {text}"),
            label=f"tab:{name}_{suite}",
        )
        stem.with_suffix(".tex").write_text(latex.replace(" > ", " $>$ "))
        plot(raw, title, stem.with_suffix(".png"))
        print(f"\n{title}\n{markdown}")
        written += [stem.with_suffix(ext) for ext in (".csv", ".md", ".tex", ".png")]
    print("\n" + "\n".join(said))
    return written
