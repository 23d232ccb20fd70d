"""Screen candidate changes for faster ES learning on the workstation budget's root pair.

Each candidate is a list of `python -m epoet` overrides; each runs for every seed through
`bench/time_to_walker.py`'s root pair, on a shorter budget (the proxy: the score reached in
`--iterations` iterations, or the iteration at which it reaches 2000). Every (candidate, seed)
appends one JSON line to `--out`, with the command, commit and machine load, so the screen
resumes where it stopped and the record stays with the repository:

    python bench/screen_walkers.py --iterations 100 --seeds 1,2,3 [candidate ...]
    python bench/screen_walkers.py --report            # the table of what is in --out

Scores, iterations and steps are a function of the config and seed; minutes depend on the
load, which each line records.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from time_to_walker import describe, root_pair_config, time_to_walker  # noqa: E402

from epoet.core.cores import default_workers  # noqa: E402

# Why each: docs/benchmarks.md "Walker experiments" keeps the reasoning and the outcome.
# Each names every setting it changes, whatever the budget's default (budget=workstation has
# normalised observations since the screen found them; the rows before that ran its defaults).
CANDIDATES: dict[str, list[str]] = {
    "baseline": ["algo.es.obs_norm_episodes=0"],
    "lr=0.02": ["algo.es.obs_norm_episodes=0", "algo.es.lr=0.02"],
    "sigma=0.04": ["algo.es.obs_norm_episodes=0", "algo.es.sigma=0.04"],
    "no_progress_steps=200": ["algo.es.obs_norm_episodes=0", "agent.no_progress_steps=200"],
    "obs_norm": ["algo.es.obs_norm_episodes=1"],
    # on top of the survivor
    "obs_norm+lr=0.02": ["algo.es.obs_norm_episodes=1", "algo.es.lr=0.02"],
    "obs_norm+no_progress_steps=200": ["algo.es.obs_norm_episodes=1",
                                       "agent.no_progress_steps=200"],
    # the paper's population (256 mirrored pairs) against the budget's 48, on the relief the
    # rows above ran on (S fixed at 0.1 m, the budget's schedule then): compare steps
    "obs_norm+n_pairs=256": ["algo.es.obs_norm_episodes=1", "budget.n_pairs=256",
                             "budget.max_height_step=0.0"],
}
OUT = Path(__file__).parent / "walker_screen.jsonl"


def _commit() -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True, cwd=Path(__file__).parent).stdout.strip()


def _done(out: Path, iterations: int) -> set[tuple[str, int]]:
    if not out.exists():
        return set()
    rows = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    return {(r["candidate"], r["seed"]) for r in rows if r["budget_iterations"] == iterations}


def screen(names: list[str], seeds: list[int], iterations: int, out: Path) -> None:
    done = _done(out, iterations)
    for name in names:
        for seed in seeds:
            if (name, seed) in done:
                continue
            overrides = [f"budget.iterations={iterations}", *CANDIDATES[name]]
            cfg = root_pair_config(seed, overrides)
            threshold = cfg.algo.repro_threshold * cfg.budget.score_scale
            load_before = os.getloadavg()[0]
            walk = time_to_walker(cfg, threshold)
            print(f"[{name}] {describe(seed, threshold, walk)}", flush=True)
            row = {"candidate": name, "seed": seed, "budget_iterations": iterations,
                   "command": "python bench/time_to_walker.py --seeds "
                              f"{seed} {' '.join(overrides)}".rstrip(),
                   "commit": _commit(), "workers": cfg.workers.num or default_workers(),
                   "load1_before": round(load_before, 2),
                   "load1_after": round(os.getloadavg()[0], 2),
                   **{k: (round(v, 2) if isinstance(v, float) else v)
                      for k, v in walk._asdict().items()}}
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")


def report(out: Path) -> None:
    """One line per candidate and budget: seeds, walkers (the iteration, environment steps and
    minutes at which each reached 2000), the final scores and their median."""
    rows = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    groups: dict[tuple[str, int], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["candidate"], r["budget_iterations"]), []).append(r)
    print("| change | iterations | seeds | reached 2000: iteration (M steps, min) | final score |"
          " median final |")
    print("|---|---|---|---|---|---|")
    for (name, iterations), rs in groups.items():
        rs.sort(key=lambda r: r["seed"])
        reached = "; ".join(f"{r['iterations']} ({r['env_steps'] / 1e6:.1f}, {r['minutes']:.1f})"
                            if r["reached"] else "-" for r in rs)
        scores = ", ".join(f"{r['score']:.0f}" for r in rs)
        print(f"| {name} | {iterations} | {', '.join(str(r['seed']) for r in rs)} | "
              f"{sum(r['reached'] for r in rs)}/{len(rs)}: {reached} | {scores} | "
              f"{np.median([r['score'] for r in rs]):.0f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("candidates", nargs="*", help=f"default: all of {list(CANDIDATES)}")
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--report", action="store_true", help="print the table and stop")
    args = parser.parse_args()
    if args.report:
        report(args.out)
        return
    unknown = [n for n in args.candidates if n not in CANDIDATES]
    if unknown:
        sys.exit(f"error: unknown candidate(s) {unknown}; known: {list(CANDIDATES)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    screen(args.candidates or list(CANDIDATES), [int(s) for s in args.seeds.split(",")],
           args.iterations, args.out)
    report(args.out)


if __name__ == "__main__":
    main()
