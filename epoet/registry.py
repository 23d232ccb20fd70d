"""The algorithms: every `Algorithm` record (epoet.core.algorithm), found without a list.

An algorithm's record is a module-level value of the module that defines its schema, the
config.py of its package (epoet/open_ended/config.py: ePOET; epoet/rl/config.py: PPO, SAC and VMPO),
so `_declared` imports each epoet/<package>/config.py and keeps the records whose schema that
module defines: a new package with a record in its config.py is found, and nothing else names
it. Schema modules are light (no torch, no MuJoCo), so finding the records costs composition
nothing it did not import already. Code outside epoet/ (a test, a notebook) adds its own
algorithm with `register`.
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path

from epoet.core.algorithm import Algorithm, Family
from epoet.core.schema import ConfigError

PACKAGE = Path(__file__).resolve().parent
_records: dict[str, Algorithm] = {}


def _declared() -> dict[str, Algorithm]:
    """The records the packages of epoet/ declare, by name."""
    found: dict[str, Algorithm] = {}
    for path in sorted(PACKAGE.glob("*/config.py")):
        module = import_module(f"epoet.{path.parent.name}.config")
        for value in vars(module).values():
            if isinstance(value, Algorithm) and value.schema.__module__ == module.__name__:
                _add(found, value)
    return found


def _add(records: dict[str, Algorithm], record: Algorithm) -> None:
    other = records.get(record.name)
    if other is not None and other != record:
        raise ValueError(f"two algorithms are named {record.name!r}: {other} and {record}.")
    records[record.name] = record


def _all() -> dict[str, Algorithm]:
    if not _records:
        _records.update(_declared())
    return _records


def register(record: Algorithm) -> None:
    """Add an algorithm declared outside epoet/, before the config is composed (its runner
    must be importable where it runs)."""
    _add(_all(), record)


def algorithms(family: Family | None = None) -> list[Algorithm]:
    """Every algorithm (of `family`), in table and legend order: by family, then by name."""
    order = list(Family)
    return sorted(
        (r for r in _all().values() if family in (None, r.family)),
        key=lambda r: (order.index(r.family), r.name),
    )


def names(family: Family | None = None) -> list[str]:
    """The algorithms' names (of `family`), in table and legend order."""
    return [r.name for r in algorithms(family)]


def algorithm(name: str) -> Algorithm:
    """The record named `name`; ConfigError naming the algorithms there are."""
    record = _all().get(name)
    if record is None:
        raise ConfigError(f"unknown algorithm {name!r} (available: {', '.join(names())})")
    return record
