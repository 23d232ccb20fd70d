"""What every config schema shares: the one error type and its range checks.

Schemas live beside the code they configure (envs/config.py, terrain/config.py, ...); each
failure is one `ConfigError` sentence naming the key a user types.
"""

from __future__ import annotations

from typing import Any


class ConfigError(ValueError):
    """A config value that cannot work; the message is one sentence naming it."""


def check(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


def config_key(obj: Any, name: str) -> str:
    """The dotted config key a user types for a field, e.g. `terrain.grid`."""
    return f"{obj.KEY}.{name}" if obj.KEY else name


def positive(obj: Any, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        check(value > 0, f"{config_key(obj, name)} must be > 0, got {value}.")


def non_negative(obj: Any, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        check(value >= 0, f"{config_key(obj, name)} must be >= 0, got {value}.")
