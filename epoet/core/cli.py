"""Shared by the command-line entry points: bad input ends in one line on stderr, exit 2
(`epoet.cli` parses the key=value commands and runs the Hydra app this way)."""

from __future__ import annotations

import re
import sys
from typing import NoReturn

from hydra.errors import MissingConfigException
from omegaconf import DictConfig
from omegaconf.errors import ConfigAttributeError, ConfigKeyError

from epoet.core.errors import first_line
from epoet.core.schema import closest, unknown_key

# Config paths a user may have typed that have since been renamed: refused with today's name.
RENAMED = {"algo_budget/poet": "algo_budget/open_ended"}  # the open-ended family's values


def fail(err: BaseException) -> NoReturn:
    """Exit 2 with one line: the error's first line, plus its cause's (Hydra wraps OmegaConf's
    errors); an unknown key or config choice is named as the user typed it, with the closest
    valid one."""
    print(f"error: {message(err)}", file=sys.stderr)
    sys.exit(2)


def message(err: BaseException) -> str:
    cause = err.__cause__
    if isinstance(cause, (ConfigAttributeError, ConfigKeyError)) and cause.full_key:
        if (renamed := RENAMED.get(cause.full_key)) is not None:
            return f"{cause.full_key} is now {renamed}: override {renamed}=<budget>."
        parent = cause.parent_node  # the node the key was set on: its valid keys
        valid = list(parent.keys()) if isinstance(parent, DictConfig) else []
        return unknown_key(cause.full_key, [str(k) for k in valid])
    text = first_line(err)
    if cause is not None and str(cause).strip() and first_line(cause) not in text:
        text += f": {first_line(cause)}"
    if isinstance(err, MissingConfigException) and err.options:
        # Schemas are registered in the same groups; users choose among the YAML files only.
        options = sorted(o for o in err.options if not o.endswith("_schema"))
        text += f" (available: {', '.join(options)})"
        if (typed := re.search(r"Could not find '(.+)/([^/']+)'", text)) is not None:
            group, choice = typed.groups()
            if (match := closest(choice, options)) is not None:
                text += f"; did you mean {group}={match}?"
    return text
