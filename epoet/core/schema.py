"""What every config schema shares: the one error type and its range checks.

Schemas live beside the code they configure (envs/config.py, terrain/config.py, ...); each
failure is one `ConfigError` sentence naming the key a user types.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Sequence
from typing import Any

from omegaconf import DictConfig, OmegaConf


class ConfigError(ValueError):
    """A config value that cannot work; the message is one sentence naming it."""


def closest(word: str, choices: Sequence[str]) -> str | None:
    """The choice a typo most likely meant (difflib's closest above its default cutoff)."""
    found = difflib.get_close_matches(word, list(choices), n=1)
    return found[0] if found else None


def unknown_key(key: str, valid: Sequence[str]) -> str:
    """The sentence for a dotted key no schema has, naming the closest valid key at its level
    (or, with none close, every one), as a user types them: never a schema's class name."""
    prefix, _, name = key.rpartition(".")
    # `_target_` and, at the top, Hydra's own node are not what a user meant
    names = [n for n in valid if not n.startswith("_") and (prefix or n != "hydra")]
    dotted = f"{prefix}." if prefix else ""
    if (match := closest(name, names)) is not None:  # the name alone: a shared prefix is no match
        return f"unknown key {key}: did you mean {dotted}{match}?"
    where = f"{prefix}'s keys" if prefix else "the top-level keys"
    return f"unknown key {key}: {where} are {', '.join(names)}."


def check_known_keys(node: DictConfig, prefix: str = "") -> None:
    """Refuse a key its schema does not have: Hydra adds `+key=value` to a structured config
    without asking, and the dataclass built from it would carry the typo where nothing reads
    it, so a misspelt setting would silently not apply."""
    schema = OmegaConf.get_type(node)
    if dataclasses.is_dataclass(schema):
        fields = [f.name for f in dataclasses.fields(schema)]
        for key in map(str, node.keys()):
            if key not in fields and key != "_target_":  # Hydra's
                raise ConfigError(unknown_key(f"{prefix}{key}", fields))
    for child, value in node.items_ex(resolve=False):
        if isinstance(value, DictConfig):
            check_known_keys(value, f"{prefix}{child!s}.")


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
