"""Reading the authors' pickles without their code.

Their CPPN genomes are pickled neat-python 0.92 genomes (classes of their `poet_distributed`
package and of neat 0.92) and their observation normalisers pickled objects of their own
`torchrl` package; neither package is installable. `read_pickle` rebuilds any such object as a
`Record` of its attributes (numpy arrays are the only real classes allowed), so unpickling runs
none of their code and imports nothing of theirs.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

import neat
import numpy as np

from epoet.eval.reference.files import ReferenceFileError

try:  # numpy's array reconstruction; numpy 2 moved the module its pickles name
    from numpy._core import multiarray as _multiarray
except ImportError:  # numpy 1
    from numpy.core import multiarray as _multiarray  # type: ignore[no-redef]  # the same module

_NUMPY: dict[tuple[str, str], Any] = {
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
}
for _module in ("numpy.core.multiarray", "numpy._core.multiarray"):
    _NUMPY[(_module, "_reconstruct")] = _multiarray._reconstruct
    _NUMPY[(_module, "scalar")] = _multiarray.scalar


class Record:
    """An object of a class we do not import: its class name and its attributes."""

    cls: str = ""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args

    def __setstate__(self, state: Any) -> None:
        if isinstance(state, tuple) and len(state) == 2:  # (dict, slots)
            state = {**(state[0] or {}), **(state[1] or {})}
        if not isinstance(state, dict):
            raise pickle.UnpicklingError(f"{self.cls} has a state that is not a dict")
        self.__dict__.update(state)


class _Unpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _NUMPY:
            return _NUMPY[(module, name)]
        return type(name, (Record,), {"cls": f"{module}.{name}"})


def read_pickle(path: Path) -> Any:
    """The pickled object, with every non-numpy class a Record; ReferenceFileError if the file
    is not a readable pickle."""
    try:
        return _Unpickler(io.BytesIO(Path(path).read_bytes())).load()
    except (
        OSError,
        pickle.UnpicklingError,
        EOFError,
        AttributeError,
        ValueError,
        TypeError,
        IndexError,
    ) as err:
        raise ReferenceFileError(f"{path} is not a readable pickle ({err}).") from None


def _float(record: Record, name: str, path: Path) -> float:
    value = getattr(record, name, None)
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise ReferenceFileError(f"{path} is not a neat genome: a gene has no numeric {name}.")
    return float(value)


def read_genome(path: Path) -> dict[str, Any]:
    """A pickled neat 0.92 CPPN genome as plain data: {"nodes": [[key, bias, response,
    activation, aggregation], ...], "connections": [[in, out, weight, enabled], ...]} in the
    genome's own order (which fixes the order neat sums a node's inputs in)."""
    genome = read_pickle(path)
    nodes, connections = getattr(genome, "nodes", None), getattr(genome, "connections", None)
    if not (
        isinstance(genome, Record) and isinstance(nodes, dict) and isinstance(connections, dict)
    ):
        raise ReferenceFileError(f"{path} is not a pickled neat genome (no nodes and connections).")
    node_rows = []
    for key, gene in nodes.items():
        activation, aggregation = (
            getattr(gene, "activation", None),
            getattr(gene, "aggregation", None),
        )
        if not (
            isinstance(key, int) and isinstance(activation, str) and isinstance(aggregation, str)
        ):
            raise ReferenceFileError(f"{path} is not a neat genome: node {key!r} is malformed.")
        node_rows.append(
            [
                key,
                _float(gene, "bias", path),
                _float(gene, "response", path),
                activation,
                aggregation,
            ]
        )
    connection_rows = []
    for key, gene in connections.items():
        if not (
            isinstance(key, tuple)
            and len(key) == 2
            and all(isinstance(k, int) for k in key)
            and isinstance(getattr(gene, "enabled", None), bool)
        ):
            raise ReferenceFileError(
                f"{path} is not a neat genome: connection {key!r} is malformed."
            )
        connection_rows.append([key[0], key[1], _float(gene, "weight", path), gene.enabled])
    if 0 not in nodes:
        raise ReferenceFileError(f"{path} is not a CPPN genome: it has no output node 0.")
    return {"nodes": node_rows, "connections": connection_rows}


def to_neat(genome: dict[str, Any]) -> neat.DefaultGenome:
    """The plain genome as a neat-python 2.0 genome (what epoet.terrain.cppn evaluates)."""
    out = neat.DefaultGenome(0)
    for key, bias, response, activation, aggregation in genome["nodes"]:
        node = neat.genes.DefaultNodeGene(int(key))
        node.bias, node.response = float(bias), float(response)
        node.activation, node.aggregation = str(activation), str(aggregation)
        out.nodes[int(key)] = node
    for innovation, (i, o, weight, enabled) in enumerate(genome["connections"], start=1):
        gene = neat.genes.DefaultConnectionGene((int(i), int(o)), innovation=innovation)
        gene.weight, gene.enabled = float(weight), bool(enabled)
        out.connections[(int(i), int(o))] = gene
    return out


def read_normaliser(path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """An observation normaliser of the authors' torchrl: (mean, var, clip); it computed
    clip((obs - mean) / (sqrt(var) + 1e-4), -clip, clip)."""
    norm = read_pickle(path)
    mean, var, clip = (getattr(norm, k, None) for k in ("_mean", "_var", "clip"))
    if not (
        isinstance(mean, np.ndarray)
        and isinstance(var, np.ndarray)
        and mean.shape == var.shape
        and mean.ndim == 1
        and isinstance(clip, (int, float))
    ):
        raise ReferenceFileError(
            f"{path} is not an observation normaliser of the reference's "
            f"torchrl (no _mean, _var arrays and clip)."
        )
    return mean.astype(np.float64), var.astype(np.float64), float(clip)
