"""One Hydra job: validate the config, open the tracker, run the algorithm's runner.

Data flow is one way: config -> components -> runner -> tracker. Everything that can fail on bad
input (config ranges, an unsupported combination, the tracking store, the checkpoint to resume)
fails here, in one sentence, before any long work starts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from omegaconf import DictConfig, OmegaConf

from epoet.config import Config, compose, validate
from epoet.core.algorithm import ELAPSED
from epoet.core.checkpoint import CHECKPOINT_NAME, CheckpointError, find_checkpoint, load_checkpoint
from epoet.core.cores import default_workers
from epoet.core.lifecycle import StopOnSignal
from epoet.envs.spaces import robot_sizes
from epoet.eval.reference.files import configure
from epoet.migration import RESUMABLE, config_changes
from epoet.registry import algorithm
from epoet.run_state import (
    DONE,
    LIVE,
    close_killed_run,
    extends_budget,
    finished_limits,
    mark_done,
    mark_live,
    orphaned_run,
    process_tags,
)

if TYPE_CHECKING:
    from epoet.tracking import MlflowTracker, StoredRun

# resume=auto: continue this run folder's checkpoint if any; skip it if DONE, unless the budget
# asked for is larger than the one it finished on
AUTO = "auto"


def run_params(cfg: Config, resolved: dict[str, Any], tracking_uri: str) -> dict[str, str]:
    """The run's MLflow params: the values it runs with (the worker count and store the defaults
    resolve to), without the settings it never reads (`Config.unused_keys`) and without `resume`
    and `check` (where a run continues and whether it runs, not settings of it)."""
    from epoet.tracking import flatten

    params = flatten({k: v for k, v in resolved.items() if k not in ("resume", "check")})
    unused = cfg.unused_keys()
    params = {
        k: v for k, v in params.items() if not any(k == u or k.startswith(f"{u}.") for u in unused)
    }
    params["tracking.uri"] = tracking_uri
    if cfg.workers.num is None and cfg.workers.address is None:
        # one worker (ES) or torch thread (baselines) per core; a Ray cluster brings its own
        params["workers.num"] = str(default_workers())
    return params


@dataclass(frozen=True)
class Prepared:
    """A run that passed every check a run makes before any work: its validated config and the
    checkpoint it continues (`resume`: its state, from `resume_path`), if any."""

    cfg: Config
    resume: dict[str, Any] | None = None
    resume_path: Path | None = None


def prepare(raw: DictConfig, run_dir: Path) -> Prepared | None:
    """Validate a run as it would start in `run_dir`: the config's ranges and combinations,
    the checkpoint to resume (its algorithm and config), a Ray address, the algorithm's inputs.
    and, last (it imports mlflow), the tracking store. Raises ConfigError, CheckpointError or
    TrackingError in one sentence; None: `resume=auto` finds `run_dir` finished (DONE) and the
    budget no larger. Writes nothing (a new sqlite store is not made yet), so `check=true` calls
    it too."""
    cfg: Config = validate(raw)
    configure(cfg.epoet_3d)
    from epoet.envs.mjcf import robot_spec  # imports MuJoCo

    robot_spec(cfg.agent)  # the robot's MJCF fits its config (ConfigError otherwise)
    resume = None
    resume_from: str | Path | None = cfg.resume
    path = None
    if resume_from == AUTO:
        # `make paper` calls the same sweep again after an interruption: finished jobs are
        # skipped, interrupted ones continue from their checkpoint, the rest start. A finished
        # job given a larger budget continues (its checkpoint is its final state).
        checkpointed = (run_dir / CHECKPOINT_NAME).is_file()
        limits = finished_limits(run_dir)
        if limits is not None and not checkpointed:
            raise CheckpointError(
                f"{run_dir} is marked finished ({DONE}) but holds no {CHECKPOINT_NAME}: there is "
                f"nothing to continue; remove {run_dir / DONE} to train there again."
            )
        if limits is not None and not extends_budget(limits, cfg.budget):
            return None
        resume_from = run_dir if checkpointed else None
    if resume_from:
        path = find_checkpoint(resume_from)
        resume = load_checkpoint(path)
        if resume.get("algo") != cfg.algo.name:
            raise CheckpointError(
                f"checkpoint {path} is from algo={resume.get('algo')}, so it "
                f"cannot resume algo={cfg.algo.name}."
            )
        changed = config_changes(resume["config"], dataclasses.asdict(cfg), cfg.unused_keys())
        if changed:
            raise CheckpointError(
                f"checkpoint {path} was made with a different config ({', '.join(changed)}); "
                f"repeat the run's overrides (only {', '.join(RESUMABLE)} may change)."
            )
    if cfg.workers.address is not None:
        # the optional extra, on demand
        from epoet.rollout.backends.ray_cluster import check_address

        check_address(cfg.workers.address)
    orphaned_run(run_dir)  # another process training in this folder stops this one here
    if resume is None:
        cfg.algo.check_inputs(cfg)  # e.g. ePOET-SAC's `algo.sac_init`
    from epoet.tracking import check_store

    check_store(cfg.tracking.uri)
    return Prepared(cfg, resume, path)


def check(raw: DictConfig, run_dir: Path) -> str:
    """`check=true`: the checks of `prepare` and of the tracking store, and the one line that
    says what the run would do; nothing is written (no folder, no MLflow run or store)."""
    from epoet.tracking import check_store

    prepared = prepare(raw, run_dir)
    cfg: Config = prepared.cfg if prepared else validate(raw)
    uri = check_store(cfg.tracking.uri)  # prepare checked it, unless the run is DONE
    what = (
        f"{run_dir} already finished: a run would skip it"
        if prepared is None
        else f"would resume {prepared.resume_path}"
        if prepared.resume_path
        else f"would start a new run in {run_dir}"
    )
    return (
        f"[epoet] config OK: algo={cfg.algo.name} seed={cfg.seed} budget={cfg.budget.name} "
        f"terrain={cfg.terrain.kind} workers={cfg.workers.backend}; {what}, tracked in {uri} "
        f"(experiment {cfg.tracking.experiment})"
    )


def run(raw: DictConfig, run_dir: Path, prepared: Prepared | None = None) -> Any:
    """Train the configured algorithm (`prepared`: what `prepare` gave for it, if called
    already); returns the runner's final state (None when `resume=auto` finds the run folder
    already finished)."""
    prepared = prepared or prepare(raw, run_dir)
    if prepared is None:
        cfg: Config = validate(raw)
        print(
            f"[epoet] {cfg.algo.name} seed={cfg.seed}: {run_dir} already finished; skipped (a larger budget continues it)",
            flush=True,
        )
        return None
    cfg, resume = prepared.cfg, prepared.resume
    # Only now mlflow (a slow import): bad input above fails without waiting for it.
    from epoet.tracking import StoredRun, parent_run_id

    run_dir.mkdir(parents=True, exist_ok=True)
    # A finished run being continued is not finished until it ends again: an interruption now
    # must leave it for `resume=auto` to continue, not to skip.
    (run_dir / DONE).unlink(missing_ok=True)
    tags = {
        "algo": cfg.algo.name,
        "terrain": cfg.terrain.kind,
        "agent": cfg.agent.name,
        "seed": str(cfg.seed),
        "budget": cfg.budget.name,
        **process_tags(),
    }
    close_killed_run(run_dir, (resume or {}).get("run_id"))  # a run killed here before
    try:
        state, run_id = _track_and_train(cfg, raw, run_dir, resume, tags)
    finally:
        (run_dir / LIVE).unlink(missing_ok=True)
    if cfg.evaluate:
        evaluate_agent(cfg, run_dir)
    mark_done(run_dir, run_id, cfg.budget)  # after the run and its evaluation are done
    print(
        "\n".join(
            ending(
                cfg,
                run_dir,
                StoredRun.open(run_id, cfg.tracking.uri),
                in_sweep=parent_run_id() is not None,
            )
        ),
        flush=True,
    )
    return state


def _track_and_train(
    cfg: Config, raw: DictConfig, run_dir: Path, resume: dict[str, Any] | None, tags: dict[str, str]
) -> tuple[Any, str]:
    """The MLflow run and the runner, the folder marked live meanwhile; (final state, run id)."""
    from epoet.tracking import MlflowTracker, parent_run_id

    resolved = cast(dict[str, Any], OmegaConf.to_container(raw, resolve=True))  # a DictConfig's
    with MlflowTracker(cfg.tracking.uri, cfg.tracking.experiment) as tracker:
        params = run_params(cfg, resolved, tracker.tracking_uri)
        run_id = tracker.start(
            run_name=f"{cfg.algo.name}-s{cfg.seed}",
            params=params,
            tags=tags,
            parent_run_id=parent_run_id(),
            resume_run_id=resume["run_id"] if resume else None,
        )
        mark_live(run_dir, run_id, tracker.tracking_uri)
        if resume is None:
            tracker.log_dict(resolved, "config.yaml")
        print(
            f"[epoet] {cfg.algo.name} seed={cfg.seed} budget={cfg.budget.name} "
            f"run_id={tracker.run_id} dir={run_dir}",
            flush=True,
        )
        with StopOnSignal():
            result = algorithm(cfg.algo.name).runner()(cfg, tracker, run_dir, resume)
        log_agent_model(tracker, run_dir, cfg)
    return result, run_id


def ending(cfg: Config, run_dir: Path, stored: StoredRun, in_sweep: bool) -> list[str]:
    """What a finished run says last: its headline numbers and, outside a sweep (whose parent
    prints a line per job), where its outputs are and the commands that look at them."""
    from epoet.eval.keys import RESULTS, SHIPPED_NAME, suite_metric

    m = stored.metrics
    numbers = f"score {m['score']:.1f} (best {m['best_score']:.1f})" if "score" in m else ""
    if (solved := suite_metric(m, SHIPPED_NAME, "success_rate")) is not None:
        numbers += (
            f", solved {solved:.1%} of the {SHIPPED_NAME} suite (mean return "
            f"{suite_metric(m, SHIPPED_NAME, 'return_mean'):.1f})"
        )
    seconds = m.get(ELAPSED, 0.0)
    took = f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"
    head = (
        f"[epoet] {cfg.algo.name} seed={cfg.seed} budget={cfg.budget.name} done after "
        f"{took} of training: {numbers}"
    )
    if in_sweep:
        return [head]
    from epoet.eval.suite import example_terrain

    return [
        head,
        f"  outputs:  {run_dir} (checkpoint, exported agent"
        f"{f', {RESULTS}/{SHIPPED_NAME}/' if cfg.evaluate else ''}); MLflow run "
        f"{stored.run_id}",
        f"  runs:     {stored.ui_hint()}",
        f"  evaluate: python -m epoet.eval.evaluate run={run_dir}",
        f"  render:   python -m epoet.eval.render run={run_dir} terrain={example_terrain()}",
    ]


def log_agent_model(tracker: MlflowTracker, run_dir: Path, cfg: Config) -> None:
    """The exported agent (as `agent_choice` picked it, what evaluation uses) as the run's MLflow
    model `agent` (epoet.eval.agent_model)."""
    from epoet.eval.agents import policy_in

    found = policy_in(run_dir)
    if found is None:
        raise RuntimeError(f"the run exported no agent into {run_dir}.")  # a runner's bug
    tracker.log_agent(found[0].path, "epoet.eval.agent_model", *robot_sizes(cfg.agent))


class EvaluationError(RuntimeError):
    """The run trained, but its end-of-run evaluation could not run; one sentence."""


def evaluate_agent(cfg: Config, run_dir: Path) -> None:
    """The run's exported agent (as `agent_choice` picked it) on the shipped suite,
    `budget.eval_episodes` episodes per terrain, logged to its MLflow run under the shipped
    suite's name (`suite/shipped/...`, `evaluation/shipped/`): what
    `python -m epoet.eval.evaluate run=<run_dir>` does. Interrupted, the run is not DONE, and a
    resume evaluates it again (logging each metric once: `StoredRun.log_results`)."""
    from epoet.eval.agents import AgentError  # pandas, the suite, the env: only when evaluating
    from epoet.eval.evaluate import COMMAND, evaluate_run
    from epoet.eval.keys import RESULTS, SHIPPED_NAME
    from epoet.eval.suite import SuiteError

    overrides = [
        f"run={run_dir}",
        f"episodes={cfg.budget.eval_episodes}",
        f"suite={SHIPPED_NAME}",
        f"out={run_dir / RESULTS / SHIPPED_NAME}",
    ]
    overrides += [f"tracking.uri={cfg.tracking.uri}"] if cfg.tracking.uri else []
    overrides += [f"processes={cfg.workers.num}"] if cfg.workers.num else []
    try:
        evaluate_run(validate(compose(overrides, config_name=COMMAND.name)), progress=False)
    except (AgentError, SuiteError) as err:
        raise EvaluationError(
            f"{cfg.algo.name} seed={cfg.seed} trained, but its evaluation "
            f"failed: {err} (retry: python -m epoet.eval.evaluate run={run_dir})"
        ) from err
