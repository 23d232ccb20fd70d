"""What ePOET-SAC's join loses: the mapped ES agent's score against the SAC actor's.

Loads an `algo=epoet_sac` run's checkpoint and, on every active environment's terrain of the
run's last iteration, maps the SAC actor into the ES shape with both mappings (`distill`, ours,
and `random`, the paper's random parameter selection; three mapping seeds each) and scores the
mapped agents and the actor itself from the same starts:

    python bench/join_mapping.py /path/to/run/folder budget=laptop

The overrides are the run's (as for `resume=`). The last line is
`gap distill = X random = Y` (mean |mapped score - SAC actor score|).
"""
from __future__ import annotations

import sys

import numpy as np

from epoet.core.checkpoint import find_checkpoint, load_checkpoint
from epoet.config import load
from epoet.rollout.evaluators import make_evaluator
from epoet.epoet_sac.loop import EpoetSac
from epoet.poet.runner import layer_sizes

SEEDS = 3


def main(run_dir: str, overrides: list[str]) -> None:
    state = load_checkpoint(find_checkpoint(run_dir))["poet"]
    cfg = load(["algo=epoet_sac", *overrides])
    with make_evaluator(cfg.agent, cfg.terrain, "local", cfg.workers.batch,
                        layer_sizes(cfg)) as evaluator:
        poet = EpoetSac.from_config(cfg, evaluator)
        poet.load_state_dict(state)
        t = poet.iteration - 1
        gaps: dict[str, list[float]] = {"distill": [], "random": []}
        for pair in poet.pool.active:
            terrain = poet.service.terrain(pair.env, t)
            for mapping in gaps:
                runs = [poet.exchange.map_and_score(t + k, terrain, mapping, pair.env.index)
                        for k in range(SEEDS)]
                gaps[mapping] += [abs(m.score - m.sac_score) for m in runs]
                print(f"env{pair.env.index}: SAC actor {runs[0].sac_score:8.1f}  {mapping:7s} "
                      + " ".join(f"{m.score:8.1f}" for m in runs), flush=True)
        poet.close()
    print(f"gap distill = {np.mean(gaps['distill']):.1f} random = {np.mean(gaps['random']):.1f}")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: python bench/join_mapping.py <run folder> [overrides...]")
    main(sys.argv[1], sys.argv[2:])
