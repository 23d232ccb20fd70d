"""Terrain settings (conf/terrain/): the heightfield, its bowl and CPPN parts, CPPN mutation, and
the kinds of terrain `terrain.kind` chooses from: the generator interface and its registry.

The registry is the set of allowed kinds, so it lives here, in the schema module, where
`TerrainConfig` checks a kind before any work starts (docs/architecture.md, "Adding a terrain
generator"). Each generator's module registers it when imported; `generator_for` imports
`epoet/terrain/<kind>.py` on first use, so a new kind is that module and its
conf/terrain/<kind>.yaml.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Protocol

import numpy as np

from epoet.core.schema import ConfigError, check, non_negative, positive


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
        check(
            self.num_inputs == 2 and self.num_outputs == 1,
            "terrain.cppn must map 2 inputs (x, y) to 1 output (height).",
        )
        non_negative(self, "num_hidden")
        known = {
            "identity",
            "sin",
            "sigmoid",
            "square",
            "tanh",
            "gauss",
            "relu",
            "abs",
            "exp",
            "log",
            "inv",
            "clamped",
            "cube",
            "hat",
            "softplus",
            "elu",
            "lelu",
            "selu",
        }
        unknown = sorted(set(self.activation_options) - known)
        check(not unknown, f"terrain.cppn.activation_options has unknown activations {unknown}.")
        # The vectorised CPPN evaluator (epoet/terrain/cppn.py) implements these neat built-ins.
        unknown = sorted(set(self.aggregation_options) - {"sum", "product", "max", "min", "mean"})
        check(
            not unknown, f"terrain.cppn.aggregation_options has unsupported aggregations {unknown}."
        )


@dataclass
class MutationConfig:
    """Validity rules for mutated CPPN children (docs/reference.md, the reference's rules)."""

    KEY: ClassVar[str] = "terrain.mutation"

    min_genome_distance: float
    check_grid: int  # samples per side of the check grid, in CPPN units
    min_range: float  # max of (output - output at the first point) must exceed this
    min_variance: float
    response_rescale_low: float  # a peak below low resets the output response to
    small_peak_response: list[float]  # U(lo, hi) / peak,
    response_rescale_high: float  # a peak above high resets it to
    large_peak_response: list[float]  # U(lo, hi) / peak (the reference's two rules)
    output_response: float  # the reference sets the output node's response before mutating
    max_tries: int  # with no connection mutations, deep genomes need many tries

    def __post_init__(self) -> None:
        positive(self, "check_grid", "max_tries", "response_rescale_low", "response_rescale_high")
        for name in ("small_peak_response", "large_peak_response"):
            lo_hi = getattr(self, name)
            check(
                len(lo_hi) == 2 and 0.0 < lo_hi[0] <= lo_hi[1],
                f"terrain.mutation.{name} must be [low, high] with 0 < low <= high, got "
                f"{list(lo_hi)}.",
            )
        non_negative(self, "min_genome_distance", "min_range", "min_variance")


RENDERINGS = ("clean", "reference")  # terrain.rendering: how a CPPN environment becomes heights
# The field the reference's rendering is defined on (reference_rendering.py): 200 x 200 samples
# over 40 m, 5 per metre (another grid over the same 40 m gets it resampled).
REFERENCE_GRID, REFERENCE_SIZE = 200, 40.0


@dataclass
class TerrainConfig:
    """The heightfield: extent, resolution, the bowl part, the CPPN part and the height schedule."""

    KEY: ClassVar[str] = "terrain"

    kind: str  # bowl | cppn
    grid: int  # samples per side
    size: float  # metres per side (square terrain centred at the origin)
    base: float  # hfield base thickness below height 0 (metres)
    max_height: float  # initial maximum height S (metres)
    max_height_step: float  # +S per iteration (paper)
    max_height_limit: float  # cap on S (reference)
    bowl_weight: float  # heightmap = w bowl + (1 - w) CPPN; 1.0 = bowl only
    rendering: (
        str  # clean | reference: a CPPN environment's heights (cppn.py, reference_rendering.py)
    )
    cppn_scale: float  # CPPN input units per metre (the reference's feature size)
    cppn_origin: list[float]  # (x, y) metres where the CPPN's input is (0, 0)
    bump_grid: int
    bump_low: float
    bump_high: float
    cppn: CppnConfig
    mutation: MutationConfig

    def __post_init__(self) -> None:
        generator_for(self.kind)  # a ConfigError naming the kinds if there is none
        positive(self, "grid", "size", "base", "bump_grid", "max_height_limit", "cppn_scale")
        non_negative(self, "max_height", "max_height_step")
        check(self.grid >= 8, f"terrain.grid must be >= 8 samples, got {self.grid}.")
        check(
            0.0 <= self.bowl_weight <= 1.0,
            f"terrain.bowl_weight must be in [0, 1], got {self.bowl_weight}.",
        )
        check(
            0.0 < self.bump_low <= self.bump_high,
            f"terrain.bump_low/bump_high must satisfy 0 < low <= high, got "
            f"{self.bump_low}/{self.bump_high}.",
        )
        check(
            len(self.cppn_origin) == 2,
            f"terrain.cppn_origin must be [x, y] metres, got {list(self.cppn_origin)}.",
        )
        check(
            self.rendering in RENDERINGS,
            f"terrain.rendering must be {' or '.join(map(repr, RENDERINGS))}, "
            f"got {self.rendering!r}.",
        )
        if self.rendering == "reference":
            check(
                self.size == REFERENCE_SIZE,
                f"terrain.rendering=reference is defined on the reference's field, "
                f"terrain.size={REFERENCE_SIZE:g} metres; got {self.size:g}.",
            )
        check(
            self.max_height <= self.max_height_limit,
            f"terrain.max_height ({self.max_height}) exceeds terrain.max_height_limit "
            f"({self.max_height_limit}).",
        )

    def reaching(self, *heights: float) -> TerrainConfig:
        """This config with a heightfield tall enough for terrains of these S: the env's
        heightfield is compiled from `max_height_limit`, so a terrain above it does not fit."""
        return replace(self, max_height_limit=max(self.max_height_limit, *heights))

    def unused_keys(self) -> tuple[str, ...]:
        """The settings this terrain's generator never reads (the bowl: the CPPN's)."""
        return generator_for(self.kind).unused_keys


# --- the kinds of terrain ---------------------------------------------------------------------


class MutationError(RuntimeError):
    """A generator found no valid child of an environment within its tries."""


class TerrainGenerator(Protocol):
    """A kind of terrain: how an environment is encoded, mutated and rendered to a heightmap.

    ePOET keeps each environment's encoding (its genome; None for a kind that has none) and
    renders it anew every iteration with a fresh seed and the schedule's S; reproduction mutates
    it. Novelty needs nothing of the generator: PATA-EC ranks the agents on the rendered
    terrain. uber-research/poet has the same seam: an environment's config, its mutation, and
    the niche that builds the environment from it."""

    kind: str  # its `terrain.kind`, stored in terrain files and ids
    evolves: bool  # whether `mutate` makes children (ePOET needs a kind that evolves)
    unused_keys: tuple[str, ...]  # the settings of conf/terrain/ it never reads

    def encode(self, cfg: TerrainConfig, seed: int) -> Any:
        """The root encoding of a new lineage, a function of `seed`."""
        ...

    def mutate(self, cfg: TerrainConfig, parent: Any, seed: int) -> Any:
        """A valid child of `parent`, a function of `seed`; MutationError when none is found."""
        ...

    def render(self, cfg: TerrainConfig, genome: Any, seed: int, max_height: float) -> np.ndarray:
        """The (grid, grid) heights in [0, 1] of `genome` at relief S = `max_height`, its random
        parts (the bowl's) drawn from `seed`."""
        ...

    def describe(self, genome: Any) -> str:
        """A canonical text of the encoding, equal for equal environments: a terrain's id digests
        it, so saved terrains name what made them."""
        ...

    def check(self, genome: Any) -> None:
        """ValueError in one sentence unless `genome` is an encoding of this kind."""
        ...


GENERATORS: dict[str, TerrainGenerator] = {}  # terrain.kind -> its generator
_MODULE_NAME = re.compile(r"[a-z_][a-z0-9_]*")


def register(generator: TerrainGenerator) -> TerrainGenerator:
    """Make `generator` the one of its kind (its module calls this when imported)."""
    GENERATORS[generator.kind] = generator
    return generator


def generator_for(kind: str, key: str = "terrain.kind") -> TerrainGenerator:
    """The generator of `kind`, its module epoet/terrain/<kind>.py imported on first use;
    ConfigError naming `key` and the registered kinds if there is none."""
    if (
        kind not in GENERATORS
        and _MODULE_NAME.fullmatch(kind)
        and importlib.util.find_spec(f"epoet.terrain.{kind}") is not None
    ):
        importlib.import_module(f"epoet.terrain.{kind}")
    if kind not in GENERATORS:
        *others, last = sorted(GENERATORS)
        choices = f"{', '.join(map(repr, others))} or {last!r}" if others else repr(last)
        raise ConfigError(f"{key} must be {choices}, got {kind!r}.")
    return GENERATORS[kind]


def evolving_kinds() -> list[str]:
    """The registered kinds ePOET can evolve."""
    return sorted(kind for kind, generator in GENERATORS.items() if generator.evolves)
