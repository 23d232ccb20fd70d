"""Structured configs: the schema behind conf/. Values live in the YAML files; these classes hold
their types and range checks, nothing else.

Hydra's ConfigStore registers each dataclass as the schema of its YAML file, so a typo or a wrong
type fails at composition. `validate` builds the dataclass tree with `OmegaConf.to_object`,
which runs each `__post_init__` range check before any work starts; every failure is one
`ConfigError` sentence naming the key a user types.
"""
from __future__ import annotations

import importlib.util
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Optional

from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf


class ConfigError(ValueError):
    """A config value that cannot work; the message is one sentence naming it."""


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


def _key(obj: Any, name: str) -> str:
    """The dotted config key a user types for a field, e.g. `terrain.grid`."""
    return f"{obj.KEY}.{name}" if obj.KEY else name


def _positive(obj: Any, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _check(value > 0, f"{_key(obj, name)} must be > 0, got {value}.")


def _non_negative(obj: Any, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        _check(value >= 0, f"{_key(obj, name)} must be >= 0, got {value}.")


@dataclass
class RewardConfig:
    """Weights of the paper's Eq. 1 as implemented by the reference (docs/reference.md)."""

    KEY: ClassVar[str] = "agent.reward"

    target_speed: float
    lateral_speed_penalty: float
    w_velocity: float
    w_heading: float
    w_lateral: float
    c_lateral: float
    c_heading: float
    c_pitch: float
    c_roll: float
    c_actuator: float
    c_vertical: float
    finish_bonus: float

    def __post_init__(self) -> None:
        _positive(self, "target_speed")
        _non_negative(self, "lateral_speed_penalty", "w_velocity", "w_heading", "w_lateral",
                      "c_lateral", "c_heading", "c_pitch", "c_roll", "c_actuator", "c_vertical",
                      "finish_bonus")


INTEGRATORS = ("rk4", "implicitfast")


@dataclass
class AgentConfig:
    """The hexapod and its episode rules (docs/reference.md "Robot, reward, episode end")."""

    KEY: ClassVar[str] = "agent"

    name: str
    timestep: float                  # one physics step per control step: 50 Hz, as the reference
    integrator: str                  # rk4 (the reference) | implicitfast (faster; README: Budgets)
    max_episode_steps: int
    start_x: float                   # spawn x; the finish line is `finish_x` (see README)
    finish_x: float
    no_progress_steps: int           # end after this many steps without a new best x
    progress_margin: float           # metres beyond the best x that count as progress
    settle_steps: int
    spawn_xy_std: float
    spawn_yaw: float                 # yaw ~ U(-spawn_yaw, spawn_yaw)
    spawn_vel_std: float
    spawn_clearance: float           # torso height above the highest ground under the robot
    reward: RewardConfig

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
    """neat-python genome settings (names as in neat-python's config file; values: paper Table 5
    and, for what it omits, the reference: conf/terrain/genome/table5.yaml)."""

    KEY: ClassVar[str] = "terrain.cppn"

    num_inputs: int
    num_outputs: int
    num_hidden: int
    initial_connection: str
    feed_forward: bool
    activation_default: str
    activation_mutate_rate: float
    activation_options: list[str]
    aggregation_default: str
    aggregation_mutate_rate: float
    aggregation_options: list[str]
    bias_init_mean: float
    bias_init_stdev: float
    bias_init_type: str
    bias_max_value: float
    bias_min_value: float
    bias_mutate_power: float
    bias_mutate_rate: float
    bias_replace_rate: float
    compatibility_disjoint_coefficient: float
    compatibility_weight_coefficient: float
    conn_add_prob: float
    conn_delete_prob: float
    enabled_default: bool
    enabled_mutate_rate: float
    node_add_prob: float
    node_delete_prob: float
    response_init_mean: float
    response_init_stdev: float
    response_init_type: str
    response_max_value: float
    response_min_value: float
    response_mutate_power: float
    response_mutate_rate: float
    response_replace_rate: float
    single_structural_mutation: bool
    structural_mutation_surer: str
    weight_init_mean: float
    weight_init_stdev: float
    weight_init_type: str
    weight_max_value: float
    weight_min_value: float
    weight_mutate_power: float
    weight_mutate_rate: float
    weight_replace_rate: float

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
    """Validity rules for mutated CPPN children (docs/reference.md, the reference's rules)."""

    KEY: ClassVar[str] = "terrain.mutation"

    min_genome_distance: float
    check_grid: int                  # samples per side of the check grid, in CPPN units
    min_range: float                 # max of (output - output at the first point) must exceed this
    min_variance: float
    response_rescale_low: float      # a peak below low resets the output response to
    small_peak_response: list[float]  # U(lo, hi) / peak,
    response_rescale_high: float     # a peak above high resets it to
    large_peak_response: list[float]  # U(lo, hi) / peak (the reference's two rules)
    output_response: float           # the reference sets the output node's response before mutating
    max_tries: int                   # with no connection mutations, deep genomes need many tries

    def __post_init__(self) -> None:
        _positive(self, "check_grid", "max_tries", "response_rescale_low", "response_rescale_high")
        for name in ("small_peak_response", "large_peak_response"):
            lo_hi = getattr(self, name)
            _check(len(lo_hi) == 2 and 0.0 < lo_hi[0] <= lo_hi[1],
                   f"terrain.mutation.{name} must be [low, high] with 0 < low <= high, got "
                   f"{list(lo_hi)}.")
        _non_negative(self, "min_genome_distance", "min_range", "min_variance")


@dataclass
class TerrainConfig:
    """The heightfield: extent, resolution, the bowl part, the CPPN part and the height schedule."""

    KEY: ClassVar[str] = "terrain"

    kind: str                        # bowl | cppn
    grid: int                        # samples per side
    size: float                      # metres per side (square terrain centred at the origin)
    base: float                      # hfield base thickness below height 0 (metres)
    max_height: float                # initial maximum height S (metres)
    max_height_step: float           # +S per iteration (paper)
    max_height_limit: float          # cap on S (reference)
    bowl_weight: float               # heightmap = w bowl + (1 - w) CPPN; 1.0 = bowl only
    cppn_scale: float                # CPPN input units per metre (the reference's feature size)
    cppn_origin: list[float]         # (x, y) metres where the CPPN's input is (0, 0)
    bump_grid: int
    bump_low: float
    bump_high: float
    cppn: CppnConfig
    mutation: MutationConfig

    def __post_init__(self) -> None:
        _check(self.kind in ("bowl", "cppn"),
               f"terrain.kind must be 'bowl' or 'cppn', got {self.kind!r}.")
        _positive(self, "grid", "size", "base", "bump_grid", "max_height_limit", "cppn_scale")
        _non_negative(self, "max_height", "max_height_step")
        _check(self.grid >= 8, f"terrain.grid must be >= 8 samples, got {self.grid}.")
        _check(0.0 <= self.bowl_weight <= 1.0,
               f"terrain.bowl_weight must be in [0, 1], got {self.bowl_weight}.")
        _check(0.0 < self.bump_low <= self.bump_high,
               f"terrain.bump_low/bump_high must satisfy 0 < low <= high, got "
               f"{self.bump_low}/{self.bump_high}.")
        _check(len(self.cppn_origin) == 2,
               f"terrain.cppn_origin must be [x, y] metres, got {list(self.cppn_origin)}.")
        _check(self.max_height <= self.max_height_limit,
               f"terrain.max_height ({self.max_height}) exceeds terrain.max_height_limit "
               f"({self.max_height_limit}).")

    def unused_keys(self) -> tuple[str, ...]:
        """The settings this terrain never reads: the bowl has no CPPN."""
        if self.kind == "bowl":
            return ("terrain.cppn", "terrain.mutation", "terrain.cppn_scale",
                    "terrain.cppn_origin")
        return ()


@dataclass
class EsConfig:
    """OpenAI-ES of every pair (paper Table 4, docs/reference.md "ES and the ePOET loop")."""

    KEY: ClassVar[str] = "algo.es"

    hidden: list[int]
    lr: float
    lr_decay: float
    lr_floor: float
    sigma: float
    sigma_decay: float
    sigma_floor: float
    l2_coeff: float
    obs_norm_episodes: int           # 0: raw observations; k: standardised, stats from k per pair

    def __post_init__(self) -> None:
        _check(len(self.hidden) > 0 and all(h > 0 for h in self.hidden),
               f"algo.es.hidden must be a non-empty list of positive sizes, got {self.hidden}.")
        _positive(self, "lr", "lr_floor", "sigma", "sigma_floor")
        _non_negative(self, "l2_coeff", "obs_norm_episodes")
        for name in ("lr_decay", "sigma_decay"):
            value = getattr(self, name)
            _check(0.0 < value <= 1.0, f"algo.es.{name} must be in (0, 1], got {value}.")
        _check(self.lr_floor <= self.lr and self.sigma_floor <= self.sigma,
               "algo.es floors must not exceed the initial lr / sigma.")


@dataclass
class PoetConfig:
    """ePOET (paper Table 4); score thresholds are for 2000-step episodes (see BudgetConfig)."""

    KEY: ClassVar[str] = "algo"

    name: str
    es: EsConfig
    iterations_before_transfer: int
    adjust_interval: int             # reproduction every adjust_interval transfer intervals
    later_reproduce_interval: Optional[int]  # after the first reproduction (null: the same)
    transfer_bar_window: int         # a transfer must beat the best of this many evaluations
    proposal_step: str               # sgd | adam: the fine-tuning step of transfer and admission
    max_num_envs: int
    num_children: int
    max_admitted: int
    mc_lower: float
    mc_upper: float
    repro_threshold: float
    novelty_k: int

    def __post_init__(self) -> None:
        _positive(self, "iterations_before_transfer", "adjust_interval", "max_num_envs",
                  "num_children", "max_admitted", "novelty_k", "transfer_bar_window")
        _check(self.later_reproduce_interval is None or self.later_reproduce_interval > 0,
               f"algo.later_reproduce_interval must be > 0 or null, got "
               f"{self.later_reproduce_interval}.")
        _check(self.proposal_step in ("sgd", "adam"),
               f"algo.proposal_step must be 'sgd' or 'adam', got {self.proposal_step!r}.")
        _check(self.mc_lower < self.mc_upper,
               f"algo.mc_lower ({self.mc_lower}) must be below algo.mc_upper ({self.mc_upper}).")


@dataclass
class BudgetConfig:
    """How much compute, never which algorithm. Paper values are the `paper` budget.

    Score thresholds (minimal criterion, reproduction, solved) are set for 2000-step episodes
    and multiplied by `score_scale` (the paper budget: 1). A small budget may also set ePOET's
    transfer and reproduction intervals; null keeps the algorithm's (the paper's).
    """

    KEY: ClassVar[str] = "budget"

    name: str
    iterations: int                  # ES iterations (ePOET / ePOET-SAC)
    n_pairs: int                     # mirrored pairs per ES step (2 episodes each)
    episode_steps: int
    eval_episodes: int
    frames: int                      # environment frames for the RL baselines
    eval_every: int                  # RL baselines: frames between deterministic evaluations
    score_scale: float
    transfer_interval: Optional[int]     # null: the algorithm's
    reproduce_interval: Optional[int]    # null: the algorithm's
    sac_frames_per_iteration: Optional[int]  # ePOET-SAC; null: the algorithm's
    hours: Optional[float]           # wall-clock stop: hours of training over resumes; null: none

    def __post_init__(self) -> None:
        _positive(self, "iterations", "n_pairs", "episode_steps", "eval_episodes", "frames",
                  "eval_every", "score_scale")
        _check(self.hours is None or self.hours > 0,
               f"budget.hours must be > 0 or null, got {self.hours}.")
        for name in ("transfer_interval", "reproduce_interval", "sac_frames_per_iteration"):
            value = getattr(self, name)
            _check(value is None or value > 0, f"budget.{name} must be > 0 or null, got {value}.")

    def time_is_up(self, seconds: float) -> bool:
        """Whether `seconds` of training (summed over resumes) have used up `hours`."""
        return self.hours is not None and seconds >= self.hours * 3600.0


@dataclass
class WorkersConfig:
    """Where ES rollouts run: `local` is a process pool on this machine, `ray` a Ray cluster."""

    KEY: ClassVar[str] = "workers"

    backend: str
    num: Optional[int]               # None: one worker per available core (Ray: per cluster CPU)
    batch: int                       # robots per process (fits the cache: bench/rollout_throughput)
    address: Optional[str] = None    # ray: a running cluster's address; None starts a local Ray

    def __post_init__(self) -> None:
        _check(self.backend in ("local", "ray"),
               f"workers.backend must be 'local' or 'ray', got {self.backend!r}.")
        _check(self.num is None or self.num > 0, f"workers.num must be > 0, got {self.num}.")
        _positive(self, "batch")
        _check(self.address is None or self.backend == "ray",
               "workers.address is the Ray cluster to join, so it needs workers=ray.")
        _check(self.backend != "ray" or importlib.util.find_spec("ray") is not None,
               "workers=ray needs Ray, the 'distributed' extra: "
               "pip install -c constraints.txt -e '.[distributed]'.")


@dataclass
class TrackingConfig:
    """MLflow: the store defaults to sqlite:///<project root>/mlflow.db; MLFLOW_TRACKING_URI wins."""

    KEY: ClassVar[str] = "tracking"

    experiment: str
    uri: Optional[str]

    def __post_init__(self) -> None:
        _check(bool(self.experiment), "tracking.experiment must not be empty.")


@dataclass
class Config:
    """The root config (conf/config.yaml)."""

    KEY: ClassVar[str] = ""

    algo: Any                        # one of ALGO_SCHEMAS: its YAML file names its schema
    agent: AgentConfig
    terrain: TerrainConfig
    budget: BudgetConfig
    workers: WorkersConfig
    tracking: TrackingConfig
    seed: int
    checkpoint_every: int            # ES iterations, or collector batches (baselines), per checkpoint
    agent_choice: str                # best | final: which parameters of each pair a run exports
    evaluate: bool                   # evaluate the exported agent on the suite at the end
    resume: Optional[str]            # a run folder or checkpoint file to continue; "auto": this
                                     # job's own folder if it has a checkpoint (run.py)

    def __post_init__(self) -> None:
        _check(0 <= self.seed < 2**32, f"seed must be in [0, 2**32), got {self.seed}.")
        _positive(self, "checkpoint_every")
        _check(self.agent_choice in ("best", "final"),
               f"agent_choice must be 'best' or 'final', got {self.agent_choice!r}.")
        # One source of truth for the episode length: the budget (it also scales thresholds).
        _check(self.agent.max_episode_steps == self.budget.episode_steps,
               f"agent.max_episode_steps ({self.agent.max_episode_steps}) follows "
               f"budget.episode_steps ({self.budget.episode_steps}); set budget.episode_steps.")
        if isinstance(self.algo, SacConfig):
            _check(self.budget.frames >= self.algo.batch_size,
                   f"budget.frames ({self.budget.frames}) must be at least algo.batch_size "
                   f"({self.algo.batch_size}), or SAC never updates.")
        _check(self.workers.backend == "local" or isinstance(self.algo, PoetConfig),
               f"workers={self.workers.backend} runs ES rollouts, and algo={self.algo.name} "
               f"has none (it collects in-process): use workers=local.")
        if isinstance(self.algo, PoetConfig):
            _check(self.terrain.kind == "cppn",
                   f"algo={self.algo.name} evolves CPPN terrains, so it needs terrain=cppn "
                   f"(got terrain={self.terrain.kind}).")

    def unused_keys(self) -> tuple[str, ...]:
        """Dotted keys (and key prefixes) of settings this run never reads, so its MLflow params
        hold only what shaped it: ES budgets are iterations, the baselines' are frames."""
        unused = list(self.terrain.unused_keys())
        if isinstance(self.algo, PoetConfig):
            unused += ["budget.frames", "budget.eval_every"]
        else:
            unused += ["budget.iterations", "budget.n_pairs", "budget.transfer_interval",
                       "budget.reproduce_interval", "workers.batch", "workers.address"]
        if not isinstance(self.algo, EpoetSacConfig):
            unused.append("budget.sac_frames_per_iteration")
        return tuple(unused)


@dataclass
class SuiteConfig:
    """`python -m epoet.terrain.suite`: the fixed evaluation suite (docs/reference.md "Evaluation").

    Rounds of mutated CPPN children with a rising S; round r aims its children at level r
    (terrain/suite.py)."""

    KEY: ClassVar[str] = ""

    terrain: TerrainConfig
    agent: AgentConfig               # the course (start_x .. finish_x) the roughness is read along
    episode_ratio: float             # evaluation episodes last this x the agent's training ones
    seed: int
    children: int                    # children per round (lineages)
    max_heights: list[float]         # S of each round, metres: one round per entry
    max_tries: int                   # mutations tried per child before taking the closest
    out: Optional[str]               # None: the shipped suite folder
    check: bool                      # regenerate and compare with `out`, write nothing

    def __post_init__(self) -> None:
        _non_negative(self, "seed")
        _positive(self, "children", "max_tries", "episode_ratio")
        _check(len(self.max_heights) > 0 and all(0 < s <= self.terrain.max_height_limit
                                                 for s in self.max_heights),
               f"max_heights must be a non-empty list in (0, terrain.max_height_limit = "
               f"{self.terrain.max_height_limit}], got {self.max_heights}.")


@dataclass
class AgentCommandConfig:
    """What the commands that run a trained agent share (evaluate, render)."""

    KEY: ClassVar[str] = ""

    run: Optional[str]               # MLflow run id, run folder or policy file
    agent: AgentConfig               # episode rules for a bare policy file (a run brings its own)
    tracking: TrackingConfig
    suite: Optional[str]             # None: the shipped suite
    seed: int                        # keys the episodes' starts

    def __post_init__(self) -> None:
        _check(bool(self.run), "run is required: run=<MLflow run id | run folder | policy file>.")
        _non_negative(self, "seed")


@dataclass
class EvaluateConfig(AgentCommandConfig):
    """`python -m epoet.evaluate`: a trained agent on the evaluation suite."""

    episodes: int                    # per terrain
    solve_score: float               # "solved": finish line and this return (x the run's scale)
    action_samples: int              # actions kept per episode, for t-SNE
    processes: Optional[int]         # None: one per available core ("workers" is a config group)
    out: Optional[str]               # results folder; None: <run folder>/evaluation or ./evaluation

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "episodes")
        _non_negative(self, "action_samples")
        _check(self.processes is None or self.processes > 0,
               f"processes must be > 0 or null, got {self.processes}.")


@dataclass
class RenderConfig(AgentCommandConfig):
    """`python -m epoet.render`: an mp4 of a trained agent on one terrain."""

    terrain: Optional[str]           # a suite terrain's name or a terrain .npz file
    steps: Optional[int]             # None: the run's episode length
    width: int
    height: int
    out: Optional[str]               # None: videos/<run>_<terrain>.mp4

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(bool(self.terrain), "terrain is required: a suite terrain's name or an .npz file.")
        _positive(self, "width", "height")
        _check(self.steps is None or self.steps > 0, f"steps must be > 0, got {self.steps}.")


@dataclass
class GalleryConfig:
    """`python -m epoet.terrain`: a root terrain and its mutated descendants as one PNG grid."""

    KEY: ClassVar[str] = ""

    terrain: TerrainConfig
    seed: int
    n: int
    out: str

    def __post_init__(self) -> None:
        _non_negative(self, "seed")
        _positive(self, "n")


# --- RL baselines: PPO, SAC and VMPO (paper Tables 2-3, docs/reference.md) -----------------
# Sizes are per collector batch of `frames_per_batch` frames; budget.frames is the total. A budget
# smaller than one batch shrinks the batch and keeps the ratios (epochs per batch, SAC updates and
# random frames per collected frame): see `BatchPlan` in epoet/rl/.

RL_ACTIVATIONS = ("tanh", "relu", "elu")


def _check_network(obj: Any) -> None:
    """The checks of an RL network config (hidden sizes, activation, lr, discount)."""
    _check(len(obj.hidden) > 0 and all(h > 0 for h in obj.hidden),
           f"{_key(obj, 'hidden')} must be a non-empty list of positive sizes, got {obj.hidden}.")
    _check(obj.activation in RL_ACTIVATIONS,
           f"{_key(obj, 'activation')} must be one of {list(RL_ACTIVATIONS)}, got "
           f"{obj.activation!r}.")
    _positive(obj, "lr")
    _check(0.0 < obj.gamma <= 1.0, f"{_key(obj, 'gamma')} must be in (0, 1], got {obj.gamma}.")


@dataclass
class RlConfig:
    """What PPO and VMPO share: the networks, the optimiser and the collector batch."""

    KEY: ClassVar[str] = "algo"

    name: str
    hidden: list[int]
    activation: str
    lr: float                        # one Adam over all parameters (Table 2: policy = value lr)
    gamma: float
    frames_per_batch: int            # the paper's trajectory_length
    obs_norm: bool                   # running observation normalisation (PPO and VMPO in the paper)

    def __post_init__(self) -> None:
        _check_network(self)
        _positive(self, "frames_per_batch")


@dataclass
class OnPolicyConfig(RlConfig):
    """PPO and VMPO: GAE on each batch, then `epochs` passes of shuffled minibatches."""

    gae_lambda: float                # Table 2 calls it "tau"
    epochs: int
    minibatch: int
    critic_coeff: float
    max_grad_norm: Optional[float]   # not in the paper; None disables clipping

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

    clip: float
    entropy_coeff: float
    normalize_advantage: bool        # not in the paper; the common PPO implementation detail

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "clip")
        _non_negative(self, "entropy_coeff")


@dataclass
class VmpoConfig(OnPolicyConfig):
    """V-MPO (Song et al. 2019; docs/reference.md); see epoet/rl/vmpo.py."""

    top_fraction: float
    eta_init: float
    eps_eta: float
    alpha_init: float
    eps_alpha: float

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(0.0 < self.top_fraction <= 1.0,
               f"algo.top_fraction must be in (0, 1], got {self.top_fraction}.")
        _positive(self, "eta_init", "eps_eta", "alpha_init", "eps_alpha")


@dataclass
class SacLearnerConfig:
    """SAC's networks, losses and replay (paper Table 3: conf/learner/sac.yaml), shared by
    `algo=sac` and `algo=epoet_sac` (as `algo.sac`)."""

    KEY: ClassVar[str] = "algo.sac"

    hidden: list[int]
    activation: str
    lr: float                        # actor, critics and the entropy temperature
    gamma: float
    batch_size: int
    tau: float                       # soft target update rate
    alpha_init: float
    target_entropy: Optional[float]  # None: -(action dimensions), the usual heuristic
    reward_scale: float
    init_random_frames: int          # Table 3 pretrain_epoch 1: the first frames act uniformly
    buffer_size: int

    def __post_init__(self) -> None:
        _check_network(self)
        _positive(self, "batch_size", "alpha_init", "reward_scale", "buffer_size")
        _non_negative(self, "init_random_frames")
        _check(0.0 < self.tau <= 1.0, f"{_key(self, 'tau')} must be in (0, 1], got {self.tau}.")
        _check(self.buffer_size >= self.batch_size,
               f"{_key(self, 'buffer_size')} ({self.buffer_size}) must hold at least one batch "
               f"({_key(self, 'batch_size')}={self.batch_size}).")


@dataclass
class SacConfig(SacLearnerConfig):
    """`algo=sac`: the learner on its own TorchRL collector (paper Table 3)."""

    KEY: ClassVar[str] = "algo"

    name: str
    frames_per_batch: int            # the paper's trajectory_length
    obs_norm: bool                   # false: the paper normalises for PPO and VMPO only
    updates_per_batch: int           # gradient updates per collector batch

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "frames_per_batch", "updates_per_batch")


# --- ePOET-SAC (paper Section 3, Algorithms 1-3; docs/reference.md) ---------------------------

SAC_TERRAINS = ("pool", "bowl")
JOIN_MAPPINGS = ("distill", "random")


@dataclass
class DistillConfig:
    """Behaviour cloning between the SAC actor and ES agents (epoet/poet/sac_bridge.py)."""

    KEY: ClassVar[str] = "algo.distill"

    states: int                      # replay states per distillation
    epochs: int
    batch: int
    lr: float

    def __post_init__(self) -> None:
        _positive(self, "states", "epochs", "batch", "lr")


@dataclass
class EpoetSacConfig(PoetConfig):
    """ePOET plus a SAC learner trained every iteration (Algorithm 1's red steps)."""

    sac: SacLearnerConfig
    distill: DistillConfig
    frames_per_iteration: int        # SAC's own environment steps per ePOET iteration (Train_SAC)
    updates_per_frame: float         # gradient updates per SAC frame (paper: 1)
    es_episodes_per_pair: int        # ES-step episodes per active pair recorded into the replay
    sac_terrain: str                 # pool: a sampled active environment; bowl: the reference's
    mapping: str                     # the join's SAC actor -> ES mapping: distill | random
    join_every_transfers: int        # the join at t mod (k N_transfer) = k N_transfer - 2
    pretrain_iterations: int         # Train_SAC iterations before iteration 0 (reference: 500)

    def __post_init__(self) -> None:
        super().__post_init__()
        _positive(self, "frames_per_iteration", "join_every_transfers")
        _non_negative(self, "updates_per_frame", "es_episodes_per_pair", "pretrain_iterations")
        _check(self.sac_terrain in SAC_TERRAINS,
               f"algo.sac_terrain must be one of {list(SAC_TERRAINS)}, got {self.sac_terrain!r}.")
        _check(self.mapping in JOIN_MAPPINGS,
               f"algo.mapping must be one of {list(JOIN_MAPPINGS)}, got {self.mapping!r}.")
        # The SAC actor and the join exchange raw-observation policies with the ES pool.
        _check(self.es.obs_norm_episodes == 0,
               "algo.es.obs_norm_episodes must be 0 for algo=epoet_sac: observation "
               "normalisation is implemented for ePOET's ES only.")


# --- composition and validation -------------------------------------------------------------------

# conf/algo/<name>.yaml -> its schema
ALGO_SCHEMAS: dict[str, type] = {"epoet": PoetConfig, "epoet_sac": EpoetSacConfig,
                                 "ppo": PpoConfig, "sac": SacConfig, "vmpo": VmpoConfig}


def register_configs() -> None:
    """Make each dataclass the schema of its YAML file (type checks at composition)."""
    cs = ConfigStore.instance()
    cs.store(name="config_schema", node=Config)
    cs.store(name="gallery_schema", node=GalleryConfig)
    cs.store(name="suite_schema", node=SuiteConfig)
    cs.store(name="evaluate_schema", node=EvaluateConfig)
    cs.store(name="render_schema", node=RenderConfig)
    cs.store(group="agent", name="hexapod_schema", node=AgentConfig)
    cs.store(group="terrain", name="terrain_schema", node=TerrainConfig)
    cs.store(group="budget", name="budget_schema", node=BudgetConfig)
    cs.store(group="workers", name="workers_schema", node=WorkersConfig)
    cs.store(group="tracking", name="tracking_schema", node=TrackingConfig)
    for name, schema in ALGO_SCHEMAS.items():
        cs.store(group="algo", name=f"{name}_schema", node=schema)


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
    one sentence. The YAML's schema (and, for `algo`, the algorithm's) decides each node's type."""
    try:
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
    for key, source in _interpolated(OmegaConf.to_container(cfg, resolve=False)).items():
        message = re.sub(rf"(?<![\w.(]){re.escape(key)}(?![\w])", f"{source} ({key})", message)
    return message


def load(overrides: Sequence[str] = ()) -> Config:
    """The validated config of `python -m epoet <overrides>`: where code outside a run (tests,
    benches, notebooks) gets the defaults, which live in the YAML files only."""
    return validate(compose(overrides))
