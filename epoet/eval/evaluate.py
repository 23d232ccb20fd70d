"""`python -m epoet.eval.evaluate run=<run folder | policy file | MLflow run id | runs:/<id>/agent | reference:<run>/<agent>> [episodes=5]
[suite=<shipped | paper | folder>]`: a trained agent on an evaluation suite (paper Section 4).

Every terrain of the suite is run `episodes` times (the paper: 32 x 5 = 160 episodes), each from
a start keyed by (seed, terrain, episode), so two agents meet the same starts. The agent runs
with the episode rules it was trained with (its run's agent config: integrator, reward) on the
suite's course: its start and finish line, and episodes `episode_ratio` x the run's training
episodes (the reference's 5000 steps for the paper's 2000). "Solved" means the paper's: the
finish line reached with a return of at least `solve_score` x the run's budget score scale.

Results are keyed by the suite's name (`epoet.eval.suite`: "shipped", the default, "paper", or a
folder's name), so one run evaluated on several suites keeps each suite's results. Writes to the
results folder (`out`, default `<run folder>/evaluation/<name>`, or `evaluation/<label>/<name>`
for an MLflow run or a policy file):
- `episodes.csv`: one row per episode (terrain, level, roughness, episode, start_seed, return,
  finished, solved, forward_distance, length, path_roughness);
- `actions.npz`: `action_samples` evenly spaced actions of every episode (`row` = the CSV row,
  `step`, `action`), for the t-SNE figure;
- `summary.json`: the metrics below, the suite's name (`suite_name`), folder and fingerprint.
and, for an MLflow run, logs the three as artifacts under `evaluation/<name>/` and the metrics
(step 0) `suite/<name>/success_rate`, `suite/<name>/success_rate_<level>`,
`suite/<name>/return_mean`, `suite/<name>/forward_distance_mean`, `suite/<name>/finish_rate`,
with the tags `eval_suite/<name>` (the suite's fingerprint), `eval_course_scale/<name>` and
`eval_episodes/<name>` (`epoet.eval.keys`). A metric point the run already holds (same key,
step and value: an evaluation interrupted after logging and run again on resume) is not logged
twice.

Examples:

    python -m epoet.eval.evaluate run=outputs/2026-11-25/10-00-00_epoet_s0
    python -m epoet.eval.evaluate run=<MLflow run id> suite=paper episodes=1
    python -m epoet.eval.evaluate run=reference:poet_hexA8/flat out=results/authors_flat
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from concurrent.futures import Executor, as_completed
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm import tqdm

from epoet.cli import KeyValueCommand
from epoet.core.cli import fail
from epoet.core.cores import default_workers
from epoet.core.files import atomic_write, savez
from epoet.core.schema import ConfigError
from epoet.eval.agents import AgentError, TrainedRun, resolve_run
from epoet.eval.config import EvaluateConfig
from epoet.eval.episodes import COLUMNS, Task, episode_seeds, evaluation_pool, run_task
from epoet.eval.keys import (
    EPISODES_TAG,
    RESULTS,
    SCALE_TAG,
    SHIPPED_NAME,
    SUITE_TAG,
    artifacts,
    metric,
    suite_argument,
    tag,
)
from epoet.eval.reference.files import configure
from epoet.eval.suite import (
    LEVELS,
    Suite,
    SuiteError,
    example_terrain,
    load_suite,
    terrain_config_for,
)
from epoet.run_state import close_if_killed
from epoet.tracking import TrackingError

COMMAND = KeyValueCommand("evaluate", __doc__, EvaluateConfig)


@dataclass
class Evaluation:
    episodes: pd.DataFrame
    actions: dict[str, np.ndarray]  # row, step, action
    metrics: dict[str, float]  # keyed by the suite's name: suite/<name>/...
    suite: Suite


def summarize(episodes: pd.DataFrame, suite: str) -> dict[str, float]:
    """Success rate overall and per level (levels without terrains are left out), means; keyed
    by the suite's name."""
    metrics = {
        metric(suite, "success_rate"): float(episodes.solved.mean()),
        metric(suite, "return_mean"): float(episodes["return"].mean()),
        metric(suite, "forward_distance_mean"): float(episodes.forward_distance.mean()),
        metric(suite, "finish_rate"): float(episodes.finished.mean()),
    }
    for level in LEVELS:
        rows = episodes[episodes.level == level]
        if len(rows):
            metrics[metric(suite, f"success_rate_{level}")] = float(rows.solved.mean())
    return metrics


def evaluate(
    run: TrainedRun, suite: Suite, cfg: EvaluateConfig, pool: Executor | None, progress: bool = True
) -> Evaluation:
    """Every terrain's episodes, in parallel over `pool`'s processes (None: in this process)."""
    agent_cfg = suite.course.rules(run.agent_config(cfg.agent))
    terrain_cfg = terrain_config_for(suite.terrains)
    tasks = [
        Task(
            k,
            terrain,
            run.agent,
            agent_cfg,
            terrain_cfg,
            episode_seeds(cfg.seed, k, cfg.episodes),
            cfg.solve_score * run.score_scale,
            cfg.action_samples,
        )
        for k, terrain in enumerate(suite.terrains)
    ]
    results: dict[int, tuple[list, list, list]] = {}
    done: Iterable = (
        map(run_task, tasks)
        if pool is None
        else (f.result() for f in as_completed([pool.submit(run_task, t) for t in tasks]))
    )
    with tqdm(
        total=len(tasks) * cfg.episodes,
        unit="episode",
        file=sys.stdout,
        desc=f"evaluate {run.label}",
        disable=not progress,
    ) as bar:
        for index, rows, samples, broken in done:
            results[index] = (rows, samples, broken)
            bar.update(len(rows))
    broken = [note for k in sorted(results) for note in results[k][2]]
    if broken:  # one line, however many episodes
        print(
            f"warning: {run.label} acted non-finite (NaN or inf) in {len(broken)} episodes, "
            f"each recorded as failed (first: {broken[0]})",
            file=sys.stderr,
            flush=True,
        )
    rows = [row for k in sorted(results) for row in results[k][0]]
    samples = [s for k in sorted(results) for s in results[k][1]]
    episodes = pd.DataFrame(rows, columns=COLUMNS)
    actions = {
        "row": np.concatenate([np.full(len(s), i) for i, s in enumerate(samples)]),
        "step": np.concatenate([np.arange(len(s)) for s in samples]),
        "action": np.concatenate(samples).astype(np.float32),
    }
    return Evaluation(episodes, actions, summarize(episodes, suite.name), suite)


def write_results(result: Evaluation, folder: Path, info: dict[str, Any]) -> dict[str, Path]:
    """episodes.csv, actions.npz and summary.json, each written atomically."""
    paths = {name: folder / name for name in ("episodes.csv", "actions.npz", "summary.json")}
    with atomic_write(paths["episodes.csv"]) as f:
        f.write(result.episodes.to_csv(index=False).encode())
    with atomic_write(paths["actions.npz"]) as f:
        savez(f, result.actions)
    with atomic_write(paths["summary.json"]) as f:
        f.write((json.dumps({**info, **result.metrics}, indent=1) + "\n").encode())
    return paths


def results_folder(cfg: EvaluateConfig, run: TrainedRun, suite: Suite) -> Path:
    if cfg.out:
        return Path(cfg.out)
    if run.folder is not None:
        return run.folder / RESULTS / suite.name
    label = "".join(c if c.isalnum() or c in "-_." else "_" for c in run.label)
    return Path(RESULTS) / label / suite.name


def evaluate_run(
    cfg: EvaluateConfig, progress: bool = True, pool: Executor | None = None
) -> tuple[Evaluation, Path, TrainedRun]:
    """Resolve, check, evaluate, write and log: the whole command, for `make paper` too;
    returns the evaluation, its results folder and the agent's run. Episodes run on `pool`
    (`evaluation_pool`), or on a pool of `cfg.processes` opened for this evaluation."""
    assert cfg.run is not None  # required: AgentCommandConfig checks it
    configure(cfg.epoet_3d)
    suite = load_suite(cfg.suite)  # before the run: resolving an authors' agent writes the store
    run = resolve_run(cfg.run, cfg.tracking.uri)
    folder = results_folder(cfg, run, suite)
    workers = cfg.processes or default_workers()  # `pool`'s, when given (one config made both)
    rules = suite.course.rules(run.agent_config(cfg.agent))
    print(
        f"evaluating {run.label} on {len(suite.terrains)} terrains x {cfg.episodes} "
        f"episodes of suite {suite.name} ({suite.folder}), {workers} processes; course "
        f"{rules.finish_x - rules.start_x:.2f} m in at most {rules.max_episode_steps} steps; "
        f"the {rules.name} with the {rules.integrator} integrator"
        f"\n  writing to {folder.absolute()}/{'' if cfg.out else ' (out=<folder> to choose)'}",
        flush=True,
    )
    scale = suite.course.scale(run.agent_config(cfg.agent))
    with nullcontext(pool) if pool is not None else evaluation_pool(workers) as pool:
        result = evaluate(run, suite, cfg, pool, progress)
    info = {
        "label": run.label,
        "run_id": run.run_id,
        "algo": run.algo,
        "seed": run.seed,
        "suite_name": suite.name,
        "suite": str(suite.folder),
        "suite_fingerprint": suite.fingerprint,
        "course_scale": scale,
        "episodes_per_terrain": cfg.episodes,
        "eval_seed": cfg.seed,
    }
    paths = write_results(result, folder, info)
    if Path(cfg.run).is_dir():  # a run folder: its run, if its process was killed, is closed
        close_if_killed(Path(cfg.run))
    if run.stored is not None:
        run.stored.log_results(
            result.metrics,
            tags={
                tag(SUITE_TAG, suite.name): suite.fingerprint,
                tag(SCALE_TAG, suite.name): f"{scale:g}",
                tag(EPISODES_TAG, suite.name): str(cfg.episodes),
            },
            artifacts={path: artifacts(suite.name) for path in paths.values()},
        )
    return result, folder, run


def main(argv: list[str] | None = None) -> None:
    """CLI: bad input (config, run, suite, store) ends in one line and exit code 2."""
    cfg: EvaluateConfig = COMMAND.parse(argv)
    try:
        result, folder, run = evaluate_run(cfg)
    except (ConfigError, AgentError, SuiteError, TrackingError, OSError) as err:
        fail(err)
    m, suite = result.metrics, result.suite
    levels = ", ".join(
        f"{level} {m[key]:.0%}"
        for level in LEVELS
        if (key := metric(suite.name, f"success_rate_{level}")) in m
    )
    print(
        f"suite {suite.name}: success rate {m[metric(suite.name, 'success_rate')]:.1%} "
        f"({levels}); mean return {m[metric(suite.name, 'return_mean')]:.1f}; mean forward "
        f"distance {m[metric(suite.name, 'forward_distance_mean')]:.2f} m"
    )
    print(f"  results:  {folder.absolute()}/ (episodes.csv, actions.npz, summary.json)")
    if run.stored is not None:
        print(f"  logged to MLflow run {run.run_id} under {artifacts(suite.name)}/")
        print(f"  runs:     {run.stored.ui_hint()}")
    where = (
        "" if suite.name == SHIPPED_NAME else f" suite={suite_argument(suite.name, suite.folder)}"
    )
    print(
        f"  render:   python -m epoet.eval.render run={cfg.run} "
        f"terrain={example_terrain(suite=suite)}{where}"
    )


if __name__ == "__main__":
    main()
