"""The key=value command line of every command composed by Hydra: `python -m epoet` (a Hydra
app) and `python -m epoet.eval.<name>` (composed from conf/<name>.yaml with its schema).

Help is generated (epoet.core.help), never written per command: the options are the schema's
fields with their comments, the defaults are the command's YAML, and what the command does and
its examples are its module docstring. `python -m epoet --help` is Hydra's own help page
(conf/hydra/help/epoet.yaml), whose template calls the `epoet_run_options` resolver registered
here, so its groups list only the choices a user may make. Bad input ends in one line, exit 2.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Callable

from hydra import initialize_config_dir
from hydra._internal.utils import get_args_parser  # Hydra's flag parser (hydra.main's)
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from epoet.config import (
    CONF_DIR,
    Config,
    compose,
    register_command,
    register_configs,
    validate,
)
from epoet.core.cli import fail
from epoet.core.help import (
    asks_for_help,
    field_comments,
    options_table,
    page,
    print_and_exit,
    reader_may_leave,
)
from epoet.core.schema import ConfigError

# What a user chooses in `python -m epoet`, in help order (the other groups are internal: the
# schemas, conf/algo_budget and conf/learner are picked by the algorithm and the budget).
RUN_GROUPS = ("algo", "agent", "terrain", "budget", "workers", "tracking")
LAUNCHER = "hydra/launcher"
LAUNCHER_HELP = "how a sweep's jobs (-m) run: in turn, in parallel (joblib) or on SLURM"
# Hydra's flags that print and run nothing, whose reader may stop reading (`--help | head -1`).
PRINT_ONLY = ("-h", "--help", "--hydra-help", "-c", "--cfg", "-i", "--info")


def shown(value: Any) -> str:
    """A default as a user would type it (YAML's null, true, false)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def group_options(group: str) -> list[str]:
    """The files a user may choose in a config group: Hydra's list (conf/ and the installed
    plugins' configs, e.g. the launchers) without the schemas. Needs Hydra initialised."""
    options = GlobalHydra.instance().config_loader().get_group_options(group)
    return sorted(o for o in options if not o.endswith("_schema"))


def run_options(*, _root_: DictConfig) -> str:
    """The `python -m epoet --help` lines of the groups and the top-level options (an OmegaConf
    resolver called by Hydra's help template, with the composed config and its choices)."""
    comments, choices = field_comments(Config), HydraConfig.get().runtime.choices
    groups = [
        (f"{group}={'|'.join(group_options(group))}", comments[group], choices[group])
        for group in RUN_GROUPS
    ]
    groups.append(
        (f"{LAUNCHER}={'|'.join(group_options(LAUNCHER))}", LAUNCHER_HELP, choices[LAUNCHER])
    )
    options = [
        (f"{f.name}=", comments[f.name], shown(_root_[f.name]))
        for f in dataclasses.fields(Config)
        if f.name not in RUN_GROUPS
    ]
    return (
        f"groups (group=choice):\n{options_table(groups)}\n\n"
        f"options (key=value; every key of a group too, e.g. budget.hours=2):\n"
        f"{options_table(options)}"
    )


def run_hydra_app(app: Callable[[], None]) -> None:
    """Run a @hydra.main app with the schemas and the help resolver registered, so composition
    errors become one line (`epoet.core.cli.fail`) instead of Hydra's report."""
    register_configs()
    OmegaConf.register_new_resolver("epoet_run_options", run_options, replace=True)
    # Under MUJOCO_GL=egl or osmesa, MuJoCo's import makes PyOpenGL log a notice (no
    # OpenGL_accelerate) at INFO, which Hydra's logging would print in every run's output.
    logging.getLogger("OpenGL").setLevel(logging.WARNING)
    os.environ["HYDRA_FULL_ERROR"] = "1"  # make Hydra re-raise instead of printing its report
    # Hydra's own flags are read by its argparse parser, whose errors print a usage block: the
    # same parser reads them first here, with a one-line error (Hydra then reads them again).
    flags = get_args_parser()
    flags.error = lambda message: fail(ConfigError(f"{message} (see --help)"))  # type: ignore[method-assign]
    flags.parse_args(sys.argv[1:])
    printing = any(arg in PRINT_ONLY for arg in sys.argv[1:])
    with reader_may_leave() if printing else contextlib.nullcontext():
        try:
            app()
        except (HydraException, OmegaConfBaseException) as err:
            fail(err)
        except OSError as err:  # e.g. an output folder that cannot be written (Hydra makes it)
            if printing and isinstance(err, BrokenPipeError):
                raise  # the reader of the printout left: reader_may_leave ends quietly
            fail(err)


@dataclass(frozen=True)
class KeyValueCommand:
    """`python -m epoet.eval.<name> key=value ...`: composed from conf/<name>.yaml, validated by
    its schema, with a generated `--help`. Defining the command registers its schema, so
    epoet/config.py, a layer below the commands, keeps no list of them."""

    name: str  # conf/<name>.yaml, its schema's node `<name>_schema`, the module epoet.eval.<name>
    doc: str | None  # the command module's docstring: what it does and its examples
    schema: type  # the dataclass of its settings (epoet/eval/config.py)
    plain: tuple[str, ...] = ()  # keys that take a value though a config group has their name

    def __post_init__(self) -> None:
        register_command(self.name, self.schema)

    @property
    def prog(self) -> str:
        return f"python -m epoet.eval.{self.name}"

    def parse(self, argv: Sequence[str] | None = None) -> Any:
        """The validated config of the command line; `--help` prints help and exits 0; bad
        input (an unknown key, a wrong type, a value out of range) is one line and exit 2."""
        args = list(sys.argv[1:] if argv is None else argv)
        if asks_for_help(args):
            print_and_exit(self.help())
        try:
            if flags := [arg for arg in args if arg.startswith("-")]:
                raise ConfigError(
                    f"unknown option {flags[0]}: {self.prog} takes key=value settings "
                    f"(see {self.prog} --help)."
                )
            plain = {
                key: arg.split("=", 1)[1]
                for arg in args
                for key in self.plain
                if arg.startswith(f"{key}=")
            }
            raw = compose([a for a in args if a.split("=", 1)[0] not in plain], self.name)
            for key, value in plain.items():
                raw[key] = value
            return validate(raw)
        except (ConfigError, HydraException, OmegaConfBaseException) as err:
            fail(err)

    def help(self) -> str:
        """Usage, what the command does, each option with its description and default (nested
        groups as `<group>.<key>`), and the examples."""
        comments, chosen = field_comments(self.schema), _group_choices(self.name)
        rows = []
        register_configs()
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            defaults = compose([], self.name)
            for f in dataclasses.fields(self.schema):
                if f.name not in chosen or f.name in self.plain:
                    rows.append((f"{f.name}=", comments[f.name], shown(defaults[f.name])))
                    continue
                options = group_options(f.name)
                if len(options) > 1:  # a choice, e.g. gallery's terrain=bowl|cppn
                    rows.append((f"{f.name}={'|'.join(options)}", comments[f.name], chosen[f.name]))
                else:  # one file whose keys may be set
                    yaml = f"conf/{f.name}/{chosen[f.name]}.yaml"
                    rows.append((f"{f.name}.<key>=", comments[f.name], yaml))
        return page(
            f"{self.prog} [key=value ...]",
            self.doc,
            [(f"options (key=value; defaults from conf/{self.name}.yaml)", options_table(rows))],
        )


def _group_choices(config_name: str) -> dict[str, str]:
    """The config groups a command's YAML chooses (`- agent: hexapod`), Hydra's own excluded."""
    yaml = OmegaConf.to_container(OmegaConf.load(CONF_DIR / f"{config_name}.yaml"))
    assert isinstance(yaml, dict)  # a config file is a mapping
    return {
        str(key): str(value)
        for entry in yaml.get("defaults", [])
        if isinstance(entry, dict)
        for key, value in entry.items()
        if not str(key).startswith("override")
    }
