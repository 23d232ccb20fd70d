"""`python -m analysis.levers --base <records> --records <records>... [--suite admitted]`:
settings compared on one suite, the way defaults are decided (docs/RESULTS.md, "Decisions on
the validation suite").

Each records folder holds one setting's runs (`<algo>_s<seed>/` of `--algo`, pipeline.snapshots' format,
their snapshots evaluated on the suite: `python -m pipeline.choose --suites admitted`). At each
CPU-minute mark a setting reads as the mean success, over its seeds, of the agent each snapshot
exported, with a 95 % t interval over seeds; beside it the medium terrains' mean and the paired
difference against `--base` over the seeds both have (the same seed and terrains), with its 95 %
t interval over those seeds. Only reads: prints one Markdown table, writes nothing.

Examples:

    python -m analysis.levers --base docs/results/levers/reference \\
        --records docs/results/levers/reference_variants4 docs/results/levers/variants4
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from analysis.mean_success import mean_interval
from analysis.records import EPISODES, RUN_FILE, read_csv, read_json
from analysis.store import AnalysisError, run_command
from epoet.core.help import HelpParser
from epoet.eval.keys import ADMITTED_NAME

Readings = dict[str, dict[int, tuple[float, float]]]  # mark -> seed -> (success, medium)


def readings(folder: Path, suite: str, algo: str) -> Readings:
    """Each snapshot's exported agent on `suite` (the records of `algo`): its success rate and
    its medium terrains'."""
    found: Readings = {}
    # by the algorithm each record names: `epoet_s*` also matches epoet_sac's records
    records = [
        (p.parent, info)
        for p in sorted(folder.glob(f"{algo}_s*/{RUN_FILE}"))
        if (info := read_json(p))["algo"] == algo
    ]
    if not records:
        raise AnalysisError(f"{folder} holds no records of {algo} ({algo}_s<seed>/{RUN_FILE}).")
    for record, info in records:
        for mark, snapshot in info.get("snapshots", {}).items():
            evaluation = snapshot.get("evaluations", {}).get(suite)
            if evaluation is None:
                continue
            episodes = read_csv(record / f"cpu{mark}" / snapshot["best_agent"] / suite / EPISODES)
            medium = episodes[episodes.level == "medium"].solved.mean()
            found.setdefault(mark, {})[int(info["seed"])] = (
                float(evaluation["success_rate"]),
                float(medium),
            )
    if not found:
        raise AnalysisError(
            f"no snapshot of {folder.name} is evaluated on suite {suite} (python -m "
            f"pipeline.choose --records {folder}/{algo}_s* --suites {suite})."
        )
    return found


def _interval(values: Sequence[float]) -> str:
    mean, low, high = (100 * v for v in mean_interval(values))
    return f"{mean:.1f} %" if np.isnan(low) else f"{mean:.1f} % [{low:.1f}, {high:.1f}]"


def _difference(values: Sequence[float]) -> str:
    mean, low, high = (100 * v for v in mean_interval(values))
    return f"{mean:+.1f}" if np.isnan(low) else f"{mean:+.1f} [{low:+.1f}, {high:+.1f}]"


def table(base: Path, folders: Sequence[Path], suite: str, algo: str) -> list[str]:
    """The Markdown rows: `base` first, then each folder, mark by mark."""
    against = readings(base, suite, algo)
    lines = [
        f"| setting | CPU minutes | seeds | success, per seed | mean [95 % CI] | medium | "
        f"paired against {base.name} |",
        "|---|---|---|---|---|---|---|",
    ]
    for folder in [base, *folders]:
        found = readings(folder, suite, algo) if folder != base else against
        for mark in sorted(found, key=float):
            seeds = found[mark]
            rates = [seeds[s][0] for s in sorted(seeds)]
            common = sorted(set(seeds) & set(against.get(mark, {})))
            paired = (
                _difference([seeds[s][0] - against[mark][s][0] for s in common])
                if folder != base and common
                else ""
            )
            lines.append(
                f"| {folder.name} | {mark} | {', '.join(map(str, sorted(seeds)))} | "
                f"{' / '.join(f'{100 * r:.1f}' for r in rates)} | {_interval(rates)} | "
                f"{100 * np.mean([seeds[s][1] for s in seeds]):.1f} % | {paired} |"
            )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m analysis.levers", __doc__)
    parser.add_argument("--base", type=Path, required=True, help="the setting compared against")
    parser.add_argument("--records", type=Path, nargs="*", default=[], help="the other settings")
    parser.add_argument("--suite", default=ADMITTED_NAME, help="the suite's name (admitted)")
    parser.add_argument("--algo", default="epoet", help="whose records a folder is read for")
    args = parser.parse_args(argv)

    def show() -> None:
        for line in table(args.base, args.records, args.suite, args.algo):
            print(line)

    return run_command(show)


if __name__ == "__main__":
    raise SystemExit(main())
