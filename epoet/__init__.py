"""epoet: open-ended locomotion learning."""

from importlib.metadata import version

# The version lives in pyproject.toml only; the installed package's metadata carries it here.
__version__ = version("epoet")
