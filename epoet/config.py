"""Structured configs: the schema behind conf/, with types checked by OmegaConf and ranges by us.

Hydra's ConfigStore registers each dataclass as the schema of its YAML file, so a typo or a wrong
type fails at composition. Ranges are checked by `validate`, which builds the dataclasses (running
their `__post_init__`) before any work starts; every failure is one `ConfigError` sentence.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, Optional

from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf


class ConfigError(ValueError):
    """A config value that cannot work; the message is one sentence naming it."""


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


def _key(obj: Any, name: str) -> str:
    """The dotted config key a user types for a field, e.g. `terrain.grid`."""
    prefix = _PREFIX.get(type(obj).__name__, "")
    return f"{prefix}.{name}" if prefix else name


def _positive(obj: Any, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _check(value > 0, f"{_key(obj, name)} must be > 0, got {value}.")


def _non_negative(obj: Any, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _check(value >= 0, f"{_key(obj, name)} must be >= 0, got {value}.")


_PREFIX = {"AgentConfig": "agent", "RewardConfig": "agent.reward", "TerrainConfig": "terrain",
           "CppnConfig": "terrain.cppn", "MutationConfig": "terrain.mutation",
           "EsConfig": "algo.es", "PoetConfig": "algo", "BudgetConfig": "budget",
           "WorkersConfig": "workers", "TrackingConfig": "tracking"}


@dataclass
class RewardConfig:
    """Weights of the paper's Eq. 1 as implemented by the reference (REFERENCE.md section 2)."""

    target_speed: float = 0.4
    lateral_speed_penalty: float = 30.0
    w_velocity: float = 6.0
    w_heading: float = 10.0
    w_lateral: float = 10.0
    c_lateral: float = 0.1
    c_heading: float = 0.1
    c_pitch: float = 0.5
    c_roll: float = 0.5
    c_actuator: float = 1e-4
    c_vertical: float = 0.7
    finish_bonus: float = 500.0

    def __post_init__(self) -> None:
        _positive(self, "target_speed")
        _non_negative(self, "lateral_speed_penalty", "w_velocity", "w_heading", "w_lateral",
                      "c_lateral", "c_heading", "c_pitch", "c_roll", "c_actuator", "c_vertical",
                      "finish_bonus")


INTEGRATORS = ("rk4", "implicitfast")


@dataclass
class AgentConfig:
    """The hexapod and its episode rules (REFERENCE.md sections 1-3)."""

    name: str = "hexapod"
    timestep: float = 0.02          # one physics step per control step: 50 Hz, as the reference
    integrator: str = "rk4"         # rk4 (the reference) | implicitfast (faster; README: Budgets)
    max_episode_steps: int = 2000
    start_x: float = -6.0           # spawn x; the finish line is `finish_x` (see README)
    finish_x: float = 6.0
    no_progress_steps: int = 500    # end after this many steps without a new best x
    progress_margin: float = 0.01   # metres beyond the best x that count as progress
    settle_steps: int = 20
    spawn_xy_std: float = 0.1
    spawn_yaw: float = 0.8          # yaw ~ U(-spawn_yaw, spawn_yaw)
    spawn_vel_std: float = 0.1
    spawn_clearance: float = 0.14   # torso height above the highest ground under the robot
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        _check(self.name == "hexapod", f"agent.name must be 'hexapod', got {self.name!r}.")
        _check(self.integrator in INTEGRATORS,
               f"agent.integrator must be one of {list(INTEGRATORS)}, got {self.integrator!r}.")
        _positive(self, "timestep", "max_episode_steps", "no_progress_steps", "spawn_clearance")
        _non_negative(self, "settle_steps", "spawn_xy_std", "spawn_yaw", "spawn_vel_std",
                      "progress_margin")
        _check(self.finish_x > self.start_x,
               f"agent.finish_x ({self.finish_x}) must be ahead of agent.start_x ({self.start_x}).")


@dataclass
class CppnConfig:
    """neat-python genome settings, paper Table 5 (names as in neat-python's config file).

    Table 5 omits seven settings; those follow the reference's config, not neat-python's usual
    values: no response or connection mutations, no replacement of biases or weights, and
    connections toggled at rate 0.1 (response_mutate_rate, response_replace_rate,
    conn_add_prob, conn_delete_prob, bias_replace_rate, weight_replace_rate,
    enabled_mutate_rate).
    """

    num_inputs: int = 2
    num_outputs: int = 1
    num_hidden: int = 2
    initial_connection: str = "full_nodirect"
    feed_forward: bool = True
    activation_default: str = "random"
    activation_mutate_rate: float = 0.5
    activation_options: list[str] = field(
        default_factory=lambda: ["identity", "sin", "sigmoid", "square", "tanh", "gauss"])
    aggregation_default: str = "sum"
    aggregation_mutate_rate: float = 0.1
    aggregation_options: list[str] = field(default_factory=lambda: ["sum"])
    bias_init_mean: float = 0.0
    bias_init_stdev: float = 0.1
    bias_init_type: str = "gaussian"
    bias_max_value: float = 10.0
    bias_min_value: float = -10.0
    bias_mutate_power: float = 0.1
    bias_mutate_rate: float = 0.75
    bias_replace_rate: float = 0.0
    compatibility_disjoint_coefficient: float = 1.0
    compatibility_weight_coefficient: float = 0.5
    conn_add_prob: float = 0.0
    conn_delete_prob: float = 0.0
    enabled_default: bool = True
    enabled_mutate_rate: float = 0.1
    node_add_prob: float = 0.1
    node_delete_prob: float = 0.075
    response_init_mean: float = 1.0
    response_init_stdev: float = 0.0
    response_init_type: str = "gaussian"
    response_max_value: float = 10.0
    response_min_value: float = -10.0
    response_mutate_power: float = 0.2
    response_mutate_rate: float = 0.0
    response_replace_rate: float = 0.0
    single_structural_mutation: bool = True
    structural_mutation_surer: str = "default"
    weight_init_mean: float = 0.0
    weight_init_stdev: float = 0.25
    weight_init_type: str = "gaussian"
    weight_max_value: float = 10.0
    weight_min_value: float = -10.0
    weight_mutate_power: float = 0.1
    weight_mutate_rate: float = 0.75
    weight_replace_rate: float = 0.0

    def __post_init__(self) -> None:
        _check(self.num_inputs == 2 and self.num_outputs == 1,
               "terrain.cppn must map 2 inputs (x, y) to 1 output (height).")
        _non_negative(self, "num_hidden")
        known = {"identity", "sin", "sigmoid", "square", "tanh", "gauss", "relu", "abs", "exp",
                 "log", "inv", "clamped", "cube", "hat", "softplus", "elu", "lelu", "selu"}
        unknown = sorted(set(self.activation_options) - known)
        _check(not unknown, f"terrain.cppn.activation_options has unknown activations {unknown}.")
        # The vectorised CPPN evaluator (epoet/terrain/cppn.py) implements these neat built-ins.
        unknown = sorted(set(self.aggregation_options) - {"sum", "product", "max", "min", "mean"})
        _check(not unknown,
               f"terrain.cppn.aggregation_options has unsupported aggregations {unknown}.")


@dataclass
class MutationConfig:
    """Validity rules for mutated CPPN children (REFERENCE.md section 4, the reference's rules)."""

    min_genome_distance: float = 0.8
    check_grid: int = 20
    min_range: float = 0.1          # max of (output - output at the first point) must exceed this
    min_variance: float = 0.1
    response_rescale_low: float = 0.25     # outside [low, high] the output response is reset
    response_rescale_high: float = 16.0
    response_target_low: float = 0.25      # to U(target_low, target_high) / peak (reference)
    response_target_high: float = 0.75
    output_response: float = 10.0   # the reference sets the output node's response before mutating
    max_tries: int = 2000           # with no connection mutations, deep genomes need many tries

    def __post_init__(self) -> None:
        _positive(self, "check_grid", "max_tries", "response_rescale_low", "response_rescale_high",
                  "response_target_low")
        _check(self.response_target_low <= self.response_target_high,
               f"terrain.mutation.response_target_low ({self.response_target_low}) must not "
               f"exceed response_target_high ({self.response_target_high}).")
        _non_negative(self, "min_genome_distance", "min_range", "min_variance")


@dataclass
class TerrainConfig:
    """The heightfield: extent, resolution, the bowl part, the CPPN part and the height schedule."""

    kind: str = "bowl"              # bowl | cppn
    grid: int = 200                 # samples per side
    size: float = 40.0              # metres per side (square terrain centred at the origin)
    base: float = 0.5               # hfield base thickness below height 0 (metres)
    max_height: float = 0.1         # initial maximum height S (metres)
    max_height_step: float = 0.01   # +S per iteration (paper)
    max_height_limit: float = 2.2   # cap on S (reference)
    bowl_weight: float = 0.3        # heightmap = 0.3 bowl + 0.7 CPPN (paper); 1.0 = bowl only
    bump_grid: int = 20
    bump_low: float = 0.15
    bump_high: float = 1.0
    cppn: CppnConfig = field(default_factory=CppnConfig)
    mutation: MutationConfig = field(default_factory=MutationConfig)

    def __post_init__(self) -> None:
        _check(self.kind in ("bowl", "cppn"),
               f"terrain.kind must be 'bowl' or 'cppn', got {self.kind!r}.")
        _positive(self, "grid", "size", "base", "bump_grid", "max_height_limit")
        _non_negative(self, "max_height", "max_height_step")
        _check(self.grid >= 8, f"terrain.grid must be >= 8 samples, got {self.grid}.")
        _check(0.0 <= self.bowl_weight <= 1.0,
               f"terrain.bowl_weight must be in [0, 1], got {self.bowl_weight}.")
        _check(0.0 < self.bump_low <= self.bump_high,
               f"terrain.bump_low/bump_high must satisfy 0 < low <= high, got "
               f"{self.bump_low}/{self.bump_high}.")
        _check(self.max_height <= self.max_height_limit,
               f"terrain.max_height ({self.max_height}) exceeds terrain.max_height_limit "
               f"({self.max_height_limit}).")


@dataclass
class EsConfig:
    """OpenAI-ES of every pair (paper Table 4, REFERENCE.md section 5)."""

    hidden: list[int] = field(default_factory=lambda: [40, 40])
    lr: float = 0.01
    lr_decay: float = 0.9999
    lr_floor: float = 0.001
    sigma: float = 0.02
    sigma_decay: float = 0.999
    sigma_floor: float = 0.01
    l2_coeff: float = 0.01

    def __post_init__(self) -> None:
        _check(len(self.hidden) > 0 and all(h > 0 for h in self.hidden),
               f"algo.es.hidden must be a non-empty list of positive sizes, got {self.hidden}.")
        _positive(self, "lr", "lr_floor", "sigma", "sigma_floor")
        _non_negative(self, "l2_coeff")
        for name in ("lr_decay", "sigma_decay"):
            value = getattr(self, name)
            _check(0.0 < value <= 1.0, f"algo.es.{name} must be in (0, 1], got {value}.")
        _check(self.lr_floor <= self.lr and self.sigma_floor <= self.sigma,
               "algo.es floors must not exceed the initial lr / sigma.")


@dataclass
class PoetConfig:
    """ePOET (paper Table 4); score thresholds are for 2000-step episodes (see BudgetConfig)."""

    name: str = "epoet"
    es: EsConfig = field(default_factory=EsConfig)
    iterations_before_transfer: int = 15
    adjust_interval: int = 5        # reproduction every adjust_interval * 15 = 75 iterations
    max_num_envs: int = 40
    num_children: int = 8
    max_admitted: int = 1
    mc_lower: float = 500.0
    mc_upper: float = 3000.0
    repro_threshold: float = 2000.0
    novelty_k: int = 5

    def __post_init__(self) -> None:
        _positive(self, "iterations_before_transfer", "adjust_interval", "max_num_envs",
                  "num_children", "max_admitted", "novelty_k")
        _check(self.mc_lower < self.mc_upper,
               f"algo.mc_lower ({self.mc_lower}) must be below algo.mc_upper ({self.mc_upper}).")


@dataclass
class BudgetConfig:
    """How much compute, never which algorithm. Paper values are the `paper` budget.

    Score thresholds (minimal criterion, reproduction, solved) are set for 2000-step episodes
    and multiplied by `score_scale` (the paper budget: 1). A small budget may also set ePOET's
    transfer and reproduction intervals; null keeps the algorithm's (the paper's).
    """

    name: str = MISSING
    iterations: int = MISSING       # ES iterations (ePOET / ePOET-SAC)
    n_pairs: int = MISSING          # mirrored pairs per ES step (paper: 256 pairs = 512 episodes)
    episode_steps: int = MISSING    # paper: 2000
    eval_episodes: int = MISSING    # paper: 5
    frames: int = MISSING           # environment frames for the RL baselines (paper: ~1M)
    eval_every: int = MISSING       # RL baselines: frames between deterministic evaluations
    score_scale: float = MISSING
    transfer_interval: Optional[int] = None
    reproduce_interval: Optional[int] = None

    def __post_init__(self) -> None:
        _positive(self, "iterations", "n_pairs", "episode_steps", "eval_episodes", "frames",
                  "eval_every", "score_scale")
        for name in ("transfer_interval", "reproduce_interval"):
            value = getattr(self, name)
            _check(value is None or value > 0, f"budget.{name} must be > 0 or null, got {value}.")


@dataclass
class WorkersConfig:
    """Where rollouts run: `local` is a process pool on this machine."""

    backend: str = "local"
    num: Optional[int] = None       # None: one worker per available core
    batch: int = 16                 # robots per process (fits the cache: bench/rollout_throughput)

    def __post_init__(self) -> None:
        _check(self.backend in ("local",),
               f"workers.backend must be 'local', got {self.backend!r}.")
        _check(self.num is None or self.num > 0, f"workers.num must be > 0, got {self.num}.")
        _positive(self, "batch")


@dataclass
class TrackingConfig:
    """MLflow: the store defaults to sqlite:///<project root>/mlflow.db; MLFLOW_TRACKING_URI wins."""

    experiment: str = "epoet"
    uri: Optional[str] = None

    def __post_init__(self) -> None:
        _check(bool(self.experiment), "tracking.experiment must not be empty.")


@dataclass
class Config:
    """The root config (conf/config.yaml)."""

    algo: Any = MISSING             # one of ALGO_SCHEMAS, chosen by `algo.name`
    agent: AgentConfig = field(default_factory=AgentConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    budget: BudgetConfig = MISSING
    workers: WorkersConfig = field(default_factory=WorkersConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    seed: int = 0
    checkpoint_every: int = 10      # ES iterations, or collector batches (baselines), per checkpoint
    resume: Optional[str] = None    # a run folder or checkpoint file to continue

    def __post_init__(self) -> None:
        _check(0 <= self.seed < 2**32, f"seed must be in [0, 2**32), got {self.seed}.")
        _positive(self, "checkpoint_every")
        # One source of truth for the episode length: the budget (it also scales thresholds).
        _check(self.agent.max_episode_steps == self.budget.episode_steps,
               f"agent.max_episode_steps ({self.agent.max_episode_steps}) follows "
               f"budget.episode_steps ({self.budget.episode_steps}); set budget.episode_steps.")
        if isinstance(self.algo, SacConfig):
            _check(self.budget.frames >= self.algo.batch_size,
                   f"budget.frames ({self.budget.frames}) must be at least algo.batch_size "
                   f"({self.algo.batch_size}), or SAC never updates.")
        if isinstance(self.algo, PoetConfig):
            _check(self.terrain.kind == "cppn",
                   f"algo={self.algo.name} evolves CPPN terrains, so it needs terrain=cppn "
                   f"(got terrain={self.terrain.kind}).")


@dataclass
class GalleryConfig:
    """`python -m epoet.terrain`: a root terrain and its mutated descendants as one PNG grid."""

    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    seed: int = 0
    n: int = 8
    out: str = "gallery"

    def __post_init__(self) -> None:
        _non_negative(self, "seed")
        _positive(self, "n")


def register_configs() -> None:
    """Make each dataclass the schema of its YAML file (type checks at composition)."""
    cs = ConfigStore.instance()
    cs.store(name="config_schema", node=Config)
    cs.store(name="gallery_schema", node=GalleryConfig)
    cs.store(group="agent", name="hexapod_schema", node=AgentConfig)
    cs.store(group="terrain", name="terrain_schema", node=TerrainConfig)
    cs.store(group="budget", name="budget_schema", node=BudgetConfig)
    cs.store(group="workers", name="workers_schema", node=WorkersConfig)
    cs.store(group="tracking", name="tracking_schema", node=TrackingConfig)
    for name, schema in ALGO_SCHEMAS.items():
        cs.store(group="algo", name=f"{name}_schema", node=schema)


CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def compose(overrides: Sequence[str] = (), config_name: str = "config") -> DictConfig:
    """The config `python -m epoet <overrides>` would run, for notebooks, tests and benches."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides))


def to_object(cfg: DictConfig, schema: type) -> Any:
    """Build the dataclass tree from a composed config, running every range check."""
    data = OmegaConf.to_container(cfg, resolve=True)
    return _build(schema, data)


def _build(schema: type, data: Any) -> Any:
    if not is_dataclass(schema) or not isinstance(data, dict):
        return data
    kwargs = {}
    names = {f.name: f for f in fields(schema)}
    for key, value in data.items():
        if key not in names:
            continue  # keys owned by other schemas (hydra internals); types were checked already
        if key == "algo" and schema is Config:
            kwargs[key] = _build(_algo_schema(value), value)
            continue
        sub = _SCHEMAS.get(str(names[key].type))
        kwargs[key] = _build(sub, value) if sub is not None else value
    return schema(**kwargs)


def _algo_schema(algo: Any) -> type:
    name = algo.get("name") if isinstance(algo, dict) else None
    _check(name in ALGO_SCHEMAS,
           f"algo must be one of {sorted(ALGO_SCHEMAS)}, got {name!r}.")
    return ALGO_SCHEMAS[name]


ALGO_SCHEMAS: dict[str, type] = {"epoet": PoetConfig}

_SCHEMAS: dict[str, type] = {cls.__name__: cls for cls in (
    RewardConfig, AgentConfig, CppnConfig, MutationConfig, TerrainConfig, EsConfig, PoetConfig,
    BudgetConfig, WorkersConfig, TrackingConfig)}


def validate(cfg: DictConfig, schema: type = Config) -> Any:
    """Range-check a composed config; raises ConfigError with one sentence."""
    return to_object(cfg, schema)


# --- RL baselines ---------------------------------------------------------------------------------
# PPO, SAC and VMPO (paper Tables 2-3, REFERENCE.md section 8); the YAML files are
# conf/algo/{ppo,sac,vmpo}.yaml and the runners live in epoet/rl/. Sizes are per collector batch of
# `frames_per_batch` frames; budget.frames is the total. A budget smaller than one batch shrinks the
# batch and keeps the ratios (epochs per batch, SAC updates and random frames per collected frame):
# see `batch_plan` in epoet/rl/common.py.

RL_ACTIVATIONS = ("tanh", "relu", "elu")


@dataclass
class RlConfig:
    """What the three baselines share: the networks, the optimiser and the collector batch."""

    name: str = MISSING
    hidden: list[int] = field(default_factory=lambda: [64, 64])
    activation: str = "tanh"
    lr: float = 3e-4                # one Adam over all parameters (Table 2: policy = value lr)
    gamma: float = 0.99
    frames_per_batch: int = 2000    # the paper's trajectory_length
    obs_norm: bool = True           # running observation normalisation (PPO and VMPO in the paper)

    def __post_init__(self) -> None:
        _check(len(self.hidden) > 0 and all(h > 0 for h in self.hidden),
               f"algo.hidden must be a non-empty list of positive sizes, got {self.hidden}.")
        _check(self.activation in RL_ACTIVATIONS,
               f"algo.activation must be one of {list(RL_ACTIVATIONS)}, got {self.activation!r}.")
        _positive(self, "lr", "frames_per_batch")
        _check(0.0 < self.gamma <= 1.0, f"algo.gamma must be in (0, 1], got {self.gamma}.")


@dataclass
class OnPolicyConfig(RlConfig):
    """PPO and VMPO: GAE on each batch, then `epochs` passes of shuffled minibatches."""

    gae_lambda: float = 0.95        # Table 2 calls it "tau"
    epochs: int = 10
    minibatch: int = 64
    critic_coeff: float = 0.5
    max_grad_norm: Optional[float] = 0.5  # not in the paper; None disables clipping

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(0.0 <= self.gae_lambda <= 1.0,
               f"algo.gae_lambda must be in [0, 1], got {self.gae_lambda}.")
        _positive(self, "epochs", "minibatch", "critic_coeff")
        _check(self.max_grad_norm is None or self.max_grad_norm > 0,
               f"algo.max_grad_norm must be > 0 or null, got {self.max_grad_norm}.")


@dataclass
class PpoConfig(OnPolicyConfig):
    """PPO with the clipped objective (paper Table 2)."""

    name: str = "ppo"
    clip: float = 0.2
    entropy_coeff: float = 0.005
    normalize_advantage: bool = True  # not in the paper; the common PPO implementation detail

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "clip")
        _non_negative(self, "entropy_coeff")


@dataclass
class VmpoConfig(OnPolicyConfig):
    """V-MPO (Song et al. 2019; REFERENCE.md section 8); see epoet/rl/vmpo.py."""

    name: str = "vmpo"
    minibatch: int = 128
    top_fraction: float = 0.5
    eta_init: float = 1.0
    eps_eta: float = 0.02
    alpha_init: float = 0.1
    eps_alpha: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(0.0 < self.top_fraction <= 1.0,
               f"algo.top_fraction must be in (0, 1], got {self.top_fraction}.")
        _positive(self, "eta_init", "eps_eta", "alpha_init", "eps_alpha")


@dataclass
class SacConfig(RlConfig):
    """SAC with twin Q networks and automatic entropy tuning (paper Table 3)."""

    name: str = "sac"
    hidden: list[int] = field(default_factory=lambda: [256, 256])
    activation: str = "relu"
    obs_norm: bool = False
    batch_size: int = 256
    tau: float = 0.005              # soft target update rate
    alpha_init: float = 1.0
    target_entropy: Optional[float] = None  # None: -(action dimensions), the usual heuristic
    reward_scale: float = 5.0
    updates_per_batch: int = 1000   # 1000 gradient updates per 2000 collected frames
    init_random_frames: int = 2000  # Table 3 pretrain_epoch 1: one batch of uniform actions
    buffer_size: int = 1_000_000

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "batch_size", "alpha_init", "reward_scale", "updates_per_batch",
                  "buffer_size")
        _non_negative(self, "init_random_frames")
        _check(0.0 < self.tau <= 1.0, f"algo.tau must be in (0, 1], got {self.tau}.")
        _check(self.buffer_size >= self.batch_size,
               f"algo.buffer_size ({self.buffer_size}) must hold at least one batch "
               f"(algo.batch_size={self.batch_size}).")


ALGO_SCHEMAS.update({"ppo": PpoConfig, "sac": SacConfig, "vmpo": VmpoConfig})
_SCHEMAS.update({cls.__name__: cls for cls in (PpoConfig, SacConfig, VmpoConfig)})
_PREFIX.update({cls.__name__: "algo" for cls in (RlConfig, OnPolicyConfig, PpoConfig, SacConfig,
                                                 VmpoConfig)})
# --- end RL baselines -----------------------------------------------------------------------------
