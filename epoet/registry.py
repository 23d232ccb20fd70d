"""The algorithms: every `Algorithm` record (epoet.core.algorithm), imported by name.

An algorithm's record is a module-level value of the module that defines its schema, the
config.py of its package (epoet/<package>/config.py); `DECLARED` imports each one, so an
editor's "go to definition" and a type checker follow `algo=sac` from here to its schema and,
through the record's `runner`, to its training. Schema modules are light (no torch, no
MuJoCo): importing them costs composition nothing it did not import already
(tests/test_architecture.py holds them below epoet/config.py). Code outside epoet/ (a test, a
notebook) adds its own algorithm with `register`.
"""

from __future__ import annotations

from epoet.core.algorithm import Algorithm, Family
from epoet.core.schema import ConfigError
from epoet.epoet_sac.config import EPOET_SAC
from epoet.open_ended.config import EPOET
from epoet.ppo.config import PPO
from epoet.sac.config import SAC
from epoet.vmpo.config import VMPO

DECLARED = (EPOET, EPOET_SAC, PPO, SAC, VMPO)  # a new algorithm adds its record here
_records: dict[str, Algorithm] = {}


def _add(records: dict[str, Algorithm], record: Algorithm) -> None:
    other = records.get(record.name)
    if other is not None and other != record:
        raise ValueError(f"two algorithms are named {record.name!r}: {other} and {record}.")
    records[record.name] = record


for _record in DECLARED:
    _add(_records, _record)


def register(record: Algorithm) -> None:
    """Add an algorithm declared outside epoet/, before the config is composed (its runner
    must be importable where it runs)."""
    _add(_records, record)


def algorithms(family: Family | None = None) -> list[Algorithm]:
    """Every algorithm (of `family`), in table and legend order: by family, then by name."""
    order = list(Family)
    return sorted(
        (r for r in _records.values() if family in (None, r.family)),
        key=lambda r: (order.index(r.family), r.name),
    )


def names(family: Family | None = None) -> list[str]:
    """The algorithms' names (of `family`), in table and legend order."""
    return [r.name for r in algorithms(family)]


def algorithm(name: str) -> Algorithm:
    """The record named `name`; ConfigError naming the algorithms there are."""
    record = _records.get(name)
    if record is None:
        raise ConfigError(f"unknown algorithm {name!r} (available: {', '.join(names())})")
    return record
