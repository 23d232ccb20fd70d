"""Checkpoints of older code, read in today's layout, and what a resume may change.

A run resumes only with the settings it was started with, but the config's layout has moved
since the first checkpoints were written (budgets took over the integrator and the height
schedule; the algorithm x budget values moved to conf/algo_budget/; robots became parts). This
module holds that history apart from running a job (epoet/run.py asks it for `config_changes`),
so every old checkpoint keeps loading and a new layout change adds its step here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from epoet.config import saved_agent
from epoet.run_state import BUDGET_LIMITS

# What a resume may change: where and how it runs, and how long it goes on.
# (`algo._target_`, the runner's dotted path that checkpoints from 2026-11 to today's registry
# held, said where the algorithm's code lived, not how it runs.)
RESUMABLE = (
    *("resume", "check", "workers", "tracking", "checkpoint_every"),
    *(f"budget.{key}" for key in BUDGET_LIMITS),
    *("snapshot_cpu_minutes", "algo._target_"),
    "selection",  # which agent the run exports, not how it trains
    "epoet_3d",  # where the authors' files are read from (checked against their hashes)
)
# Settings added after checkpoints were written, with the value that reproduces what those runs
# did: a checkpoint without them resumes only where they keep that value.
PREDATED = {"algo.es.terrain_variants": "1", "terrain.rendering": "clean"}


def saved_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's config in today's layout, with the values its run ran with.

    Checkpoints written before budgets owned their integrator and height schedule and before the
    algorithm x budget values moved to conf/algo_budget/ kept every algorithm's budget keys, the
    integrator and S schedule only in `agent` and `terrain`, ePOET's intervals as budget
    overrides of the algorithm's (null: the algorithm's) and ePOET-SAC's Train_SAC frames as
    `budget.sac_frames_per_iteration` (null: `algo.frames_per_iteration`). Checkpoints from
    before robots were parts are the hexapod's (`saved_agent`)."""
    saved = {**saved, "agent": saved_agent(saved["agent"])}
    budget, algo = dict(saved["budget"]), dict(saved["algo"])
    if "max_height" not in budget:  # before the budget owned S's start: the terrain's
        budget["max_height"] = saved["terrain"]["max_height"]
        saved = {**saved, "budget": budget}
    if "integrator" in budget:  # today's layout
        return saved
    budget["integrator"] = saved["agent"]["integrator"]
    budget["max_height_step"] = saved["terrain"]["max_height_step"]
    transfer, reproduce = budget.pop("transfer_interval"), budget.pop("reproduce_interval")
    sac_frames = budget.pop("sac_frames_per_iteration")
    if "iterations_before_transfer" in algo:  # ePOET, ePOET-SAC: their budget is iterations
        for key in ("frames", "eval_every"):
            del budget[key]
        every = transfer or algo["iterations_before_transfer"]
        first = reproduce or algo["adjust_interval"] * algo["iterations_before_transfer"]
        later = algo.pop("later_reproduce_interval") or first
        # in transfer intervals; an interval that is not a multiple shows as a changed setting
        algo.update(
            iterations_before_transfer=every,
            adjust_interval=first // every if first % every == 0 else first / every,
            later_adjust_interval=later // every if later % every == 0 else later / every,
        )
        if "frames_per_iteration" in algo:
            algo["frames_per_iteration"] = sac_frames or algo["frames_per_iteration"]
    else:  # the baselines: frames
        for key in ("iterations", "n_pairs"):
            del budget[key]
    return {**saved, "budget": budget, "algo": algo}


def config_changes(
    saved: dict[str, Any], current: dict[str, Any], unused: Sequence[str] = ()
) -> list[str]:
    """`key (old -> new)` for every setting that differs, except the RESUMABLE ones and those
    the resumed run never reads (`unused`: Config.unused_keys; `saved`: a checkpoint's config,
    in any layout `saved_config` reads). A setting the checkpoint predates counts as what its run
    did (`PREDATED`), else as null (its run had none of it), so such a run resumes with that
    setting at that value, where it would otherwise show as changed whatever the user sets."""
    from epoet.tracking import flatten

    old, new = flatten(saved_config(saved)), flatten(current)
    skipped = (*RESUMABLE, *unused)
    old = {**{k: v for k, v in PREDATED.items() if k in new}, **old}
    keys = sorted(
        k
        for k in old.keys() | new.keys()
        if old.get(k, "None") != new.get(k, "None")
        and not any(k == r or k.startswith(f"{r}.") for r in skipped)
    )
    return [f"{k} ({old.get(k, 'None')} -> {new.get(k, 'None')})" for k in keys]
