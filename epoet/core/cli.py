"""Shared by the command-line entry points: bad input ends in one line on stderr, exit 2
(`epoet.cli` parses the key=value commands and runs the Hydra app this way)."""

from __future__ import annotations

import sys
from typing import NoReturn

from hydra.errors import MissingConfigException

from epoet.core.errors import first_line


def fail(err: BaseException) -> NoReturn:
    """Exit 2 with the error's first line, plus its cause's (Hydra wraps OmegaConf's errors)."""
    text = first_line(err)
    cause = err.__cause__
    if cause is not None and str(cause).strip() and first_line(cause) not in text:
        text += f": {first_line(cause)}"
    if isinstance(err, MissingConfigException) and err.options:
        # Schemas are registered in the same groups; users choose among the YAML files only.
        options = sorted(o for o in err.options if not o.endswith("_schema"))
        text += f" (available: {', '.join(options)})"
    print(f"error: {text}", file=sys.stderr)
    sys.exit(2)
