"""`python -m pipeline.choose --records <records>/<algo>_s<seed>...`: the held-out choice of a
pool's agent (`selection`, epoet/rollout/selection.py) for records whose runs trained before
runs chose their agent on held-out terrains, and the evaluation of records' snapshots (any
algorithm's) on another suite (`--suites admitted`, the validation suite; `--minutes`,
`--exported-only`).

Each CPU-time snapshot of the record without an exported agent gets one, chosen as the run
would have chosen it (among its niches' best and last parameters, on the held-out terrains of
its seed, with the run's config as composed now plus `selection.*` overrides), marked
`post_hoc` in its choice.json; the chosen agent is evaluated on the suites with the paper's
protocol and run.json rewritten with both readings (the exported agent's and the own-terrain
choice's). The choice's CPU time is recorded (`cpu_s`); unlike a run's own, it counts against
no training budget.

Examples:

    python -m pipeline.choose --records docs/results/compute/epoet_s1 docs/results/compute/epoet_s2
    python -m pipeline.choose --records docs/results/levers/*/epoet_s* --suites admitted \
        --minutes 60 --exported-only
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from analysis.records import RUN_FILE
from analysis.store import AnalysisError, run_command
from epoet.core.help import HelpParser
from epoet.driver import SNAPSHOT_INFO
from epoet.rollout.agent_files import ES_POLICIES, EXPORTED_AGENT
from pipeline.records import write_json
from pipeline.snapshots import (
    add_evaluation_arguments,
    evaluate_snapshot,
    niches_of,
    promote_latest,
)

NOT_OVERRIDES = ("resume=", "hydra.", "tracking.", "evaluate=")  # how a run ran, not what it was


def run_overrides(command: str) -> list[str]:
    """The config overrides of a record's `python -m epoet ...` command."""
    words = shlex.split(command)[3:]
    return [w for w in words if "=" in w and not w.startswith(NOT_OVERRIDES)]


def snapshot_niches(folder: Path) -> list:
    """The niches of a record's snapshot, from their agent files (best and last parameters)."""
    from epoet.open_ended.exported_agent import Niche

    niches = []
    for path in niches_of(folder):
        with np.load(path, allow_pickle=False) as data:
            niches.append(
                Niche(
                    int(path.stem[3:]),
                    data["best_theta"],
                    float(data["best_score"]),
                    data["final_theta"],
                    float(data["final_score"]),
                )
            )
    return niches


def needs_choice(snapshot: Path) -> bool:
    """An ES pool's snapshot without its held-out choice (a baseline's policy is its own)."""
    return bool(niches_of(snapshot)) and not (snapshot / ES_POLICIES / EXPORTED_AGENT).is_file()


def choose_record(
    record: Path,
    selection: Sequence[str],
    suites: list,
    cfg,
    pool,
    minutes: set[str] | None = None,
    exported_only: bool = False,
) -> None:
    """Give every snapshot of `record` (`minutes`: those marks only) its held-out choice,
    evaluate it (`exported_only`: only the exported agent), rewrite run.json."""
    from epoet.config import load
    from epoet.eval.agents import resolve_run
    from epoet.open_ended.exported_agent import choose
    from epoet.rollout.agent_files import read_es_policy

    info = json.loads((record / RUN_FILE).read_text())
    run = load([*run_overrides(info["command"]), *selection])
    trained = resolve_run(str(record))
    for mark, entry in info["snapshots"].items():
        if minutes is not None and mark not in minutes:
            continue
        folder = record / f"cpu{mark}"
        if needs_choice(folder):
            niches = snapshot_niches(folder)
            _, sizes = read_es_policy(niches_of(folder)[0])
            iteration = json.loads((folder / SNAPSHOT_INFO).read_text())["iteration"]
            chosen = choose(
                folder, niches, run, run.agent, sizes, iteration=iteration, post_hoc=True
            )
            print(
                f"[choose] {record.name} cpu{mark}: {chosen['exported']} (own-terrain "
                f"choice {chosen['own']}; {chosen['cpu_s']:.0f} CPU s)",
                flush=True,
            )
        fresh = evaluate_snapshot(folder, record, trained, suites, cfg, pool, exported_only)
        fresh["evaluations"] = {**entry.get("evaluations", {}), **fresh["evaluations"]}
        info["snapshots"][mark] = fresh
        write_json(record / RUN_FILE, info)  # each snapshot's evaluation kept as it arrives
    info["evaluations"] = promote_latest(record, info["snapshots"])
    write_json(record / RUN_FILE, info)


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m pipeline.choose", __doc__)
    parser.add_argument(
        "--records", nargs="+", type=Path, required=True, help="records, e.g. <out>/epoet_s1"
    )
    add_evaluation_arguments(parser)
    parser.add_argument(
        "--selection", nargs="*", default=[], help="selection.* overrides (default: the config's)"
    )
    parser.add_argument(
        "--minutes", default=None, help="only the snapshots at these CPU minutes, e.g. 60,30"
    )
    parser.add_argument(
        "--exported-only",
        action="store_true",
        help="evaluate only the agent each snapshot exported, not every niche's",
    )
    args = parser.parse_args(argv)

    def choose_all() -> None:
        marks = None if args.minutes is None else {f"{float(m):g}" for m in args.minutes.split(",")}
        for record in args.records:  # every record checked before any work
            if not (record / RUN_FILE).is_file():
                raise AnalysisError(f"{record} is not a record: it has no {RUN_FILE}.")
            snapshots = json.loads((record / RUN_FILE).read_text())["snapshots"]
            unchosen = [
                m
                for m in snapshots
                if (marks is None or m in marks) and needs_choice(record / f"cpu{m}")
            ]
            if args.exported_only and unchosen:  # its new agent would lack the other suites
                raise AnalysisError(
                    f"{record} cpu{unchosen[0]} has no exported agent to read alone: run "
                    "without --exported-only to choose one and evaluate it on every suite."
                )
        from epoet.config import compose, validate
        from epoet.eval.episodes import evaluation_pool
        from epoet.eval.suite import load_suite

        suites = [load_suite(name) for name in args.suites.split(",")]
        with evaluation_pool(args.processes) as pool:
            for record in args.records:
                overrides = [f"run={record}", f"episodes={args.episodes}"]
                cfg = validate(compose(overrides, config_name="evaluate"))
                choose_record(record, args.selection, suites, cfg, pool, marks, args.exported_only)

    return run_command(choose_all)


if __name__ == "__main__":
    raise SystemExit(main())
