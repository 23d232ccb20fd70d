"""The root config of a training run, the registration of the schemas, and composition. Values
live in the YAML files; each folder's schema lives beside its code (envs/, terrain/, rollout/,
es/, open_ended/, epoet_sac/, rl/, tracking/, eval/ config.py) and holds types and range checks,
nothing else. The commands around a trained agent register their own schemas
(`register_command`, called by epoet.cli.KeyValueCommand), so this module names none of them.

Hydra's ConfigStore registers each dataclass as the schema of its YAML file, so a typo or a wrong
type fails at composition. `validate` builds the dataclass tree with `OmegaConf.to_object`,
which runs each `__post_init__` range check before any work starts; every failure is one
`ConfigError` (epoet.core.schema) sentence naming the key a user types.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, ClassVar, Optional, cast

from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from epoet.core.algorithm import Algorithm, AlgoSettings, Family
from epoet.core.schema import ConfigError, check, check_known_keys, positive
from epoet.envs.config import BODY_KEYS, HEXAPOD, AgentConfig
from epoet.registry import algorithms
from epoet.rollout.config import SelectionConfig, WorkersConfig
from epoet.terrain.config import REFERENCE_SIZE, TerrainConfig
from epoet.tracking.config import TrackingConfig


@dataclass
class BudgetConfig:
    """How much compute, never which algorithm: what every run reads. Paper values are the
    `paper` budget.

    Score thresholds (minimal criterion, reproduction, solved) are set for 2000-step episodes
    and multiplied by `score_scale` (the paper budget: 1). The integrator and the height
    schedule are the budget's too; conf/config.yaml hands them to the agent and the terrain, as
    it does the episode length. What an algorithm counts its compute in is its family's
    (`FAMILY_BUDGETS`), and conf/algo_budget/ sets its values (`register_configs`).
    """

    KEY: ClassVar[str] = "budget"

    name: str
    episode_steps: int
    eval_episodes: int
    score_scale: float
    integrator: str  # agent.integrator follows it
    max_height: float  # S at the first iteration, metres (terrain.max_height follows it)
    max_height_step: float  # +S per iteration (terrain.max_height_step follows it)
    hours: Optional[float]  # wall-clock stop: hours of training over resumes; null: none
    # CPU stop: CPU hours of the run's processes (workers, learner, evaluation inside training)
    # over resumes; null: none. The unit runs are compared in (epoet/core/clock.py).
    cpu_hours: Optional[float]

    def __post_init__(self) -> None:
        positive(self, "episode_steps", "eval_episodes", "score_scale")
        for key in ("hours", "cpu_hours"):
            value = getattr(self, key)
            check(value is None or value > 0, f"budget.{key} must be > 0 or null, got {value}.")

    def time_is_up(self, wall_seconds: float, cpu_seconds: float) -> str | None:
        """Which clock's budget the training so far (summed over resumes) has used up:
        'hours', 'cpu_hours' or None."""
        if self.hours is not None and wall_seconds >= self.hours * 3600.0:
            return "hours"
        if self.cpu_hours is not None and cpu_seconds >= self.cpu_hours * 3600.0:
            return "cpu_hours"
        return None


@dataclass
class OpenEndedBudgetConfig(BudgetConfig):
    """The compute of ePOET and ePOET-SAC: iterations of the loop and ES pairs per step."""

    iterations: int
    n_pairs: int  # mirrored pairs per ES step (2 episodes each)

    def __post_init__(self) -> None:
        super().__post_init__()
        positive(self, "iterations", "n_pairs")


@dataclass
class BaselineBudgetConfig(BudgetConfig):
    """The compute of the RL baselines: environment frames."""

    frames: int
    eval_every: int  # frames between deterministic evaluations

    def __post_init__(self) -> None:
        super().__post_init__()
        positive(self, "frames", "eval_every")


@dataclass
class Config:
    """The root config (conf/config.yaml)."""

    KEY: ClassVar[str] = ""

    # Each field's comment is its line in `python -m epoet --help` (conf/hydra/help/epoet.yaml).
    algo: AlgoSettings  # the algorithm trained (its record: epoet/registry.py)
    agent: AgentConfig  # the robot and its task: reward, episode rules, physics
    terrain: TerrainConfig  # the ground; each algorithm picks its own (ePOET: cppn)
    budget: BudgetConfig  # how much compute: episode length, iterations or frames, hours
    workers: WorkersConfig  # where ES rollouts run: local processes or a Ray cluster
    tracking: TrackingConfig  # the MLflow store and experiment a run logs to
    seed: int  # seeds everything the run draws
    checkpoint_every: int  # ES iterations, or collector batches (baselines), per checkpoint
    snapshot_cpu_minutes: list[float]  # CPU minutes of training at which the agents are saved
    agent_choice: str  # best | final: which parameters of each pair its file holds first
    selection: SelectionConfig  # which agent a run exports: held-out terrains or its own rule
    evaluate: bool  # evaluate the exported agent on the shipped suite at the end
    resume: Optional[str]  # a run folder or checkpoint file to continue; auto: this
    # job's own folder if it has a checkpoint
    check: bool  # validate the config as the run would, print one line, run nothing
    epoet_3d: Optional[str]  # a copy of ml-tue/ePOET_3D, the authors' files (docs/authors.md);
    # null: the environment variable EPOET_3D, else ../shared/ePOET_3D beside the project

    def __post_init__(self) -> None:
        check(0 <= self.seed < 2**32, f"seed must be in [0, 2**32), got {self.seed}.")
        positive(self, "checkpoint_every")
        marks = self.snapshot_cpu_minutes
        check(
            all(m > 0 for m in marks) and list(marks) == sorted(set(marks)),
            f"snapshot_cpu_minutes must be increasing positive minutes, got {list(marks)}.",
        )
        check(
            self.agent_choice in ("best", "final"),
            f"agent_choice must be 'best' or 'final', got {self.agent_choice!r}.",
        )
        # One source of truth for the episode length: the budget (it also scales thresholds).
        check(
            self.agent.max_episode_steps == self.budget.episode_steps,
            f"agent.max_episode_steps ({self.agent.max_episode_steps}) follows "
            f"budget.episode_steps ({self.budget.episode_steps}); set budget.episode_steps.",
        )
        check(
            self.terrain.kind != "bowl" or self.terrain.rendering == "clean",
            "terrain.rendering=reference renders CPPN environments; terrain.kind=bowl has none "
            "(use terrain.rendering=clean).",
        )
        check(
            self.selection.terrains == 0
            or self.selection.rendering == "clean"
            or self.terrain.size == REFERENCE_SIZE,
            f"selection.rendering=reference renders the held-out terrains on the reference's "
            f"field, terrain.size={REFERENCE_SIZE:g} metres; got {self.terrain.size:g} (or set "
            f"selection.rendering=clean).",
        )
        self.algo.check_run(self)  # what the algorithm needs of the other settings

    def unused_keys(self) -> tuple[str, ...]:
        """Dotted keys (and key prefixes) of settings this run never reads, so its MLflow params
        hold only what shaped it (a bowl terrain's CPPN settings, the baselines' ES workers)."""
        return (*self.terrain.unused_keys(), *self.algo.unused_keys())


# --- composition and validation -------------------------------------------------------------------

# What a family's budget counts, as the schema of `budget`.
FAMILY_BUDGETS: dict[Family, type[BudgetConfig]] = {
    Family.OPEN_ENDED: OpenEndedBudgetConfig,
    Family.BASELINE: BaselineBudgetConfig,
}


def register_configs() -> None:
    """Make each dataclass the schema of its YAML file (type checks at composition), and give
    every algorithm (its record) the two nodes composition reads it from."""
    cs = ConfigStore.instance()
    cs.store(name="config_schema", node=Config)
    cs.store(group="agent", name="agent_schema", node=AgentConfig)
    cs.store(group="terrain", name="terrain_schema", node=TerrainConfig)
    cs.store(group="budget", name="budget_schema", node=BudgetConfig)
    for family, budget in FAMILY_BUDGETS.items():
        cs.store(group="budget", name=f"{family.value}_budget_schema", node=budget)
    cs.store(group="workers", name="workers_schema", node=WorkersConfig)
    cs.store(group="tracking", name="tracking_schema", node=TrackingConfig)
    for record in algorithms():
        register_algorithm(cs, record)


def register_algorithm(cs: ConfigStore, record: Algorithm) -> None:
    """An algorithm's two nodes. `algo/<name>_schema`, the first default of its YAML: its
    schema with the record's name. `algo_budget/<name>`, which conf/config.yaml's
    `algo_budget: ${algo}` picks: its family's budget schema, the family's values on the budget
    (conf/algo_budget/<family>/<budget>.yaml, required) and then its own, where it has any
    (conf/algo_budget/<name>/<budget>.yaml)."""
    settings = OmegaConf.structured(record.schema)
    settings.name = record.name
    cs.store(group="algo", name=f"{record.name}_schema", node=settings)
    family = record.family.value
    defaults = [
        f"/budget/{family}_budget_schema@budget",
        {f"/algo_budget/{family}": "${budget}"},
        {f"optional /algo_budget/{record.name}": "${budget}"},
    ]
    cs.store(group="algo_budget", name=record.name, node={"defaults": defaults}, package="_global_")


def register_command(name: str, schema: type) -> None:
    """The schema of a command's conf/<name>.yaml (`<name>_schema`), registered by the command
    itself (epoet.cli.KeyValueCommand), so composition keeps no list of the commands above it:
    `compose(config_name=<name>)` needs the command's module imported (its COMMAND)."""
    ConfigStore.instance().store(name=f"{name}_schema", node=schema)


CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def compose(overrides: Sequence[str] = (), config_name: str = "config") -> DictConfig:
    """The config `python -m epoet <overrides>` would run, for notebooks, tests and benches
    (inside a running Hydra app, from that app's config search path, the same conf/)."""
    register_configs()
    if GlobalHydra.instance().is_initialized():
        return hydra_compose(config_name=config_name, overrides=list(overrides))
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides))


def validate(cfg: DictConfig) -> Any:
    """The dataclass tree of a composed config, every range check run; raises ConfigError with
    one sentence. The YAML's schema (and, for `algo`, the algorithm's) decides each node's type;
    a key none of them has (`+budget.cpu_hour=1`) is refused like a plain typo."""
    try:
        check_known_keys(cfg)
        return OmegaConf.to_object(cfg)
    except ConfigError as err:
        raise ConfigError(_typed_keys(str(err), cfg)) from None


_INTERPOLATION = re.compile(r"^\$\{([\w.]+)\}$")


def _interpolated(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Every key whose value is another key (`agent.max_episode_steps: ${budget.episode_steps}`)
    mapped to that key, in a config container that is not resolved."""
    found: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            found.update(_interpolated(value, f"{name}."))
        elif isinstance(value, str) and (match := _INTERPOLATION.match(value)):
            found[name] = match.group(1)
    return found


def _typed_keys(message: str, cfg: DictConfig) -> str:
    """Name the key the user typed: an error about a key that only follows another
    ("agent.max_episode_steps must be > 0") names the source first
    ("budget.episode_steps (agent.max_episode_steps) must be > 0")."""
    plain = cast(dict[str, Any], OmegaConf.to_container(cfg, resolve=False))  # a DictConfig's
    for key, source in _interpolated(plain).items():
        message = re.sub(rf"(?<![\w.(]){re.escape(key)}(?![\w])", f"{source} ({key})", message)
    return message


@cache
def _robot_body(robot: str) -> dict[str, Any]:
    agent = validate(compose([f"agent={robot}"])).agent
    return {key: getattr(agent, key) for key in BODY_KEYS}


def saved_agent(agent: Mapping[str, Any]) -> dict[str, Any]:
    """A saved agent config (a checkpoint's, a run's config artifact) in today's layout: one
    from before robots were parts names no MJCF and is the hexapod's, whose body it gets."""
    if "mjcf" in agent:
        return dict(agent)
    return {**_robot_body(HEXAPOD), **agent}


def load(overrides: Sequence[str] = ()) -> Config:
    """The validated config of `python -m epoet <overrides>`: where code outside a run (tests,
    benches, notebooks) gets the defaults, which live in the YAML files only."""
    return validate(compose(overrides))
