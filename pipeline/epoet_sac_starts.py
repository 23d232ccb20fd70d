"""`make epoet-sac-starts [SAC_RUN=<run folder | MLflow run id>] [SEEDS=1,2,3]`: ePOET-SAC at
the workstation budget from each of its three starts (docs/algorithms/epoet-sac.md), every seed,
evaluated on both suites, tabled, and exported as evaluation records.

The starts (`algo.sac_init`): `cold` (null), `ours` (a SAC run of ours: `--sac-run`, else the
SAC baseline trained here first, `algo=sac budget=workstation seed=1` into
`multirun/epoet-sac-starts/sac_s1`) and `authors` (reference:sac/42).

1. without `--sac-run`, trains the SAC run (`resume=auto`: a finished one is skipped);
2. per start, one multirun of the seeds into the MLflow experiment `epoet-sac-starts-<start>`,
   job folders `multirun/epoet-sac-starts/<start>/epoet_sac_s<seed>`, `resume=auto` (calling
   the command again continues where it stopped);
3. evaluates every run on each of `--suites` (default shipped,paper; pipeline.paper's
   `evaluate_missing`), writes each start's tables per suite to
   `results/epoet-sac-starts/<start>/` and exports its runs' evaluation records to
   `<records>/<start>/` (default docs/results/epoet-sac-starts);
4. writes `starts.md` there: per start and seed, what the joins did (the joined SAC actor's
   score, its mapped ES agent's score, crossover replacements, transfers out of joined pairs),
   children admitted, ANNECS, the best score, wall minutes and iterations, and the success
   rate and mean return on each suite.

Overrides after the options go to every ePOET-SAC job and to the SAC run trained for `ours`
(e.g. `budget.hours=0.25 workers.num=1`).

Examples:

    python -m pipeline.epoet_sac_starts --seeds 1
    python -m pipeline.epoet_sac_starts --sac-run multirun/epoet-sac-starts/sac_s1 --jobs 2
    python -m pipeline.epoet_sac_starts --seeds 1,2 budget.hours=0.1 workers.num=1
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from analysis.store import connect, history, run_command, seed_of, select_runs
from analysis.tables import make_tables
from epoet.core.help import HelpParser
from epoet.eval.agents import resolve_run
from epoet.eval.keys import PAPER_NAME, SHIPPED_NAME, suite_metric
from pipeline.paper import check_jobs, check_suites, evaluate_missing
from pipeline.paper import train_command as paper_train_command
from pipeline.records import export

NAME = "epoet-sac-starts"
SAC_RUN = Path("multirun") / NAME / "sac_s1"
REFERENCE = "reference:sac/42"


def starts(sac_run: str) -> dict[str, str]:
    """Each start's name and its `algo.sac_init`."""
    return {"cold": "null", "ours": sac_run, "authors": REFERENCE}


def sac_command(overrides: Sequence[str]) -> list[str]:
    """The SAC baseline that the `ours` start loads (evaluated like any run of ours), on the
    ePOET-SAC jobs' overrides, so it trains on the same terms (e.g. the same `budget.hours`)."""
    return [
        sys.executable,
        "-m",
        "epoet",
        "algo=sac",
        "budget=workstation",
        "seed=1",
        f"tracking.experiment={NAME}-sac",
        "resume=auto",
        f"hydra.run.dir={SAC_RUN}",
        *overrides,
    ]


def train_command(
    start: str, sac_init: str, seeds: str, jobs: int, overrides: Sequence[str]
) -> list[str]:
    """One start's multirun over the seeds (`make paper`'s training command for ePOET-SAC at the
    workstation budget with the start's `algo.sac_init`); `overrides` last, so they win."""
    return paper_train_command(
        "workstation",
        seeds,
        ["epoet_sac"],
        f"{NAME}-{start}",
        Path("multirun") / NAME / start,
        jobs,
        [f"algo.sac_init={sac_init}", *overrides],
    )


def _total(client, run_id: str, key: str) -> float:
    return sum(v for _, v in history(client, run_id, key))


def _listed(client, run_id: str, key: str) -> str:
    points = history(client, run_id, key)
    return ", ".join(f"{v:.0f} (it {s})" for s, v in points) or "-"


def summary_table(suites: Sequence[str], sac_run: str) -> str:
    """starts.md: one row per start and seed."""
    client, uri = connect()
    head = [
        "start",
        "seed",
        "minutes",
        "iterations",
        "joined actor (it)",
        "mapped agent (it)",
        "crossover replaced",
        "transfers out of joined",
        "admitted",
        "ANNECS",
        "best score",
        *[f"{s}: success, return" for s in suites],
    ]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for start in ("cold", "ours", "authors"):
        experiment = f"{NAME}-{start}"
        runs = (
            select_runs(client, uri, experiment, algos=("epoet_sac",))
            if client.get_experiment_by_name(experiment)
            else []
        )
        if not runs:
            rows.append(
                "| " + " | ".join([start, "-", "not run yet", *["-"] * (len(head) - 3)]) + " |"
            )
        for run in sorted(runs, key=lambda r: int(seed_of(r) or 0)):
            rid, metrics = run.info.run_id, run.data.metrics
            steps = history(client, rid, "score")
            cells = [
                start,
                seed_of(run),
                f"{metrics.get('elapsed', 0.0) / 60:.1f}",
                str(steps[-1][0] + 1 if steps else 0),
                _listed(client, rid, "join/sac_score"),
                _listed(client, rid, "join/mapped_score"),
                f"{_total(client, rid, 'replaced'):.0f}",
                f"{_total(client, rid, 'transfers/from_joined'):.0f}",
                f"{_total(client, rid, 'admitted'):.0f}",
                f"{metrics.get('annecs', 0.0):.0f}",
                f"{metrics.get('best_score', 0.0):.0f}",
            ]
            for suite in suites:
                rate = suite_metric(metrics, suite, "success_rate")
                ret = suite_metric(metrics, suite, "return_mean")
                cells.append("-" if rate is None else f"{rate:.2f}, {ret:.0f}")
            rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows) + "\n" + sac_note(sac_run)


def sac_note(sac_run: str) -> str:
    """The SAC run the `ours` start loaded: its name, id, minutes and frames."""
    stored = resolve_run(sac_run).stored
    if stored is None:
        return f"\nThe SAC run of ours (`ours`): {sac_run}.\n"
    metrics = stored.metrics
    return (
        f"\nThe SAC run of ours (`ours`): {stored.name} ({stored.run_id}, {sac_run}), "
        f"{metrics.get('elapsed', 0.0) / 60:.0f} minutes, "
        f"{metrics.get('frames', 0.0) / 1e3:.0f}k frames.\n"
    )


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = HelpParser("python -m pipeline.epoet_sac_starts", __doc__)
    parser.add_argument(
        "--sac-run",
        default=None,
        help="the SAC run the `ours` start loads (run folder or MLflow run id; "
        f"None: train one into {SAC_RUN})",
    )
    parser.add_argument("--seeds", default="1,2,3", help="comma-separated seeds of each start")
    parser.add_argument("--jobs", type=int, default=1, help="training jobs at a time")
    parser.add_argument(
        "--suites",
        default=f"{SHIPPED_NAME},{PAPER_NAME}",
        help="comma-separated suites every run is evaluated and tabled on",
    )
    parser.add_argument(
        "--episodes", type=int, default=None, help="evaluation episodes per terrain (None: 5)"
    )
    parser.add_argument(
        "--out", type=Path, default=Path("results") / NAME, help="tables: OUT/<start>/"
    )
    parser.add_argument(
        "--records",
        type=Path,
        default=Path("docs") / "results" / NAME,
        help="evaluation records and starts.md: RECORDS/<start>/",
    )
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for every ePOET-SAC job")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    sac_run = args.sac_run
    check_suites([s for s in args.suites.split(",") if s])
    # every job before any training (without --sac-run, `ours` is checked as the cold start)
    check_jobs(
        [["algo=sac", "budget=workstation", *args.overrides]]
        + [
            ["algo=epoet_sac", "budget=workstation", f"algo.sac_init={init}", *args.overrides]
            for init in starts(sac_run or "null").values()
        ]
    )
    if sac_run is None:
        sac = sac_command(args.overrides)
        print(f"[{NAME}] the SAC run of ours: {' '.join(sac[1:])}", flush=True)
        if (code := subprocess.run(sac).returncode) != 0:
            return code
        sac_run = str(SAC_RUN.resolve())
    suites = [s for s in args.suites.split(",") if s]
    for start, sac_init in starts(sac_run).items():
        command = train_command(start, sac_init, args.seeds, args.jobs, args.overrides)
        print(f"[{NAME}] {start}: {' '.join(command[1:])}", flush=True)
        if (code := subprocess.run(command).returncode) != 0:
            print(
                f"error: the {start} runs stopped with exit code {code}; run the same command "
                f"again to continue where they stopped.",
                file=sys.stderr,
            )
            return code

    def analyse() -> None:
        for start in starts(sac_run):
            experiment, out = f"{NAME}-{start}", args.out / start
            evaluate_missing(experiment, out, suites, args.episodes)
            for suite in suites:
                make_tables(experiment, out, suite)
            export(experiment, args.records / start)
        table = summary_table(suites, sac_run)
        for folder in (args.out, args.records):
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "starts.md").write_text(table)
        print(table)

    return run_command(analyse)


if __name__ == "__main__":
    raise SystemExit(main())
