"""`python -m analysis.paper_report --records docs/results/<name> [--suites paper,admitted,shipped]`:
what the paper reports, from one experiment's records alone (`make paper` at a CPU-hour budget
writes them; pipeline.snapshots' format).

Per suite, into `<out>/<suite name>/`:
- the paper's Table 1 (success by level, mean ± std over seeds), the same run by run with the
  mean over seeds and its 95 % t interval (`table1_seeds_*`), Table 2 (return over the easy and
  medium terrains), the IQM and probability-of-improvement tables (analysis.tables), read at
  each record's latest snapshot;
- success against CPU hours for every algorithm with each seed and the interval over seeds, its
  figure, the learning curves, the pairwise comparisons and the paper's claims with their
  intervals at every CPU-time mark (analysis.success_vs_compute).

The same records give the same bytes (tests/test_paper_report.py rebuilds every committed
report), so a committed report is checked against the records beside it.

Examples:

    python -m analysis.paper_report --records docs/results/paper-workstation
    python -m analysis.paper_report --records docs/results/paper-workstation --suites admitted \\
        --out /tmp/report
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from analysis.store import run_command
from analysis.success_vs_compute import write
from analysis.tables import tables_from_records
from epoet.core.help import HelpParser
from epoet.eval.keys import ADMITTED_NAME, PAPER_NAME, SHIPPED_NAME
from epoet.eval.suite import load_suite

SUITES = f"{PAPER_NAME},{ADMITTED_NAME},{SHIPPED_NAME}"


def write_report(records: Path, suites: Sequence[str], out: Path) -> list[Path]:
    """Every suite's tables, comparisons and figures into out/<suite name>/; the paths."""
    names = [load_suite(suite).name for suite in suites]  # every suite reads before any write
    paths = []
    for suite, name in zip(suites, names):
        print(f"\n[report] suite {name}", flush=True)
        paths += tables_from_records(records, out / name, suite)
        paths += write(records, name, out / name)
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m analysis.paper_report", __doc__)
    parser.add_argument(
        "--records", type=Path, required=True, help="the experiment's records folder"
    )
    parser.add_argument(
        "--suites", default=SUITES, help="comma-separated suites (names or folders)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (None: results/paper/<records folder name>)",
    )
    args = parser.parse_args(argv)

    def report() -> None:
        out = args.out or Path("results") / "paper" / args.records.name
        write_report(args.records, [s for s in args.suites.split(",") if s], out)
        print(f"[report] in {out}/", flush=True)

    return run_command(report)


if __name__ == "__main__":
    raise SystemExit(main())
