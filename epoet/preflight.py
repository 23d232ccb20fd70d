"""Before a run's folder exists: a Hydra callback (conf/config.yaml `hydra.callbacks`) called
after composition and before Hydra makes the output folder.

- `check=true` validates the run there, exactly as the run would (`epoet.run.check`), prints
  one line and exits, so a check creates no folder, no MLflow run and no store.
- Otherwise it notes the first folder of the run's (or sweep's) output path that does not exist
  yet; when the run is then refused for its input, `remove_refused` takes away what Hydra made
  in it (its `.hydra/` record, an empty log, a sweep's multirun.yaml) and nothing else: a folder
  that existed before, or holds anything but Hydra's files, stays.
"""

from __future__ import annotations

import sys
from contextlib import suppress
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, open_dict, read_write

from epoet.core.checkpoint import CheckpointError
from epoet.core.cli import fail
from epoet.core.schema import ConfigError

HYDRA_RECORD = ("config.yaml", "hydra.yaml", "overrides.yaml")  # what Hydra writes in .hydra/
SWEEP_RECORD = "multirun.yaml"  # what it writes in a sweep's folder

# The folders this process is about to create (one per Hydra run or sweep): Hydra builds the
# callback, the task function reads what it noted, so the note lives in the module.
_created: list[Path] = []


def first_missing(path: Path) -> Path | None:
    """The outermost folder of `path` that does not exist yet (None: all of it exists)."""
    missing = None
    for folder in [path, *path.parents]:
        if folder.exists():
            break
        missing = folder
    return missing


class Preflight(Callback):
    """`check=true` before any folder exists; and the folders a run is about to create."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        run_dir = Path(str(config.hydra.run.dir)).absolute()
        if config.check:
            print(_check(config, run_dir), flush=True)
            sys.exit(0)
        if (created := first_missing(run_dir)) is not None:
            _created.append(created)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        if config.check:
            fail(ConfigError("check=true checks one run: leave out -m, one value per key."))
        if (created := first_missing(Path(str(config.hydra.sweep.dir)).absolute())) is not None:
            _created.append(created)


def _check(config: DictConfig, run_dir: Path) -> str:
    """The run's checks on its config as the job would see it (the Hydra node removed)."""
    from epoet.run import check  # the run's module (and its imports) only when checking
    from epoet.tracking import TrackingError

    HydraConfig.instance().set_config(config)  # `${hydra:...}` resolves as in the job
    task = config.copy()
    with read_write(task), open_dict(task):
        del task["hydra"]
    try:
        return check(task, run_dir)
    except (ConfigError, CheckpointError, TrackingError, OSError) as err:
        fail(err)


def _hydra_files(folder: Path) -> list[Path] | None:
    """Hydra's own files in `folder` (its .hydra/ record, empty logs, multirun.yaml), or None
    when it holds anything else."""
    found = []
    for entry in folder.iterdir():
        if entry.name == ".hydra" and entry.is_dir():
            inside = list(entry.iterdir())
            if any(p.name not in HYDRA_RECORD for p in inside):
                return None
            found += inside
        elif entry.is_file() and (
            entry.name == SWEEP_RECORD or (entry.suffix == ".log" and entry.stat().st_size == 0)
        ):
            found.append(entry)
        else:
            return None
    return found


def remove_refused(run_dir: Path) -> None:
    """Remove the folder Hydra made for a run refused for its input, and its parents up to the
    first that existed before this run, each only while it holds nothing but Hydra's files;
    files are removed by name and folders only when empty, never a tree."""
    run_dir = run_dir.absolute()
    created = next((c for c in _created if c == run_dir or c in run_dir.parents), None)
    folder = run_dir
    while created is not None and folder.is_dir():
        files = _hydra_files(folder)
        if files is None:
            return
        for path in files:
            path.unlink()
        with suppress(OSError):  # something else appeared meanwhile: it stays
            if (folder / ".hydra").is_dir():
                (folder / ".hydra").rmdir()
            folder.rmdir()
        if folder.exists() or folder == created:
            return
        folder = folder.parent
