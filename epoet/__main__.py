"""`python -m epoet`: the Hydra entry point; `--help` is conf/hydra/help/epoet.yaml."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from epoet import __version__
from epoet.cli import run_hydra_app
from epoet.config import CONF_DIR
from epoet.core.checkpoint import CHECKPOINT_NAME, CheckpointError
from epoet.core.cli import fail
from epoet.core.help import print_and_exit
from epoet.core.lifecycle import Stopped
from epoet.core.schema import ConfigError
from epoet.preflight import remove_refused


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def _app(cfg: DictConfig) -> None:
    # Imported here, after Hydra composed the config: mlflow is a slow import, which a
    # composition error (a typo in an override) should not wait for.
    from epoet.run import EvaluationError, prepare, run
    from epoet.tracking import TrackingError

    run_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        prepared = prepare(cfg, run_dir)
    except (ConfigError, TrackingError, CheckpointError) as err:  # refused: nothing has run
        remove_refused(run_dir)  # the folder Hydra made for it, if new and only Hydra's
        fail(err)  # bad input: one line, exit 2, nothing written or overwritten
    try:
        run(cfg, run_dir, prepared)
    except (ConfigError, TrackingError, CheckpointError, EvaluationError) as err:
        fail(err)
    except OSError as err:  # a full disk or a read-only folder: the last checkpoint is intact
        fail(err)
    except Stopped as stop:  # SIGINT / SIGTERM: the checkpoint is written
        print(
            f"epoet: {stop}; checkpoint saved, continue with {resume_command(run_dir)}",
            file=sys.stderr,
        )
        sys.exit(stop.exit_code)
    except KeyboardInterrupt:  # a second Ctrl-C: stopped at once
        saved = (run_dir / CHECKPOINT_NAME).exists()
        hint = f"; continue with {resume_command(run_dir)}" if saved else ""
        print(f"epoet: interrupted{hint}", file=sys.stderr)
        sys.exit(130)


def resume_command(run_dir: Path) -> str:
    """The command that continues this run: `resume=` and the overrides it was started with
    (a resume must repeat them, epoet/migration.py RESUMABLE), quoted for a shell."""
    overrides = [o for o in HydraConfig.get().overrides.task if not o.startswith("resume=")]
    return shlex.join(["python", "-m", "epoet", f"resume={run_dir}", *overrides])


if __name__ == "__main__":
    if "--version" in sys.argv[1:]:  # Hydra's --version would print Hydra's
        print_and_exit(f"epoet {__version__}")
    run_hydra_app(_app)
