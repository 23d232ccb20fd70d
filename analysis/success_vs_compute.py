"""`python -m analysis.success_vs_compute --records docs/results/<name> [--suite paper]`: success
against compute, and the learning curves, from records alone (pipeline.snapshots writes them).

For each algorithm and CPU-time mark (the runs' `snapshot_cpu_minutes`), first the paper's
statistic: the mean success over the suite's terrains of each run's agent at that mark, each
seed's value and the mean over seeds with its 95 % t interval (analysis.mean_success: the suite
is fixed, the seeds are the draw). Then, secondary, the IQM over runs and terrains with its
stratified-bootstrap interval (analysis.stats), which trims away the easy and hard terrains of
a near-binary score. Readings of an ePOET pool: the run's exported agent (`selection`: chosen
on held-out terrains, or by the run's own rule), the niche with the best score on its own
terrain where the record holds that choice apart, and the mean over its niche agents. The
authors' agents are the horizontal references, in the same statistic: the mean success of each
algorithm's published agents in the reference records (docs/results/reference).

Writes to `<out>/<records folder name>/<suite name>/` (`--out` default: results/compute):
success_vs_compute.{md,csv,png}, learning_curves.{png,csv} (score against environment steps and
against CPU hours), levels.md (per level, and where the failed medium episodes stop:
analysis.levels), comparisons.md where they hold two algorithms or more (the paired difference of mean success X - Y with its interval over seeds, and P(X > Y) with its
ties ceiling, at every mark both reached), claims.md (the paper's claims, each record's `beats`, whose two
algorithms they hold) and, where they hold ePOET-SAC runs, joins.md (what their joins did to
the pool: analysis.joins).

Examples:

    python -m analysis.success_vs_compute --records docs/results/compute
    python -m analysis.success_vs_compute --records docs/results/compute --suite shipped \
        --out /tmp/fig
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; never need a display

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from analysis.comparisons import claims, comparisons  # noqa: E402
from analysis.figures import plot_learning_curves  # noqa: E402
from analysis.joins import joins_table  # noqa: E402
from analysis.levels import AT_STEP, level_summary, level_table  # noqa: E402
from analysis.mean_success import (  # noqa: E402
    mean_interval,
)
from analysis.records import (  # noqa: E402
    EPISODES,
    RUN_FILE,
    one_protocol,
    read_csv,
    read_json,
    read_records,
    record_file,
)
from analysis.stats import iqm_interval  # noqa: E402
from analysis.store import (  # noqa: E402
    AnalysisError,
    in_order,
    output_folder,
    run_command,
)
from analysis.tables import to_markdown  # noqa: E402
from epoet.core.algorithm import CPU_TIME, ENV_STEPS, SCORE, Family  # noqa: E402
from epoet.core.help import HelpParser  # noqa: E402
from epoet.eval.keys import PAPER_NAME  # noqa: E402
from epoet.registry import algorithm  # noqa: E402

REFERENCE = Path(__file__).resolve().parent.parent / "docs" / "results" / "reference"
READINGS = {
    "best": "the run's exported agent",
    "own": "the niche agent with the best score on its own terrain",
    "niches": "mean over its niche agents",
}


def success_matrix(
    record: Path, snapshot: str, agents: Sequence[str], suite: str
) -> tuple[pd.Series, int]:
    """Per terrain (suite order), the success of the agents' episodes at the snapshot, averaged
    over the agents; and the episodes per terrain of their evaluations, which must agree."""
    frames = {
        agent: read_csv(record / snapshot / agent / suite / EPISODES, ["terrain", "solved"])
        for agent in agents
    }
    per_terrain = one_protocol(
        {
            f"{record.name} {snapshot} {agent}": int(frame.groupby("terrain").size().max())
            for agent, frame in frames.items()
        }
    )
    episodes = pd.concat(frames.values(), ignore_index=True)
    return episodes.groupby("terrain", sort=False).solved.mean().astype(float), per_terrain


def compute_table(records: Path, suite: str) -> pd.DataFrame:
    """One row per run, mark and reading: algo, seed, minutes, cpu_hours (the snapshot's own
    CPU time), reading, success (the run's success rate), per-terrain successes and the
    episodes per terrain, one number for every row (`one_protocol`)."""
    rows = []
    for info in read_records(records):
        folder = Path(records) / info["record"]
        with record_file(folder / RUN_FILE):  # its snapshots' entries
            for minutes, snap in info.get("snapshots", {}).items():
                evaluation = snap["evaluations"].get(suite)
                if evaluation is None:
                    continue
                evaluated = evaluation["agents"]
                niches = sorted(a for a in evaluated if a.startswith("env"))
                pool = algorithm(info["algo"]).family is Family.OPEN_ENDED
                # a reading only where its agents were evaluated (`--exported-only`: the best)
                readings = {
                    "best": [snap["best_agent"]],
                    **({"own": [snap["own_agent"]]} if snap.get("own_agent") in evaluated else {}),
                    **({"niches": niches} if niches else {}),
                    **({} if pool else {"niches": [snap["best_agent"]]}),  # a baseline's one policy
                }
                for reading, agents in readings.items():
                    terrains, per_terrain = success_matrix(folder, f"cpu{minutes}", agents, suite)
                    rows.append(
                        {
                            "algo": info["algo"],
                            "seed": info["seed"],
                            "minutes": float(minutes),
                            "cpu_hours": snap["cpu_time"] / 3600,
                            "reading": reading,
                            "success": float(terrains.mean()),
                            "terrains": terrains,
                            "episodes": per_terrain,
                        }
                    )
    if not rows:
        raise AnalysisError(
            f"no record in {records} has a CPU-time snapshot evaluated on suite {suite}: "
            f"run python -m pipeline.snapshots --runs <run folders> --out {records}."
        )
    one_protocol({f"{r['algo']} s{r['seed']} at {r['minutes']:g} min": r["episodes"] for r in rows})
    return pd.DataFrame(rows)


def summary(table: pd.DataFrame) -> pd.DataFrame:
    """Per algorithm, mark and reading: runs, the seeds' mean successes, mean CPU hours, the
    mean over seeds with its t interval, then the IQM with its interval (ePOET's niche reading
    only where the pool held more than one agent)."""
    out = []
    for (algo, minutes, reading), rows in table.groupby(["algo", "minutes", "reading"]):
        if reading == "niches" and algorithm(algo).family is not Family.OPEN_ENDED:
            continue
        rows = rows.sort_values("seed")
        matrix = np.stack([t.to_numpy() for t in rows.terrains])
        mean, low, high = mean_interval(rows.success)
        point, iqm_low, iqm_high = iqm_interval(matrix)
        out.append(
            {
                "algo": algo,
                "minutes": minutes,
                "reading": reading,
                "runs": len(rows),
                "cpu_hours": rows.cpu_hours.mean(),
                "seeds": " ".join(f"s{s}:{v:.1%}" for s, v in zip(rows.seed, rows.success)),
                "mean": mean,
                "ci_low": low,
                "ci_high": high,
                "iqm": point,
                "iqm_low": iqm_low,
                "iqm_high": iqm_high,
            }
        )
    frame = pd.DataFrame(out)
    order = {a: i for i, a in enumerate(in_order(frame.algo))}
    return frame.sort_values(
        ["algo", "reading", "minutes"], key=lambda c: c.map(order) if c.name == "algo" else c
    )


def reference_lines(suite: str, episodes: int, folder: Path = REFERENCE) -> dict[str, float]:
    """Mean success of each algorithm's published agents on the suite (their records), from
    evaluations of the runs' protocol only (`episodes` per terrain)."""
    rates: dict[str, list[float]] = {}
    for path in sorted(folder.glob("*/run.json")):
        info = read_json(path)
        evaluation = info.get("evaluations", {}).get(suite)
        if evaluation is not None and evaluation.get("episodes_per_terrain") == episodes:
            rates.setdefault(info["algo"], []).append(evaluation["success_rate"])
    return {algo: float(np.mean(v)) for algo, v in rates.items() if np.mean(v) > 0}


def plot(frame: pd.DataFrame, references: dict[str, float], suite: str, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    algos = in_order(frame.algo)
    for algo in algos:
        color, name = algorithm(algo).colour, algorithm(algo).label
        for reading, style in (("best", "-o"), ("niches", ":s")):
            rows = frame[(frame.algo == algo) & (frame.reading == reading)]
            if rows.empty:
                continue
            label = name if reading == "best" else f"{name} ({READINGS[reading]})"
            low, high = rows.ci_low.fillna(rows["mean"]), rows.ci_high.fillna(rows["mean"])
            ax.errorbar(
                rows.cpu_hours,
                100 * rows["mean"],
                yerr=[100 * (rows["mean"] - low), 100 * (high - rows["mean"])],
                fmt=style,
                color=color,
                capsize=3,
                label=label,
            )
        if algo in references:
            ax.axhline(100 * references[algo], color=color, ls="--", lw=1)
    ax.set_xlim(0, max(1.0, 1.1 * frame.cpu_hours.max()))
    ax.set_xlabel("CPU hours of training (one core)")
    for algo, value in references.items():
        if algo not in algos:
            continue
        ax.annotate(
            f"authors' {algorithm(algo).label} {value:.1%}",
            (ax.get_xlim()[1], 100 * value),
            fontsize=7,
            ha="right",
            va="bottom",
        )
    ax.set_ylabel(f"success on suite {suite} (%): mean over seeds, 95 % t interval")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def curves_from_records(records: Path) -> pd.DataFrame:
    """The records' learning curves in analysis.figures' layout, with the CPU time the runs are
    compared on."""
    frames = []
    for info in read_records(records):
        path = Path(records) / info["record"] / "curves.csv"
        if not path.is_file():
            continue
        columns = ["step", SCORE, ENV_STEPS, CPU_TIME]
        curves = read_csv(path, columns).dropna(subset=columns[1:])
        frames.append(
            pd.DataFrame(
                {
                    "run_id": info["run_id"],
                    "algo": info["algo"],
                    "seed": info["seed"],
                    "step": curves.step,
                    ENV_STEPS: curves[ENV_STEPS],
                    CPU_TIME: curves[CPU_TIME],
                    SCORE: curves[SCORE],
                }
            )
        )
    if not frames:
        raise AnalysisError(f"no record in {records} holds learning curves (curves.csv).")
    return pd.concat(frames, ignore_index=True)


def interval(point: float, low: float, high: float) -> str:
    """A percentage with its interval (none where there is no interval: one run)."""
    if np.isnan(low):
        return f"{100 * point:.1f}"
    return f"{100 * point:.1f} [{100 * low:.1f}, {100 * high:.1f}]"


def write(records: Path, suite: str, out: Path) -> list[Path]:
    table = compute_table(records, suite)  # a bad records folder writes nothing
    frame = summary(table)
    curves = curves_from_records(records)
    references = reference_lines(suite, int(table.episodes.iloc[0]))  # one number (compute_table)
    out.mkdir(parents=True, exist_ok=True)
    frame.to_csv(out / "success_vs_compute.csv", index=False)
    shown = frame.assign(
        mean=[interval(r.mean, r.ci_low, r.ci_high) for r in frame.itertuples()],
        iqm=[interval(r.iqm, r.iqm_low, r.iqm_high) for r in frame.itertuples()],
        cpu_hours=frame.cpu_hours.round(2),
        reading=frame.reading.map(READINGS),
    ).drop(columns=["ci_low", "ci_high", "iqm_low", "iqm_high"])
    notes = [
        f"- authors' {a}: {v:.1%} (mean over their published agents)" for a, v in references.items()
    ]
    (out / "success_vs_compute.md").write_text(
        f"Success on suite {suite} against CPU hours: mean success over its terrains, each "
        f"seed's and the mean over seeds with its 95 % t interval (the paper's statistic); "
        f"secondary, the IQM over runs x terrains with its 95 % stratified-bootstrap "
        f"interval\n\n{to_markdown(shown)}\n\n" + "\n".join(notes) + "\n"
    )
    paths = [out / "success_vs_compute.csv", out / "success_vs_compute.md"]
    readings = (
        (
            "comparisons.md",
            comparisons(table),
            f"Algorithms compared on suite {suite} at each CPU-time mark (the runs' exported "
            f"agents): X - Y in mean success with its 95 % interval over seeds; P(X > Y) with "
            f"its interval and the largest value its ties allow",
        ),
        (
            "claims.md",
            comparisons(table, claims()),
            f"The paper's claims on suite {suite} (X better than Y: ePOET-SAC than ePOET, ePOET "
            f"than SAC, SAC than PPO) at each CPU-time mark, read as comparisons.md reads "
            f"them: a claim holds where the interval of X - Y lies above 0",
        ),
    )
    for name, compared, title in readings:
        if not compared.empty:
            (out / name).write_text(f"{title}\n\n{to_markdown(compared)}\n")
            paths.append(out / name)
    levels = level_summary(level_table(records, suite))
    (out / "levels.md").write_text(
        f"Per level on suite {suite}, the runs' exported agents, mean over seeds: success per "
        f"level; on the medium terrains, the share of episodes that end at the reference "
        f"renderer's step ({AT_STEP[0]:g}-{AT_STEP[1]:g} m past the spawn, not finished), "
        f"that share among the failed episodes, and their mean forward distance\n\n"
        f"{to_markdown(levels.round(3))}\n"
    )
    paths.append(out / "levels.md")
    joins = joins_table(records, suite)
    if not joins.empty:
        (out / "joins.md").write_text(
            f"What ePOET-SAC's joins did (analysis.joins), suite {suite}\n\n{to_markdown(joins)}\n"
        )
        paths.append(out / "joins.md")
    paths.append(plot(frame, references, suite, out / "success_vs_compute.png"))
    paths += plot_learning_curves(curves, out, (CPU_TIME, "CPU time of training (s)"))
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m analysis.success_vs_compute", __doc__)
    parser.add_argument(
        "--records", type=Path, required=True, help="records folder (pipeline.snapshots's)"
    )
    parser.add_argument(
        "--suite", default=PAPER_NAME, help="suite whose evaluations are read (name or folder)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results") / "compute",
        help="output folder; the figures go to <out>/<records folder name>/<suite name>/",
    )
    args = parser.parse_args(argv)

    def report() -> None:
        out = output_folder(args.out, args.suite, "", records=args.records)
        for path in write(args.records, out.name, out):  # evaluations are keyed by suite name
            print(path, flush=True)

    return run_command(report)


if __name__ == "__main__":
    raise SystemExit(main())
