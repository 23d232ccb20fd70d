"""What "the same loop state" means for the ePOET and ePOET-SAC tests: every entry of two
checkpoints' `open_ended` states equal, wall and CPU time aside."""

from __future__ import annotations

import dataclasses
from typing import Any

import neat
import numpy as np
import torch
from tensordict import TensorDictBase

from epoet.terrain.cppn import fingerprint

CLOCKS = ("elapsed", "cpu_time")  # wall and CPU seconds, never equal between two runs


def assert_same_state(a: dict[str, Any], b: dict[str, Any]) -> None:
    """Counters, transfers, the run's best score, and for every pair (active and archived, in
    order) its environment (the genome by its genes), optimiser, scores, best score and best
    parameters; and whatever else the loop keeps (ePOET-SAC's joins, replay mix and SAC state).
    Lists must have the same length; arrays and tensors equal bit for bit."""
    assert a.keys() == b.keys()
    for key in a.keys() - set(CLOCKS):
        _assert_same(a[key], b[key], key)


def _assert_same(a: Any, b: Any, where: str) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), f"{where}: lengths {len(a)}, {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, TensorDictBase):  # ePOET-SAC's replay storage
        assert isinstance(b, TensorDictBase) and a.batch_size == b.batch_size, where
        _assert_same(a.to_dict(), b.to_dict(), where)
    elif isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor), where
        np.testing.assert_array_equal(a.numpy(), b.numpy(), err_msg=where)
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, neat.DefaultGenome):
        assert fingerprint(a) == fingerprint(b), where
    elif dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for field in dataclasses.fields(a):
            _assert_same(getattr(a, field.name), getattr(b, field.name), f"{where}.{field.name}")
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"
