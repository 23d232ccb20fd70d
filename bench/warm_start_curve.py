"""Does a warm-started SAC actor keep its skill inside ePOET-SAC? (issue 36)

Runs `algo=epoet_sac` exactly as `python -m epoet` does (the same loop, evaluator and
iterations; no tracker, no checkpoints) and, after every `--every`-th iteration, scores the SAC
actor's deterministic policy on the terrain Train_SAC used at that iteration, from that
environment's evaluation starts of that iteration (Key.EVAL: the starts the pool's agent of that
environment is scored from). Row -1 is the loaded actor before any training, on iteration 0's
terrain. Scoring steps SAC's own env between iterations and draws no random numbers the run
uses, so the run is the one `python -m epoet` would make with the same overrides.

    .venv/bin/python bench/warm_start_curve.py --out curve.jsonl [--every 2] override ...

Each line of `--out`: iteration, environment, score, the iteration's `sac/alpha`,
`sac/updated_from_pool` and `sac/score` where it has them, wall seconds and the load average.

    .venv/bin/python bench/warm_start_curve.py --table old_s1.jsonl new_s1.jsonl ...

prints the curves side by side as a markdown table (a column per file, the scored rows).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from contextlib import closing
from pathlib import Path

from epoet.config import load
from epoet.epoet_sac.loop import EpoetSac
from epoet.epoet_sac.runner import warm_start_of
from epoet.open_ended.keys import Key
from epoet.open_ended.runner import layer_sizes
from epoet.rollout.evaluators import evaluator_for

KEPT = (
    "sac/alpha",
    "sac/score",
    "sac/top_score",
    "sac/updated_from_pool",
    "sac/distilled_score",
    "sac/warm_loss_qvalue",
    "join/",
    "admitted",
    "transfers",
    "replaced",
)  # key prefixes


def score(loop: EpoetSac, t: int) -> tuple[int, float]:
    """The actor's mean return on iteration t's Train_SAC terrain, from its evaluation starts."""
    pair = loop.sac_pair(t)
    service = loop.service
    seeds = service.seeds(service.eval_episodes, Key.EVAL, pair.env.index, t)
    return pair.env.index, loop.exchange.actor_score(service.terrain(pair.env, t), seeds)


def table(paths: list[str]) -> str:
    """The scored rows of curve files as one markdown table, a column per file (its stem)."""
    columns: dict[str, dict[int, float]] = {}
    for path in paths:
        rows = [json.loads(line) for line in open(path)]
        columns[Path(path).stem] = {r["iteration"]: r["score"] for r in rows if "score" in r}
    iterations = sorted({t for c in columns.values() for t in c})
    lines = ["| iteration | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for t in iterations:
        cells = [f"{c[t]:.0f}" if t in c else "" for c in columns.values()]
        lines.append(f"| {'start' if t < 0 else t} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", nargs="+", help="curve files: print them side by side")
    parser.add_argument("--out")
    parser.add_argument("--every", type=int, default=2)
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    if args.table:
        print(table(args.table))
        return
    if not args.out:
        parser.error("--out is required to run")
    cfg = load(["algo=epoet_sac", *args.overrides])
    started = time.perf_counter()
    with (
        open(args.out, "w") as out,
        evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator,
        closing(EpoetSac.from_config(cfg, evaluator, warm_start_of(cfg))) as loop,
    ):

        def write(t: int, metrics: dict[str, float], scored: bool) -> None:
            row: dict[str, object] = {"iteration": t}
            if scored:
                row["env"], row["score"] = score(loop, max(t, 0))
            row.update({k: v for k, v in metrics.items() if k.startswith(KEPT)})
            row["wall_s"] = round(time.perf_counter() - started, 1)
            row["load1"] = os.getloadavg()[0]
            out.write(json.dumps(row) + "\n")
            out.flush()
            print(json.dumps(row), flush=True)

        write(-1, {}, True)
        while loop.iteration < cfg.budget.iterations:
            t = loop.iteration
            metrics = loop.run_iteration()
            last = t == cfg.budget.iterations - 1
            write(t, metrics, t % args.every == 0 or last or "joined" in metrics)


if __name__ == "__main__":
    main()
