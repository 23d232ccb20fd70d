"""How large (and how hard) a held-out validation set must be for `selection` to export a good
agent.

A run exports the candidate (every niche's best and last parameters) that solves most of its
held-out CPPN terrains (conf/config.yaml `selection` and the budgets' overrides of it,
epoet/rollout/selection.py). This bench re-chooses, on several held-out sets, among the
candidates of every CPU-time snapshot of ePOET or ePOET-SAC records
(docs/results/.../epoet_s<seed>, epoet_sac_s<seed>), with the real selection code (`epoet.open_ended.exported_agent.candidates`,
`epoet.rollout.selection.es_held_out` on the terrains generated from the run's seed, never an
evaluation suite), and judges each choice
by the chosen candidate's success on `--suite` (32 terrains x 5 episodes, the protocol of
pipeline/snapshots.py): `admitted`, the validation suite, where a default is decided; `paper`,
the test suite, as the first calls did, before the validation protocol (docs/RESULTS.md).

Per size it prints: the mean success of the chosen agents over the snapshots, how
often the choice is the snapshot's best candidate on the suite (the oracle), the mean regret (oracle
minus chosen, percentage points) and the CPU seconds the selection took (mean per snapshot and
total); the run's own-terrain choice (choice.json `own`) and the oracle are printed for reference.

A candidate's success is read from the record when one of the snapshot's evaluated
agent files holds its parameters (a niche file holds its best; `agent.npz` the exported one);
otherwise it is evaluated here (`pipeline.snapshots.evaluated_agent` + `epoet.eval.evaluate`, the
record's evaluate config, 5 episodes per terrain). Those evaluations and every selection (its
record and CPU seconds) are cached in --cache, so a second call with more sizes only adds what
is new. Runs in one process.

A size is `T` (T terrains, `selection.episodes` of the config) or `TxE` (T terrains, E episodes).

Examples:

    python bench/selection_size.py --records docs/results/compute/epoet_s1 --sizes 8 16 32 64
    python bench/selection_size.py --suite admitted --records docs/results/levers/*/epoet_s1
    python bench/selection_size.py --records docs/results/levers/*/epoet_s1 --sizes 8 8x2 16
    python bench/selection_size.py --records docs/results/paper-workstation/epoet*_s? --minutes 60
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.mean_success import mean_interval
from epoet.config import compose, load, validate
from epoet.eval.agents import resolve_run
from epoet.eval.evaluate import evaluate
from epoet.eval.keys import ADMITTED_NAME, NAMED_SUITES
from epoet.eval.suite import load_suite
from epoet.open_ended.exported_agent import candidates
from epoet.rollout.agent_files import ES_POLICIES, read_es_policy
from epoet.rollout.selection import CHOICE_FILE, es_held_out
from pipeline.choose import run_overrides, snapshot_niches
from pipeline.snapshots import evaluated_agent, niches_of

PAPER_EPISODES = 5  # pipeline/snapshots.py's protocol: the paper's 5 episodes per terrain


@dataclass
class Snapshot:
    """One CPU-time snapshot of a record: its candidates and their success on the suite."""

    label: str  # e.g. compute/epoet_s1 cpu30
    folder: Path
    names: list[str]
    thetas: np.ndarray
    layer_sizes: tuple[int, ...]
    success: dict[str, float]  # candidate name -> success on the judging suite
    own: str  # the run's own-terrain choice (choice.json)
    recorded: dict[str, Any]  # the record's choice.json


@dataclass(frozen=True)
class Size:
    """A held-out set: `terrains` x `episodes`, rendered at `max_height` (None: the config's)."""

    terrains: int
    episodes: int
    max_height: float | None = None

    @property
    def label(self) -> str:
        at = "" if self.max_height is None else f"@{self.max_height:g}"
        return f"{self.terrains}x{self.episodes}{at}"


@dataclass(frozen=True)
class Pick:
    """One snapshot's choice on one held-out set (or `own`, `oracle`), judged on the suite."""

    choice: str  # a Size's label, `own` or `oracle`
    run: Path  # the record
    success: float  # of the chosen candidate
    oracle: float  # of the snapshot's best candidate
    cpu_s: float = 0.0  # the choice's
    by_rule: dict[str, float] | None = None  # tie-breaking rule -> its pick's success
    tied: bool = False  # the rules pick different candidates


def parse_size(text: str, default_episodes: int) -> Size:
    """`T`, `TxE`, and either with `@S` (terrains at S metres) -> a Size."""
    size, _, height = text.lower().partition("@")
    terrains, _, episodes = size.partition("x")
    return Size(
        int(terrains),
        int(episodes) if episodes else default_episodes,
        float(height) if height else None,
    )


def theta_key(theta: np.ndarray) -> str:
    """A short hash of parameters: a cache entry is for these exact candidates."""
    return hashlib.sha1(np.ascontiguousarray(theta, dtype=np.float64).tobytes()).hexdigest()[:16]


def cached(path: Path, compute) -> dict[str, Any]:
    """`compute()`'s JSON result, stored at `path` the first time."""
    if path.is_file():
        return json.loads(path.read_text())
    result = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1))
    return result


def suite_success(
    record: Path,
    folder: Path,
    name: str,
    theta: np.ndarray,
    evaluated: dict,
    cache: Path,
    suite: str,
) -> float:
    """The candidate's success on `suite`: the record's when an evaluated agent file holds
    `theta`, else evaluated here with the record's protocol (cached)."""
    for stem, success in evaluated.items():
        path = folder / ES_POLICIES / f"{stem}.npz"
        if path.is_file() and np.array_equal(read_es_policy(path)[0], theta):
            return float(success)

    tag = f"{record.parent.name}_{record.name}_{folder.name}_{name.replace('/', '_')}"

    def run() -> dict[str, Any]:
        # The niche's file with `theta` swapped in: its layout, integrator and sizes kept.
        niche = folder / ES_POLICIES / f"{name.split('/')[0]}.npz"
        agent_file = cache / "agents" / f"{tag}.npz"
        agent_file.parent.mkdir(parents=True, exist_ok=True)
        with np.load(niche, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
        np.savez(agent_file, **{**arrays, "theta": theta, "choice": np.array("final")})
        cfg = validate(
            compose([f"run={record}", f"episodes={PAPER_EPISODES}"], config_name="evaluate")
        )
        agent = evaluated_agent(agent_file, folder.name, resolve_run(str(record)))
        started = time.process_time()
        print(f"[{suite}] evaluating {record} {folder.name} {name}", flush=True)
        result = evaluate(agent, load_suite(suite), cfg, None, progress=False)
        success = result.metrics[f"suite/{suite}/success_rate"]
        return {"success": success, "cpu_s": time.process_time() - started}

    return float(cached(cache / suite / f"{tag}_{theta_key(theta)}.json", run)["success"])


def snapshots_of(
    record: Path, cache: Path, suite: str, minutes: list[str] | None = None
) -> list[Snapshot]:
    """The record's snapshots (run.json `snapshots`; those at `minutes` if given), their
    candidates as a run names them."""
    info = json.loads((record / "run.json").read_text())
    found = []
    for mark, entry in info["snapshots"].items():
        if minutes and mark not in minutes:
            continue
        folder = record / f"cpu{mark}"
        names, thetas, _ = candidates(snapshot_niches(folder))
        # agent file stem -> success; a snapshot not evaluated on the suite has every candidate
        # evaluated here
        evaluated = entry["evaluations"].get(suite, {}).get("agents", {})
        success = {
            n: suite_success(record, folder, n, t, evaluated, cache, suite)
            for n, t in zip(names, thetas)
        }
        recorded = json.loads((folder / ES_POLICIES / CHOICE_FILE).read_text())
        found.append(
            Snapshot(
                f"{record.parent.name}/{record.name} cpu{mark}",
                folder,
                names,
                thetas,
                read_es_policy(niches_of(folder)[0])[1],
                success,
                recorded["own"],
                recorded,
            )
        )
    return found


def select(record: Path, cfg: Any, snap: Snapshot, size: Size, cache: Path) -> dict[str, Any]:
    """The held-out choice on this set, by the run's selection code and its config `cfg`
    (the record's command's, as pipeline/choose.py composes it; cached)."""

    def run() -> dict[str, Any]:
        sel = replace(cfg.selection, terrains=size.terrains, episodes=size.episodes)
        if size.max_height is not None:
            sel = replace(sel, max_height=size.max_height)
        started = time.process_time()
        held_out = es_held_out(
            snap.thetas,
            snap.names,
            cfg.agent,
            cfg.terrain,
            sel,
            cfg.seed,
            snap.layer_sizes,
            cfg.workers.batch,
            cfg.budget.score_scale,
        )
        return {**held_out, "cpu_s": time.process_time() - started}

    key = f"{record.parent.name}_{record.name}_{snap.folder.name}_{size.label}"
    print(f"[select] {snap.label} {size.label}", flush=True)
    return cached(cache / "select" / f"{key}_{theta_key(snap.thetas)}.json", run)


TIE_RULES = ("return", "earliest", "latest")
FIELDS = ("success", "oracle", "cpu_s")  # the summary's columns, per pick


def run_mean(group: list[Pick], run: Path) -> float:
    """The mean success of one run's picks (its snapshots) in `group`."""
    return float(np.mean([p.success for p in group if p.run == run]))


def tie_choices(held_out: dict[str, Any]) -> dict[str, str]:
    """The candidate each tie-breaking rule exports among those solving the most held-out
    episodes: the product's (the higher mean return), the earliest and the latest candidate."""
    solved = {name: c["solved"] for name, c in held_out["candidates"].items()}
    top = [name for name, share in solved.items() if share == max(solved.values())]
    return dict(zip(TIE_RULES, (held_out["chosen"], top[0], top[-1])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--records", nargs="+", type=Path, required=True, help="ePOET or ePOET-SAC records"
    )
    parser.add_argument(
        "--sizes",
        nargs="+",
        default=["8", "16", "32", "64"],
        help="T or TxE (terrains x eps), either with @S (at S metres)",
    )
    parser.add_argument("--cache", type=Path, default=Path("/tmp/hsel_cache"))
    parser.add_argument(
        "--suite",
        choices=NAMED_SUITES,
        default=ADMITTED_NAME,
        help="the suite that judges each choice (default: the validation suite)",
    )
    parser.add_argument(
        "--minutes", nargs="+", help="only the snapshots at these CPU minutes (default: all)"
    )
    args = parser.parse_args()

    default_episodes = load().selection.episodes
    sizes = [parse_size(s, default_episodes) for s in args.sizes]
    picks: list[Pick] = []
    detail = []
    started = time.process_time()
    for record in args.records:
        cfg = load(run_overrides(json.loads((record / "run.json").read_text())["command"]))
        for snap in snapshots_of(record, args.cache, args.suite, args.minutes):
            best = max(snap.success.values())
            line = [snap.label, f"{len(snap.names)}", f"{100 * best:5.1f}"]
            line.append(f"{snap.own}={100 * snap.success[snap.own]:.1f}")
            picks.append(Pick("own", record, snap.success[snap.own], best))
            picks.append(Pick("oracle", record, best, best))
            ran = snap.recorded["selection"]  # the set the run itself chose on
            for size in sizes:
                chosen = select(record, cfg, snap, size, args.cache)
                name = chosen["chosen"]
                by_rule = tie_choices(chosen)
                picks.append(
                    Pick(
                        size.label,
                        record,
                        snap.success[name],
                        best,
                        chosen["cpu_s"],
                        {rule: snap.success[pick] for rule, pick in by_rule.items()},
                        len(set(by_rule.values())) > 1,
                    )
                )
                line.append(f"{name}={100 * snap.success[name]:.1f}")
                same_set = (size.terrains, size.episodes) == (ran["terrains"], ran["episodes"])
                if (
                    same_set
                    and size.max_height in (None, ran["max_height"])
                    and name != snap.recorded["validation"]
                ):
                    line[-1] += "(!=record)"
            detail.append(line)
    by_choice: dict[str, list[Pick]] = {}
    for pick in picks:
        by_choice.setdefault(pick.choice, []).append(pick)

    head = ["snapshot", "K", "oracle", "own", *(size.label for size in sizes)]
    print(
        f"\nPer snapshot on {args.suite}: candidates K, oracle success %, each choice=its success %"
    )
    print(" | ".join(head))
    for line in detail:
        print(" | ".join(line))

    n = len(detail)
    print(f"\nSummary over {n} snapshots (suite {args.suite}: 32 terrains x 5 episodes)")
    print(
        f"{'choice':>8} {'mean success %':>15} {'picks oracle':>13} {'mean regret pts':>16} "
        f"{'CPU s/snapshot':>15} {'CPU s total':>12}"
    )
    for label, group in by_choice.items():
        picked, oracle, cpu = (np.array([getattr(p, f) for p in group]) for f in FIELDS)
        print(
            f"{label:>8} {100 * picked.mean():15.1f} "
            f"{f'{int(np.isclose(picked, oracle).sum())}/{n}':>13} "
            f"{100 * (oracle - picked).mean():16.2f} {cpu.mean():15.1f} {cpu.sum():12.1f}"
        )
    first, *others = (size.label for size in sizes)
    if len(args.records) > 1:
        print(f"\nPer run (the mean over its snapshots), each size - {first}: mean [95 % t], pts")
        for label in others:
            diffs = [
                100 * (run_mean(by_choice[label], run) - run_mean(by_choice[first], run))
                for run in args.records
            ]
            mean, low, high = mean_interval(diffs)
            print(f"{label:>8} {mean:+5.1f} [{low:+.1f}, {high:+.1f}] over {len(diffs)} runs")
    print("\nTie-breaking: snapshots whose top candidates tie on solved share and pick")
    print("differently, and the mean success % each rule's choice gives over all snapshots")
    print(f"{'choice':>8} {'tied':>6} " + " ".join(f"{rule:>9}" for rule in TIE_RULES))
    for label in (size.label for size in sizes):
        group = by_choice[label]
        tied = sum(p.tied for p in group)
        means = [100 * np.mean([p.by_rule[rule] for p in group if p.by_rule]) for rule in TIE_RULES]
        print(f"{label:>8} {f'{tied}/{n}':>6} " + " ".join(f"{m:9.1f}" for m in means))
    print(f"\n(this call's CPU: {time.process_time() - started:.0f} s; cached work not redone)")


if __name__ == "__main__":
    main()
