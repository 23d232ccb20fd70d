"""What ePOET-SAC's join keeps of the SAC actor: the mapped ES agent's score over the actor's.

For each run seed, builds `algo=epoet_sac` with the overrides (the default start is the
authors' SAC actor, `reference:sac/42`), runs `--iterations` iterations of the real loop (at
least one, so the pool's observation statistics exist and the mapping works in the pool's
standardised space, as at a join), then on the terrain Train_SAC used at the last of them maps
the actor into the ES network with each of `--mappings` (the join's own code,
`ActorExchange.map_and_score`, keyed by the iteration) and scores the mapped agent and the actor
from the same starts (SacKey.JOIN_EVAL). For actors that walk (score >= 1000), it reports mapped /
actor; the last line is the smallest ratio per mapping over the seeds.

    .venv/bin/python bench/join_mapping.py [--seeds 1,2,3] [--iterations 1]
        [--mappings dagger,distill,random] override ...
"""

from __future__ import annotations

import argparse
import json
import os
import time
from contextlib import closing

from epoet.config import load
from epoet.epoet_sac.loop import EpoetSac
from epoet.epoet_sac.runner import warm_start_of
from epoet.open_ended.runner import layer_sizes
from epoet.rollout.evaluators import evaluator_for

WALKS = 1000.0  # an actor that walks: the threshold


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--iterations", type=int, default=1)
    parser.add_argument("--mappings", default="dagger,distill,random")
    parser.add_argument("--out", default=None, help="JSON lines, one per seed and mapping")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    ratios: dict[str, list[float]] = {m: [] for m in args.mappings.split(",")}
    out = open(args.out, "w") if args.out else None
    for seed in (int(s) for s in args.seeds.split(",")):
        cfg = load(["algo=epoet_sac", *args.overrides, f"seed={seed}"])
        with (
            evaluator_for(cfg.workers, cfg.agent, cfg.terrain, layer_sizes(cfg)) as evaluator,
            closing(EpoetSac.from_config(cfg, evaluator, warm_start_of(cfg))) as loop,
        ):
            for _ in range(max(1, args.iterations)):
                loop.run_iteration()
            t = loop.iteration - 1
            pair = loop.sac_pair(t)
            terrain = loop.service.terrain(pair.env, t)
            for mapping in ratios:
                started = time.perf_counter()
                mapped = loop.exchange.map_and_score(t, terrain, mapping, t)
                walks = mapped.sac_score >= WALKS
                ratio = mapped.score / mapped.sac_score if walks else float("nan")
                if walks:
                    ratios[mapping].append(ratio)
                row = {
                    "seed": seed,
                    "iteration": t,
                    "env": pair.env.index,
                    "mapping": mapping,
                    "actor": round(mapped.sac_score, 1),
                    "mapped": round(mapped.score, 1),
                    "ratio": round(ratio, 3),
                    "error": mapped.error,
                    **mapped.cost,
                    "seconds": round(time.perf_counter() - started, 1),
                    "load1": os.getloadavg()[0],
                }
                print(json.dumps(row), flush=True)
                if out:
                    out.write(json.dumps(row) + "\n")
                    out.flush()
    print(
        " ".join(
            f"min ratio {m} = {min(r):.3f} ({len(r)} walking)"
            if r
            else f"min ratio {m} = n/a (0 walking)"
            for m, r in ratios.items()
        )
    )


if __name__ == "__main__":
    main()
