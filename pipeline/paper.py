"""`make paper BUDGET=<budget> SEEDS=1,2,3`: every algorithm x seed, evaluated, tabled, plotted.

1. trains every algorithm (`--algos`; default: every registered one, epoet/registry.py) for
   every seed as one Hydra multirun into the MLflow experiment `paper-<budget>`, with fixed job
   folders (`<--runs>/<algo>_s<seed>`, default `multirun/paper-<budget>/`) and `resume=auto`,
   so calling it again after an interruption skips the finished jobs and continues the
   interrupted ones from their checkpoints; `--jobs` at a time (default: one per core), each
   with its share of the cores as workers;
2. evaluates and tables, in one of two ways:
   - at a budget that ends runs by CPU hours (`budget.cpu_hours`: workstation), each run's
     CPU-time snapshots (`snapshot_cpu_minutes`) are evaluated as soon as its job ends, by the
     job's own slot (pipeline/snapshot_records.py), the agent each snapshot exported on each
     suite of `--suites` (default `paper,admitted,shipped`), into the records folder
     `--records` (default `<out>/records`); then analysis.paper_report writes from the records
     alone, per suite, Tables 1 and 2, each seed with the interval over seeds, success against
     CPU hours for every algorithm, and the paper's claims as paired differences, into `<out>/`;
   - otherwise every finished run that has no evaluation yet on each suite (default
     `shipped,paper`; a run's `eval_suite/<name>` tag) is evaluated and logged to the store
     (`evaluate_missing`, tagged with the evaluating commit, `eval_commit/<name>`), and the
     tables (`analysis.tables`, `analysis.stats`) and figures (t-SNE, the suite gallery of the
     first suite) are written from the store to `<out>/`; `--records <folder>` also exports
     every evaluated run as evaluation records there (`pipeline.records`).

`<out>` defaults to results/paper-<budget>.

Examples:

    python -m pipeline.paper --budget smoke --seeds 1          # a few minutes, end to end
    python -m pipeline.paper --budget workstation --records docs/results/paper-workstation \\
        --runs /data/paper-workstation                          # 15 CPU hours on one core each
    python -m pipeline.paper --budget laptop --algos epoet,ppo --records docs/results/mine
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf.errors import OmegaConfBaseException

from analysis.figures import write_figures
from analysis.paper_report import write_report
from analysis.store import connect, require_runs, run_command, select_runs, unevaluated
from analysis.tables import make_tables
from epoet.config import CONF_DIR, Config, compose, validate
from epoet.core.cli import fail
from epoet.core.cores import default_workers
from epoet.core.help import HelpParser
from epoet.core.schema import ConfigError
from epoet.eval.episodes import evaluation_pool
from epoet.eval.evaluate import evaluate_run
from epoet.eval.keys import ADMITTED_NAME, PAPER_NAME, SHIPPED_NAME
from epoet.eval.suite import SuiteError, load_suite
from epoet.registry import names
from pipeline.records import COMMIT_TAG, export

SUITES = f"{SHIPPED_NAME},{PAPER_NAME}"
# At a CPU-hour budget: the test suite, the validation suite and the shipped suite (the second check)
SNAPSHOT_SUITES = f"{PAPER_NAME},{ADMITTED_NAME},{SHIPPED_NAME}"


def parallel_overrides(jobs: int, cores: int) -> list[str]:
    """Hydra overrides that run `jobs` training jobs at a time (the joblib launcher), each with
    its share of the cores as workers, so jobs x workers <= cores; none for one job."""
    if jobs == 1:
        return []
    return [
        "hydra/launcher=joblib",
        f"hydra.launcher.n_jobs={jobs}",
        f"workers.num={max(1, cores // jobs)}",
    ]


def record_overrides(records: Path, suites: Sequence[str], episodes: int | None) -> list[str]:
    """The Hydra callback that records each job's snapshots when it ends (snapshot_records)."""
    key = "+hydra.callbacks.records"
    return [
        f"{key}._target_=pipeline.snapshot_records.RecordSnapshots",
        f"{key}.out='{records.absolute()}'",
        f"{key}.suites='{','.join(suites)}'",
        f"{key}.episodes={episodes or 5}",
    ]


def train_command(
    budget: str,
    seeds: str,
    algos: Sequence[str],
    experiment: str,
    sweep_dir: Path,
    jobs: int = 1,
    overrides: Sequence[str] = (),
) -> list[str]:
    """The training multirun, seed by seed (every algorithm's first seed before any second);
    `overrides` come last, so they win over the budget's values."""
    return [
        sys.executable,
        "-m",
        "epoet",
        "-m",
        f"seed={seeds}",
        f"algo={','.join(algos)}",
        *parallel_overrides(jobs, default_workers()),
        f"budget={budget}",
        f"tracking.experiment={experiment}",
        "resume=auto",
        # step 2 evaluates every run on the chosen suite with the chosen episode count
        "evaluate=false",
        f"hydra.sweep.dir={sweep_dir}",
        "hydra.sweep.subdir=${algo.name}_s${seed}",
        *overrides,
    ]


def check_suites(suites: Sequence[str]) -> None:
    """Every suite the runs will be evaluated on exists and reads, before hours of training."""
    try:
        for suite in suites:
            load_suite(suite)
    except SuiteError as err:
        fail(err)


def check_jobs(jobs: Sequence[Sequence[str]]) -> list[Config]:
    """Each training job's overrides checked as its run will check them (composition, ranges,
    combinations, what it starts from: its settings' `check_inputs`), before any training, so bad
    input is one line and exit 2 at once instead of a failed job minutes later. Sweep values
    (`a=1,2`) are the launcher's to expand and are left out of the check."""
    parser = OverridesParser.create()
    configs = []
    for overrides in jobs:
        try:
            parsed = parser.parse_overrides(list(overrides))
            single = [str(o.input_line) for o in parsed if not o.is_sweep_override()]
            configs.append(validate(compose(single)))
            configs[-1].algo.check_inputs(configs[-1])
        except (ConfigError, HydraException, OmegaConfBaseException) as err:
            fail(err)
    return configs


def evaluate_missing(
    experiment: str, out: Path, suites: Sequence[str | None], episodes: int | None
) -> None:
    """Evaluate (and log) every FINISHED run of `experiment` that has no evaluation yet on each
    of `suites` (None: the shipped suite), all through one process pool; local copies of the
    results go to out/evaluations/<run id>/<suite name>. Each evaluation is tagged with the
    commit that made it (`eval_commit/<suite name>`)."""
    from epoet.tracking import git_commit

    client, uri = connect()
    runs = require_runs(select_runs(client, uri, experiment), experiment, uri)
    configs = []
    for suite in suites:
        loaded = load_suite(suite)
        missing = unevaluated(runs, loaded)
        if not missing:
            continue
        print(
            f"[paper] evaluating {len(missing)} run(s) that have no evaluation on suite "
            f"{loaded.name} ({loaded.fingerprint}): "
            f"{', '.join(r.info.run_name for r in missing)}",
            flush=True,
        )
        overrides = (
            [f"tracking.uri={uri}"]
            + ([f"suite={suite}"] if suite else [])
            + ([f"episodes={episodes}"] if episodes else [])
        )
        configs += [
            (
                loaded.name,
                validate(
                    compose(
                        [
                            f"run={run.info.run_id}",
                            f"out={out / 'evaluations' / run.info.run_id / loaded.name}",
                            *overrides,
                        ],
                        config_name="evaluate",
                    )
                ),
            )
            for run in missing
        ]
    if not configs:
        return
    commit = git_commit()
    with evaluation_pool(default_workers()) as pool:
        for name, cfg in configs:
            _, _, run = evaluate_run(cfg, pool=pool)
            assert run.run_id is not None  # `run=<run id>`: a stored run
            client.set_tag(run.run_id, f"{COMMIT_TAG}/{name}", commit)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = HelpParser("python -m pipeline.paper", __doc__)
    parser.add_argument("--budget", default="laptop", help="the budget every job trains at")
    parser.add_argument("--seeds", default="1,2,3", help="comma-separated seeds")
    parser.add_argument(
        "--algos", default=",".join(names()), help="comma-separated algorithms (default: all)"
    )
    parser.add_argument(
        "--suites",
        "--suite",
        default=None,
        help="comma-separated suite names or folders that every run is evaluated and tabled "
        f"on (default: {SNAPSHOT_SUITES} at a CPU-hour budget, else {SUITES})",
    )
    parser.add_argument(
        "--episodes", type=int, default=None, help="evaluation episodes per terrain (None: 5)"
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=default_workers(),
        help="training jobs at a time (default: one per core); each gets cores / jobs workers",
    )
    parser.add_argument(
        "--runs",
        type=Path,
        default=None,
        metavar="FOLDER",
        help="where the job folders go (None: multirun/paper-<budget>)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="results folder (None: results/paper-<budget>)"
    )
    parser.add_argument(
        "--records",
        type=Path,
        default=None,
        metavar="FOLDER",
        help="also export every evaluated run as evaluation records into "
        "FOLDER (python -m pipeline.records), e.g. docs/results/<name>",
    )
    parser.add_argument(
        "overrides", nargs="*", help="Hydra overrides for every training job, e.g. budget.hours=0.4"
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    algos = [a for a in args.algos.split(",") if a]
    budgets = sorted(p.stem for p in (CONF_DIR / "budget").glob("*.yaml"))
    problems = (
        [f"unknown budget {args.budget!r} (available: {', '.join(budgets)})"]
        if args.budget not in budgets
        else []
    )
    problems += [
        f"unknown algorithm {a!r} (available: {', '.join(names())})"
        for a in algos
        if a not in names()
    ]
    if args.suites is not None and not [s for s in args.suites.split(",") if s]:
        problems.append(f"--suites names no suite, got {args.suites!r}")
    if not all(s.strip().isdigit() for s in args.seeds.split(",")):
        problems.append(f"seeds must be comma-separated integers, got {args.seeds!r}")
    if not 1 <= args.jobs <= default_workers():
        problems.append(
            f"--jobs must be between 1 and the {default_workers()} available cores, got {args.jobs}"
        )
    if problems:
        print(f"error: {problems[0]}.", file=sys.stderr)
        return 2
    seed = args.seeds.split(",")[0]
    configs = check_jobs(
        [[f"algo={a}", f"budget={args.budget}", f"seed={seed}", *args.overrides] for a in algos]
    )
    # Runs ended by CPU hours have their CPU-time snapshots: those are what is evaluated.
    by_cpu = all(cfg.budget.cpu_hours is not None for cfg in configs)
    suites = [s for s in (args.suites or (SNAPSHOT_SUITES if by_cpu else SUITES)).split(",") if s]
    check_suites(suites)
    experiment = f"paper-{args.budget}"
    out = args.out or Path("results") / experiment
    records = args.records or (out / "records" if by_cpu else None)
    command = train_command(
        args.budget,
        args.seeds,
        algos,
        experiment,
        args.runs or Path("multirun") / experiment,
        args.jobs,
        [
            *(record_overrides(records, suites, args.episodes) if by_cpu and records else []),
            *args.overrides,
        ],
    )
    print(
        f"[paper] training {len(algos)} algorithms x seeds {args.seeds} at budget "
        f"{args.budget}, {args.jobs} at a time (finished jobs are skipped)"
        + (f", each recorded into {records}/ as it ends" if by_cpu else "")
        + f":\n  {' '.join(command[1:])}",
        flush=True,
    )
    if (code := subprocess.run(command).returncode) != 0:
        print(
            f"error: training stopped with exit code {code}; run the same command again to "
            f"continue where it stopped.",
            file=sys.stderr,
        )
        return code

    def analyse() -> None:
        if by_cpu:
            assert records is not None  # by_cpu: the default records folder
            write_report(records, suites, out)
            return
        evaluate_missing(experiment, out, suites, args.episodes)
        for suite in suites:
            make_tables(experiment, out, suite)
        write_figures(experiment, out / "figures", suites[0])
        if args.records is not None:
            export(experiment, args.records)

    if code := run_command(analyse):
        return code
    where = f"tables and figures in {out}/"
    if not by_cpu:
        where = f"tables in {out}/, figures in {out / 'figures'}/"
    print(f"[paper] {where}" + (f", records in {records}/" if records is not None else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
