"""`python -m pipeline.snapshots --runs <run folder>... --out docs/results/<name>`: success against
compute. Every CPU-time snapshot of each run (`<run folder>/snapshots/cpu<minutes>/`, written
at the marks of `snapshot_cpu_minutes` while it trains) is evaluated on the suites with the
paper's protocol (5 episodes per terrain; solved = finish line and return >= 2000), every agent
of it: an ePOET pool's every niche agent, a baseline's one policy (`--exported-only`: the agent
the snapshot exported, what the tables read). The results go to records
that outlive the machine (docs/results/README.md, "Success against compute"):

    <out>/<algo>_s<seed>/run.json        the run (command, commits, CPU and wall time, load) and,
                                         per snapshot and suite, the best agent's and the niche
                                         mean's success
    <out>/<algo>_s<seed>/curves.csv      its learning curves, one row per logged step
    <out>/<algo>_s<seed>/config.yaml     its resolved config
    <out>/<algo>_s<seed>/cpu<m>/         the snapshot's agent files and snapshot.json, and
                                         <agent>/<suite>/{summary.json,episodes.csv}
    <out>/<algo>_s<seed>/<suite>/, policies/ or policy.pt: the latest snapshot's best agent's
                                         evaluation and agents, so `make tables RECORDS=<out>`
                                         and `run=<out>/<record>` read it as any record

A run still training is fine: what its snapshots hold so far is evaluated, and a second call
evaluates only what is new (each evaluation is written atomically and never repeated), so the
command is run again as snapshots arrive. The run's best agent of a snapshot is the pool's
agent with the best score on its own environment, the one `evaluate run=<run folder>` picks.

Examples:

    python -m pipeline.snapshots --runs runs/epoet_s1 runs/ppo_s1 --out docs/results/compute
    python -m pipeline.snapshots --runs outputs/<date>/<run> --out /tmp/records --suites paper
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd
import yaml
from mlflow import MlflowClient

from analysis.joins import JOIN_KEYS
from analysis.records import EPISODES, RUN_FILE, SUMMARY, trained_record
from analysis.store import AnalysisError, connect, run_command
from epoet.core.algorithm import SCORE_METRICS
from epoet.core.checkpoint import CheckpointError, load_checkpoint
from epoet.core.files import atomic_write
from epoet.core.help import HelpParser
from epoet.driver import SNAPSHOT_INFO, SNAPSHOTS
from epoet.eval.agents import RECORD_CONFIG, TrainedRun, policy_in, resolve_run
from epoet.eval.config import EvaluateConfig
from epoet.eval.episodes import evaluation_pool
from epoet.eval.evaluate import evaluate, write_results
from epoet.eval.keys import PAPER_NAME, SHIPPED_NAME
from epoet.eval.suite import Suite, load_suite
from epoet.rollout.agent_files import ES_POLICIES, EXPORTED_AGENT, LAST_POLICY, TORCH_POLICY
from epoet.rollout.selection import CHOICE_FILE, LAST
from epoet.tracking.provenance import git_commit
from pipeline.records import write_json
from pipeline.run_header import command_of, load_of, overrides_command, run_header

CURVES = "curves.csv"
# What a learning curve holds: what every algorithm logs (the metrics contract,
# epoet/core/algorithm.py: the score, the best so far, the three axes), then the pool and S, and
# what ePOET-SAC's joins did (analysis.joins).
CURVE_KEYS = (*SCORE_METRICS, "annecs", "active_envs", "max_height", *JOIN_KEYS)


def niches_of(snapshot: Path) -> list[Path]:
    """A pool's niche agents, in admission order (none for a baseline)."""
    return sorted((snapshot / ES_POLICIES).glob("env*.npz"), key=lambda p: int(p.stem[3:]))


def agents_of(snapshot: Path) -> list[Path]:
    """A snapshot's agent files: a pool's every niche agent and the one the run exported (when
    it chose one: `selection`), or a baseline's exported policy and its last where they differ."""
    exported = snapshot / ES_POLICIES / EXPORTED_AGENT
    pool = niches_of(snapshot) + ([exported] if exported.is_file() else [])
    last = snapshot / LAST_POLICY
    return pool or [snapshot / TORCH_POLICY, *([last] if last.is_file() else [])]


def choice_of(snapshot: Path) -> Path | None:
    """The snapshot's choice record (a pool's beside its agents, a baseline's beside its
    policy); None for a run from before runs chose their agent."""
    found = [p for p in (snapshot / ES_POLICIES, snapshot) if (p / CHOICE_FILE).is_file()]
    return found[0] / CHOICE_FILE if found else None


def files_of(snapshot: Path) -> list[Path]:
    """What a record keeps of a snapshot's agents: their files and the run's choice record."""
    choice = choice_of(snapshot)
    return agents_of(snapshot) + ([choice] if choice else [])


def own_choice(snapshot: Path) -> str | None:
    """The agent file (its stem) the run's own rule picks: a pool's best score on its own
    terrain, a baseline's last policy; None for a baseline from before the choice."""
    choice = choice_of(snapshot)
    if choice is not None:
        own = str(json.loads(choice.read_text())["own"])
        if own == LAST:
            return Path(LAST_POLICY).stem if (snapshot / LAST_POLICY).is_file() else "policy"
        return own.split("/")[0]
    found = policy_in(snapshot)
    return found[1] if found and found[0].kind == "es" else None


def snapshots_of(run_dir: Path) -> list[tuple[float, Path]]:
    """(CPU minutes, folder) of each complete snapshot, in order."""
    found = []
    for info in (run_dir / SNAPSHOTS).glob(f"*/{SNAPSHOT_INFO}"):
        found.append((float(json.loads(info.read_text())["cpu_minutes"]), info.parent))
    return sorted(found)


def evaluated_agent(path: Path, snapshot: str, trained: TrainedRun) -> TrainedRun:
    """The agent file as its run's agent: the run's episode rules and score scale."""
    return TrainedRun(
        resolve_run(str(path)).agent,
        f"{trained.algo}-s{trained.seed} {snapshot} {path.stem}",
        None,
        trained.algo,
        trained.seed,
        trained.config,
        None,
    )


def evaluate_snapshot(
    snapshot: Path,
    record: Path,
    trained: TrainedRun,
    suites: Sequence[Suite],
    cfg: EvaluateConfig,
    pool: Any,
    exported_only: bool = False,
) -> dict[str, Any]:
    """Every agent of the snapshot (`exported_only`: the one the run exported) on every suite
    (those not evaluated before), its files copied into the record; returns the snapshot's
    entry of run.json (the niches' mean only where every niche was evaluated)."""
    target = record / snapshot.name
    for path in [*files_of(snapshot), snapshot / SNAPSHOT_INFO]:
        copy = target / path.relative_to(snapshot)
        if not copy.exists():
            with atomic_write(copy) as file:
                file.write(path.read_bytes())
    info = json.loads((snapshot / SNAPSHOT_INFO).read_text())
    best, _ = policy_in(snapshot) or (None, None)
    assert best is not None  # a snapshot holds its agents (take_snapshots writes them first)
    own = own_choice(snapshot)
    choice = choice_of(snapshot)
    entry: dict[str, Any] = {
        **info,
        "best_agent": best.path.stem,
        **({"own_agent": own} if own else {}),
        **({"choice": json.loads(choice.read_text())} if choice else {}),
        "evaluations": {},
    }
    for suite in suites:
        rates = {}
        for path in [best.path] if exported_only else agents_of(snapshot):
            out = target / path.stem / suite.name
            if not (out / SUMMARY).is_file():
                agent = evaluated_agent(path, snapshot.name, trained)
                print(f"[snapshots] {agent.label} at {snapshot.name} on {suite.name}", flush=True)
                result = evaluate(agent, suite, cfg, pool, progress=False)
                write_results(
                    result,
                    out,
                    {
                        "label": agent.label,
                        "algo": trained.algo,
                        "seed": trained.seed,
                        "suite_name": suite.name,
                        "suite_fingerprint": suite.fingerprint,
                        "course_scale": suite.course.scale(agent.agent_config(cfg.agent)),
                        "episodes_per_terrain": cfg.episodes,
                        "eval_seed": cfg.seed,
                        "commit": git_commit(),
                    },
                )
                (out / "actions.npz").unlink()  # the t-SNE samples: not kept in records
            rates[path.stem] = json.loads((out / SUMMARY).read_text())
        pool_rates = [rates[p.stem] for p in niches_of(snapshot) if p.stem in rates]
        niches = pool_rates if len(pool_rates) == len(niches_of(snapshot)) else []
        niches = niches or ([] if exported_only else list(rates.values()))
        key = f"suite/{suite.name}/success_rate"
        entry["evaluations"][suite.name] = {
            "fingerprint": suite.fingerprint,
            "course_scale": rates[best.path.stem]["course_scale"],
            "episodes_per_terrain": cfg.episodes,
            "commit": rates[best.path.stem].get("commit"),
            "success_rate": rates[best.path.stem][key],  # the exported agent's
            **({"success_rate_own": rates[own][key]} if own and own in rates else {}),
            **({"success_rate_mean": sum(s[key] for s in niches) / len(niches)} if niches else {}),
            "agents": {name: s[key] for name, s in rates.items()},
        }
    return entry


def curves_of(client: MlflowClient, run_id: str) -> pd.DataFrame:
    """One row per logged step (an iteration, or a collector batch and evaluation) with every
    curve key logged at it."""
    columns = {}
    for key in CURVE_KEYS:
        points = client.get_metric_history(run_id, key)
        if points:
            columns[key] = pd.Series({p.step: p.value for p in points})
    table = pd.DataFrame(columns).sort_index()
    table.index.name = "step"
    return table


def suites_on_disk(record: Path) -> set[str]:
    """The record's top-level evaluation folders (<suite>/summary.json)."""
    return {p.parent.name for p in record.glob(f"*/{SUMMARY}")}


def checkpoint_of(run_dir: Path) -> dict[str, Any]:
    try:
        return load_checkpoint(run_dir)
    except CheckpointError as err:
        raise AnalysisError(f"{run_dir} is not a run folder with a checkpoint: {err}") from None


def promote_latest(record: Path, snapshots: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Make the latest snapshot's exported agent stand for the record (its agent files and
    evaluations at the record's top level, an earlier snapshot's removed); returns run.json's
    `evaluations`."""
    evaluations: dict[str, Any] = {}
    if snapshots:
        last = list(snapshots.values())[-1]
        folder = record / f"cpu{last['cpu_minutes']:g}"
        shutil.rmtree(record / ES_POLICIES, ignore_errors=True)  # an earlier snapshot's pool
        for path in files_of(folder):
            with atomic_write(record / path.relative_to(folder)) as file:
                file.write(path.read_bytes())
        for suite, entry in last["evaluations"].items():
            for name in (SUMMARY, EPISODES):
                with atomic_write(record / suite / name) as file:
                    file.write((folder / last["best_agent"] / suite / name).read_bytes())
            evaluations[suite] = {
                **{k: entry[k] for k in ("fingerprint", "course_scale", "episodes_per_terrain")},
                "success_rate": entry["success_rate"],
                "commit": entry["commit"],
                "snapshot": f"cpu{last['cpu_minutes']:g}",
            }
    for stale in suites_on_disk(record) - evaluations.keys():  # an earlier snapshot's
        shutil.rmtree(record / stale)
    return evaluations


def record_snapshots(
    run_dir: Path,
    out: Path,
    suites: Sequence[Suite],
    cfg: EvaluateConfig,
    pool: Any,
    tracking_uri: str | None = None,
    exported_only: bool = False,
) -> Path:
    """The run's record, its new snapshots evaluated (`exported_only`: only the agent each
    snapshot exported, not a pool's every niche); run.json written last. The run's MLflow
    store: `tracking_uri`, else the one its config names, else epoet's default."""
    state = checkpoint_of(run_dir)
    config = state["config"]
    uri = tracking_uri or config["tracking"]["uri"]
    trained = resolve_run(str(run_dir), uri)
    record = out / trained_record(state["algo"], config["seed"])
    snapshots = {
        f"{minutes:g}": evaluate_snapshot(folder, record, trained, suites, cfg, pool, exported_only)
        for minutes, folder in snapshots_of(run_dir)
    }
    if (record / RUN_FILE).is_file():  # suites evaluated by an earlier call stay listed
        earlier = json.loads((record / RUN_FILE).read_text()).get("snapshots", {})
        for minutes, entry in snapshots.items():
            kept = earlier.get(minutes, {}).get("evaluations", {})
            entry["evaluations"] = {**kept, **entry["evaluations"]}
    client, uri = connect(uri)
    run = client.get_run(state["run_id"])
    with atomic_write(record / CURVES) as file:
        file.write(curves_of(client, state["run_id"]).to_csv().encode())
    with atomic_write(record / RECORD_CONFIG) as file:
        file.write(yaml.safe_dump(config, sort_keys=False).encode())
    evaluations = promote_latest(record, snapshots)
    # the run folder's own overrides, else its sweep job's or its params' (run_header)
    command = overrides_command(run_dir)
    header = run_header(
        client,
        run,
        record.name,
        uri,
        {"command": command, "command_source": "overrides"} if command else command_of(client, run),
        status=True,  # a run still training is recorded as far as it got
    )
    pool = state.get("open_ended")
    loop = state.get("loop", {})
    write_json(
        record / RUN_FILE,
        {
            **header,
            "training": {
                "cpu_time_s": pool["cpu_time"] if pool else loop.get("cpu_time"),
                "wall_time_s": pool["elapsed"] if pool else loop.get("wall_time"),
                "env_steps": pool["env_steps"] if pool else loop.get("frames"),
                **({"iterations": pool["iteration"]} if pool else {"frames": loop.get("frames")}),
                "workers": config["workers"]["num"],
                "stop_reason": run.data.tags.get("stop_reason"),
            },
            "load": load_of(client, run),
            "snapshots": snapshots,
            "evaluations": evaluations,
        },
    )
    return record


def add_evaluation_arguments(parser: HelpParser) -> None:
    """How records evaluate agents: the suites, episodes per terrain, processes."""
    parser.add_argument(
        "--suites",
        default=f"{PAPER_NAME},{SHIPPED_NAME}",
        help="suites (names or folders), comma-separated",
    )
    parser.add_argument(
        "--episodes", type=int, default=5, help="episodes per terrain and agent (the paper's 5)"
    )
    parser.add_argument("--processes", type=int, default=1, help="evaluation processes (default 1)")


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m pipeline.snapshots", __doc__)
    parser.add_argument(
        "--runs", nargs="+", type=Path, required=True, help="run folders, training or finished"
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="records folder, e.g. docs/results/compute"
    )
    add_evaluation_arguments(parser)
    parser.add_argument(
        "--exported-only",
        action="store_true",
        help="evaluate only the agent each snapshot exported (the tables' reading), not every "
        "niche agent of a pool",
    )
    parser.add_argument(
        "--tracking-uri",
        default=None,
        help="the runs' MLflow store (None: their config's, else MLFLOW_TRACKING_URI, else "
        "epoet's)",
    )
    args = parser.parse_args(argv)

    def export() -> None:
        for run_dir in args.runs:  # every folder checked before any evaluation
            checkpoint_of(run_dir)
        from epoet.config import compose, validate

        suites = [load_suite(name) for name in args.suites.split(",")]
        with evaluation_pool(args.processes) as pool:
            for run_dir in args.runs:
                overrides = [f"run={run_dir}", f"episodes={args.episodes}"]
                cfg = validate(compose(overrides, config_name="evaluate"))
                record = record_snapshots(
                    run_dir, args.out, suites, cfg, pool, args.tracking_uri, args.exported_only
                )
                print(f"[snapshots] {run_dir} -> {record}", flush=True)

    return run_command(export)


if __name__ == "__main__":
    raise SystemExit(main())
