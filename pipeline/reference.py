"""`make reference` (`python -m pipeline.reference [--episodes 5] [--suite paper]`): the
authors' published agents (read from their files: epoet.eval.reference) on the paper's suite, tabled like runs.

1. evaluates every shipped `reference:<run>/<agent>` that has no evaluation on the suite yet
   (each agent's MLflow run in the experiment `reference`; one process pool for all of them);
2. writes Tables 1-2 to `results/reference/<suite>/`, an algorithm's row over its agents (an
   ePOET run's niche agents are its "runs": the reference's evaluate_model.py counts every
   niche agent on every terrain, so its success rate is the mean over niche agents);
3. writes `agents.{md,csv}` beside them: one row per agent, the same columns;
4. with `--records <folder>`, exports every agent's run as an evaluation record there
   (`pipeline.records`: `<folder>/<algo>_<agent>/`, e.g. `epoet_flat`, `epoet_sac_sac_58`,
   `ppo_0`), so `python -m analysis.tables --records <folder> --suite paper` rebuilds the
   tables without the store.
The paper reports neither VMPO nor which niche makes an algorithm's row; both are shown.

Examples:

    python -m pipeline.reference
    python -m pipeline.reference --episodes 1 --out /tmp/reference
    python -m pipeline.reference --suite shipped --records docs/results/reference
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from analysis.store import connect, evaluation_on, run_command
from analysis.tables import EASY_MEDIUM, episodes_of, make_tables, to_markdown
from epoet.config import compose, validate
from epoet.core.cores import default_workers
from epoet.core.help import HelpParser
from epoet.eval.agents import resolve_run
from epoet.eval.episodes import evaluation_pool
from epoet.eval.evaluate import evaluate_run
from epoet.eval.reference import EXPERIMENT, PREFIX, names
from epoet.eval.suite import LEVELS, load_suite
from pipeline.records import export


def evaluate_reference(out: Path, suite: str, episodes: int) -> list[str]:
    """Evaluate the shipped agents without an evaluation on `suite`; their run ids."""
    loaded = load_suite(suite)
    runs = {name: resolve_run(PREFIX + name) for name in names()}  # made in the store if new
    client, uri = connect()
    ids = {
        name: run.stored.run_id for name, run in runs.items() if run.stored is not None
    }  # every one: resolve_run stores reference agents
    missing = [
        name
        for name, run_id in ids.items()
        if evaluation_on(client.get_run(run_id), loaded) is None
    ]
    if missing:
        print(
            f"[reference] evaluating {len(missing)} agent(s) on suite {loaded.name}, "
            f"{episodes} episodes per terrain: {', '.join(missing)}",
            flush=True,
        )
        with evaluation_pool(default_workers()) as pool:
            for name in missing:
                cfg = validate(
                    compose(
                        [
                            f"run={PREFIX}{name}",
                            f"suite={suite}",
                            f"episodes={episodes}",
                            f"tracking.uri={uri}",
                            f"out={out / 'evaluations' / name.replace('/', '_')}",
                        ],
                        config_name="evaluate",
                    )
                )
                evaluate_run(cfg, pool=pool)
    return list(ids.values())


def agent_rows(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per agent: success rate per level and in total, easy+medium return mean, max."""
    rows = []
    for (algo, agent), mine in episodes.groupby(["algo", "seed"], sort=False):
        row = {"algorithm": algo, "agent": agent}
        for level in (*LEVELS, "total"):
            rows_at = mine if level == "total" else mine[mine.level == level]
            row[level] = f"{100 * rows_at.solved.mean():.1f}" if len(rows_at) else "-"
        easy_medium = mine[mine.level.isin(EASY_MEDIUM)]["return"]
        row["easy+medium return"] = f"{easy_medium.mean():.1f} ± {easy_medium.std(ddof=1):.1f}"
        row["max return"] = f"{easy_medium.max():.1f}"
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m pipeline.reference", __doc__)
    parser.add_argument("--suite", default="paper", help="suite name or folder")
    parser.add_argument("--episodes", type=int, default=5, help="episodes per terrain")
    parser.add_argument(
        "--out", type=Path, default=Path("results") / "reference", help="tables: OUT/<suite>/"
    )
    parser.add_argument(
        "--records",
        type=Path,
        default=None,
        metavar="FOLDER",
        help="also export every agent's run as an evaluation record into "
        "FOLDER, e.g. docs/results/reference",
    )
    args = parser.parse_args(argv)

    def run() -> None:
        run_ids = evaluate_reference(args.out, args.suite, args.episodes)
        out = args.out / load_suite(args.suite).name
        make_tables(EXPERIMENT, out, args.suite, run_ids)
        client, _ = connect()
        episodes = episodes_of(client, [client.get_run(r) for r in run_ids], load_suite(args.suite))
        shown = agent_rows(episodes)
        shown.to_csv(out / "agents.csv", index=False)
        (out / "agents.md").write_text(
            f"Every authors' agent on suite {args.suite}: success "
            f"rate (%) by level, return over the easy and medium "
            f"terrains\n\n{to_markdown(shown)}\n"
        )
        print(f"\n{to_markdown(shown)}\n\nwrote {out / 'agents.md'}")
        if args.records is not None:
            export(EXPERIMENT, args.records, run_ids=run_ids)

    return run_command(run)


if __name__ == "__main__":
    raise SystemExit(main())
