"""CPPN-NEAT terrains (`terrain.kind=cppn`, ePOET's): a random bowl mixed with the heights of an
evolving CPPN, real neat-python 2.0 genomes evaluated over a grid with numpy.

Conventions (fixed here, used everywhere in the package):
- Inputs: node -1 is x, node -2 is y. On a terrain the inputs are metres from
  `terrain.cppn_origin` times `terrain.cppn_scale` (`field_inputs`): the reference's coordinates,
  so a genome makes features of the same size in metres at any grid resolution. The validity
  rules look at the genome on its own check grid over [-1, 1) CPPN units (`check_inputs`), as
  the reference does. Output: node 0.
- neat-python draws from the global `random` module. Genome creation and mutation run inside
  `seeded_random(seed)`, which seeds the global generator and restores its previous state
  afterwards, so every genome is a function of its seed and callers' random streams are
  untouched. (Not thread-safe: neat's module functions are bound to the one global generator.)
- Node keys and innovation numbers are drawn from a fresh genome config per operation, started
  after the parent's largest key/innovation, so a child does not depend on what was created
  earlier in the process. (New genes get keys above all of the parent's, which is what the
  parent-child distance needs; unrelated genomes may reuse keys, which would only matter for
  crossover, and CPPNs are never crossed over: paper appendix "Generated Environments".)
"""

from __future__ import annotations

import copy
import random
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import fields

import neat
import numpy as np
from neat.graphs import feed_forward_layers

from epoet.terrain.bowl import bowl_of
from epoet.terrain.config import (
    REFERENCE_GRID,
    CppnConfig,
    MutationConfig,
    MutationError,
    TerrainConfig,
    register,
)
from epoet.terrain.terrain import normalize

INPUT_KEYS = (-1, -2)  # x, y
OUTPUT_KEY = 0


class CppnMutationError(MutationError):
    """No valid child CPPN was found within `mutation.max_tries` attempts."""


def genome_config(cfg: CppnConfig) -> neat.genome.DefaultGenomeConfig:
    """neat's genome config built from the schema (no config file), with a fresh tracker.

    Only the [DefaultGenome] section is needed: there is no Population (ePOET replaces NEAT's
    fitness-driven reproduction with PATA-EC), so species/stagnation/reproduction settings
    would be unused.
    """
    params = {}
    for f in fields(CppnConfig):
        value = getattr(cfg, f.name)
        if isinstance(value, list):
            params[f.name] = " ".join(value)
        else:
            params[f.name] = str(value)
    gc = neat.DefaultGenome.parse_config(params)
    gc.innovation_tracker = neat.InnovationTracker()
    return gc


@contextmanager
def seeded_random(seed: int) -> Iterator[None]:
    """Run neat-python (which uses the global `random`) deterministically from `seed`."""
    saved = random.getstate()
    random.seed(seed)
    try:
        yield
    finally:
        random.setstate(saved)


def new_genome(cfg: CppnConfig, seed: int) -> neat.DefaultGenome:
    """A root CPPN: neat's initial genome (Table 5: 2 hidden nodes, full_nodirect).

    As in the reference, the root's output activation is set to sin; its response stays at
    neat's initial value (1.0), so roots are smooth and complexity comes from mutation. Children
    keep whatever output activation mutation gives them (the reference forces sin on the root
    only).
    """
    gc = genome_config(cfg)
    genome = neat.DefaultGenome(0)
    with seeded_random(seed):
        genome.configure_new(gc)
    genome.nodes[OUTPUT_KEY].activation = "sin"
    return genome


def field_inputs(
    grid: int, size: float, origin: Sequence[float], scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) CPPN inputs at a terrain's (grid, grid) samples: rows follow y, columns x.

    The samples span `size` metres centred at the origin (MuJoCo's hfield layout); each input is
    the sample's metres from `origin`, times `scale` CPPN units per metre.
    """
    axis = np.linspace(-size / 2.0, size / 2.0, grid)
    return np.meshgrid((axis - origin[0]) * scale, (axis - origin[1]) * scale, indexing="xy")


def check_inputs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference's check grid: (i - n/2) / (n/2) for i < n on both inputs, so [-1, 1) with
    the first point at (-1, -1)."""
    axis = (np.arange(n) - n / 2.0) / (n / 2.0)
    return np.meshgrid(axis, axis, indexing="xy")


def _clip60(z: np.ndarray) -> np.ndarray:
    return np.clip(z, -60.0, 60.0)


# numpy versions of neat.activations, formula for formula (same clipping), so the vectorised
# evaluation equals FeedForwardNetwork.activate to the last bit or within an ulp of exp/sin.
_ACTIVATIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "sigmoid": lambda z: 1.0 / (1.0 + np.exp(-_clip60(5.0 * z))),
    "tanh": lambda z: np.tanh(_clip60(2.5 * z)),
    "sin": lambda z: np.sin(_clip60(5.0 * z)),
    "gauss": lambda z: np.exp(-5.0 * np.clip(z, -3.4, 3.4) ** 2),
    "relu": lambda z: np.where(z > 0.0, z, 0.0),
    "elu": lambda z: np.where(z > 0.0, z, np.exp(np.minimum(z, 0.0)) - 1),
    "lelu": lambda z: np.where(z > 0.0, z, 0.005 * z),
    "selu": lambda z: np.where(
        z > 0.0,
        1.0507009873554804934193349852946 * z,
        1.0507009873554804934193349852946
        * 1.6732632423543772848170429916717
        * (np.exp(np.minimum(z, 0.0)) - 1),
    ),
    "softplus": lambda z: 0.2 * np.log(1 + np.exp(_clip60(5.0 * z))),
    "identity": lambda z: z,
    "clamped": lambda z: np.clip(z, -1.0, 1.0),
    "inv": lambda z: np.where(z == 0.0, 0.0, 1.0 / np.where(z == 0.0, 1.0, z)),
    "log": lambda z: np.log(np.maximum(1e-7, z)),
    "exp": lambda z: np.exp(_clip60(z)),
    "abs": np.abs,
    "hat": lambda z: np.maximum(0.0, 1 - np.abs(z)),
    "square": lambda z: z**2,
    "cube": lambda z: z**3,
}


def _aggregate(name: str, terms: list[np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
    """neat.aggregations over per-link arrays, accumulated left to right like Python's sum."""
    if name == "sum":
        total = np.zeros(shape)
        for t in terms:
            total = total + t
        return total
    if name == "product":
        total = np.ones(shape)
        for t in terms:
            total = total * t
        return total
    if not terms:
        return np.zeros(shape)
    if name == "max":
        return np.max(terms, axis=0)
    if name == "min":
        return np.min(terms, axis=0)
    if name == "mean":
        return _aggregate("sum", terms, shape) / len(terms)
    raise ValueError(f"CPPN aggregation {name!r} is not supported by the vectorised evaluator.")


def evaluate(genome: neat.DefaultGenome, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The genome's output at every (x, y), exactly as neat's FeedForwardNetwork computes it.

    Same node order (neat.graphs.feed_forward_layers over the enabled connections), same link
    order (the genome's connection order) and node value
    activation(bias + response * aggregation(weight_i * input_i)). Overflow gives inf/nan
    instead of neat's OverflowError; callers treat non-finite output as invalid.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"CPPN inputs x {x.shape} and y {y.shape} must have the same shape.")
    connections = [cg.key for cg in genome.connections.values() if cg.enabled]
    layers, required = feed_forward_layers(list(INPUT_KEYS), [OUTPUT_KEY], connections)
    readable = required | set(INPUT_KEYS)
    values = {INPUT_KEYS[0]: x, INPUT_KEYS[1]: y, OUTPUT_KEY: np.zeros(x.shape)}
    with np.errstate(all="ignore"):
        for layer in layers:
            for node in layer:
                terms = [
                    values[i] * genome.connections[(i, o)].weight
                    for i, o in connections
                    if o == node and i in readable
                ]
                gene = genome.nodes[node]
                act = _ACTIVATIONS.get(gene.activation)
                if act is None:
                    raise ValueError(
                        f"CPPN node {node} uses activation {gene.activation!r}, "
                        "which the vectorised evaluator does not support."
                    )
                s = _aggregate(gene.aggregation, terms, x.shape)
                values[node] = act(gene.bias + gene.response * s)
    return values[OUTPUT_KEY]


def has_input_output_path(genome: neat.DefaultGenome) -> bool:
    """Validity rule (a): some input reaches the output through enabled connections."""
    reached = set(INPUT_KEYS)
    edges = [cg.key for cg in genome.connections.values() if cg.enabled]
    grew = True
    while grew:
        new = {o for i, o in edges if i in reached and o not in reached}
        reached |= new
        grew = bool(new)
    return OUTPUT_KEY in reached


def _fresh_counters(gc: neat.genome.DefaultGenomeConfig, parent: neat.DefaultGenome) -> None:
    """Start node keys and innovation numbers after the parent's, independent of history."""
    gc.node_indexer = None  # neat restarts it at max(node keys) + 1
    last = max((cg.innovation for cg in parent.connections.values()), default=0)
    gc.innovation_tracker = neat.InnovationTracker(start_number=last)


def _rescaled_response(peak: float, rules: MutationConfig) -> float | None:
    """The reference's output-response reset for a peak outside the allowed range, else None."""
    if peak < rules.response_rescale_low:
        return random.uniform(*rules.small_peak_response) / peak
    if peak > rules.response_rescale_high:
        return random.uniform(*rules.large_peak_response) / peak
    return None


def mutate_genome(
    parent: neat.DefaultGenome,
    cppn: CppnConfig,
    rules: MutationConfig,
    seed: int,
    field: tuple[np.ndarray, np.ndarray],
) -> neat.DefaultGenome:
    """A mutated child that passes the reference's validity rules (docs/reference.md).

    Each attempt copies the parent, sets the output response to `rules.output_response` (the
    reference), applies one neat mutation, and accepts it if (a) an input-output path exists,
    (b) its distance to the parent exceeds `min_genome_distance`, (c) on the check grid the
    output minus its value at the first point has max > min_range and variance > min_variance,
    and the output is finite on the terrain's inputs `field` (our addition: chained square/inv
    nodes can overflow). Then, as the reference does, a peak below `response_rescale_low` sets
    the output response to U(small_peak_response) / peak and one above `response_rescale_high`
    to U(large_peak_response) / peak, drawn from the same seeded stream.
    """
    gc = genome_config(cppn)
    check_x, check_y = check_inputs(rules.check_grid)
    with seeded_random(seed):
        for _ in range(rules.max_tries):
            child = copy.deepcopy(parent)
            child.key = parent.key + 1
            child.fitness = None
            child.nodes[OUTPUT_KEY].response = rules.output_response
            _fresh_counters(gc, parent)
            child.mutate(gc)
            if not has_input_output_path(child):
                continue
            if parent.distance(child, gc) <= rules.min_genome_distance:
                continue
            out = evaluate(child, check_x, check_y)
            shifted = out - out.flat[0]
            peak = float(np.max(shifted))
            if not (
                np.all(np.isfinite(out))
                and peak > rules.min_range
                and float(np.var(shifted)) > rules.min_variance
            ):
                continue
            if not np.all(np.isfinite(evaluate(child, *field))):
                continue
            response = _rescaled_response(peak, rules)
            if response is not None:
                child.nodes[OUTPUT_KEY].response = response
            return child
    raise CppnMutationError(
        f"no valid CPPN child in {rules.max_tries} tries (seed {seed}); relax "
        "terrain.mutation (min_genome_distance, min_range, min_variance) or raise max_tries."
    )


def fingerprint(genome: neat.DefaultGenome) -> str:
    """A canonical text of the genome's genes, for content-derived terrain ids."""
    nodes = [
        f"n{k}:{g.activation}:{g.aggregation}:{g.bias!r}:{g.response!r}"
        for k, g in sorted(genome.nodes.items())
    ]
    conns = [
        f"c{k[0]},{k[1]}:{g.weight!r}:{g.enabled}" for k, g in sorted(genome.connections.items())
    ]
    return ";".join(nodes + conns)


# --- the generator ----------------------------------------------------------------------------


def cppn_inputs(cfg: TerrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """The CPPN's (x, y) inputs at the terrain's samples (the reference's metres per unit)."""
    return field_inputs(cfg.grid, cfg.size, cfg.cppn_origin, cfg.cppn_scale)


def mix(bowl: np.ndarray, cppn: np.ndarray, bowl_weight: float) -> np.ndarray:
    """normalize(w * normalize(bowl) + (1 - w) * normalize(cppn)), in [0, 1] (paper: w = 0.3)."""
    if not 0.0 <= bowl_weight <= 1.0:
        raise ValueError(f"bowl_weight must be in [0, 1], got {bowl_weight}.")
    return normalize(bowl_weight * normalize(bowl) + (1.0 - bowl_weight) * normalize(cppn))


def render_reference(
    genome: neat.DefaultGenome, seed: int, max_height: float, grid: int = REFERENCE_GRID
) -> np.ndarray:
    """`genome` as the reference rendered it (reference_rendering.py: the CPPN read in a window,
    each row drifting beyond it, the step where it ends), at relief S = `max_height`, on the
    reference's 200 x 200 samples, resampled (linearly, corner to corner) to `grid` per side."""
    # numba (the reference rendering's kernel) and scipy.ndimage are imported on first use, as
    # in bowl.py: a composed config checks its kind by this module without rendering anything.
    from scipy import ndimage

    from epoet.terrain.reference_rendering import reference_inputs
    from epoet.terrain.reference_rendering import render as reference_render

    heights = reference_render(evaluate(genome, *reference_inputs()), seed, max_height)
    if grid == REFERENCE_GRID:
        return heights
    at = np.linspace(0.0, REFERENCE_GRID - 1.0, grid)
    rows, cols = np.meshgrid(at, at, indexing="ij")
    return np.clip(ndimage.map_coordinates(heights, [rows, cols], order=1), 0.0, 1.0)


class CppnGenerator:
    """`terrain.kind=cppn`: the bowl mixed with a CPPN genome's heights (`bowl_weight`); children
    are valid mutations of the genome (`mutate_genome`)."""

    kind = "cppn"
    evolves = True
    unused_keys: tuple[str, ...] = ()

    def encode(self, cfg: TerrainConfig, seed: int) -> neat.DefaultGenome:
        return new_genome(cfg.cppn, seed)

    def mutate(
        self, cfg: TerrainConfig, parent: neat.DefaultGenome, seed: int
    ) -> neat.DefaultGenome:
        return mutate_genome(parent, cfg.cppn, cfg.mutation, seed, cppn_inputs(cfg))

    def render(
        self, cfg: TerrainConfig, genome: neat.DefaultGenome, seed: int, max_height: float
    ) -> np.ndarray:
        if cfg.rendering == "reference":
            return render_reference(genome, seed, max_height, cfg.grid)
        cppn = evaluate(genome, *cppn_inputs(cfg))
        if not np.all(np.isfinite(cppn)):
            raise ValueError(
                f"the CPPN genome gives non-finite heights on the {cfg.grid} x {cfg.grid} grid."
            )
        return mix(bowl_of(cfg, seed, max_height), cppn, cfg.bowl_weight)

    def describe(self, genome: neat.DefaultGenome) -> str:
        return fingerprint(genome)

    def check(self, genome: object) -> None:
        if not isinstance(genome, neat.DefaultGenome):
            raise ValueError("a 'cppn' terrain needs its CPPN genome (a neat DefaultGenome).")


register(CppnGenerator())
