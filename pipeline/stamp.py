"""`python -m pipeline.stamp --records docs/results`: stamp each agent file of the records with
the physics integrator its run trained with (its record's config.yaml, `agent.integrator`).

Agent files written before they recorded their integrator run bare under `agent.integrator`
(RK4 by default), so a gait trained with implicitfast fell over when a user evaluated the file
alone (docs/api.md, "Agent files"). A file that already records an integrator is checked
against its record's and left as it is; a file outside any record (no config.yaml above it, as
the authors' agents) is left alone. Every write is atomic.

Examples:

    python -m pipeline.stamp --records docs/results
"""

from __future__ import annotations

import io
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from analysis.store import AnalysisError, run_command
from epoet.core.files import atomic_write, savez
from epoet.core.help import HelpParser
from epoet.eval.agents import RECORD_CONFIG
from epoet.rollout.agent_files import INTEGRATOR, TORCH_POLICY, recorded_integrator

# libyaml's loader where PyYAML was built with it: a record's config.yaml parses about ten times
# faster than in pure Python, and the records hold a few hundred agent files
SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def agent_files(records: Path) -> Iterator[Path]:
    """Every ES agent file and exported torch policy under `records`."""
    for path in sorted(records.rglob("*")):
        if path.name == TORCH_POLICY or (path.suffix == ".npz" and path.parent.name == "policies"):
            yield path


def record_config(path: Path, top: Path) -> dict[str, Any] | None:
    """The config of the nearest record above `path` (up to `top`), None outside any."""
    for folder in path.parents:
        if (folder / RECORD_CONFIG).is_file():
            return dict(yaml.load((folder / RECORD_CONFIG).read_text(), Loader=SAFE_LOADER))
        if folder == top:
            return None
    return None


def record_integrator(path: Path, top: Path) -> str | None:
    """The integrator its record's run trained with, None outside any record."""
    config = record_config(path, top)
    return None if config is None else str(config["agent"]["integrator"])


def stamp(path: Path, integrator: str) -> None:
    """Add `integrator` to the agent file, atomically."""
    if path.name == TORCH_POLICY:
        import torch

        spec = torch.load(path, weights_only=True, map_location="cpu")
        spec[INTEGRATOR] = integrator
        buffer = io.BytesIO()
        torch.save(spec, buffer)
        with atomic_write(path) as file:
            file.write(buffer.getvalue())
        return
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    arrays[INTEGRATOR] = np.array(integrator)
    with atomic_write(path) as file:
        savez(file, arrays)


def stamp_records(records: Path) -> tuple[int, int]:
    """Stamp every unstamped agent file under `records`; (stamped, already right)."""
    stamped = right = 0
    for path in agent_files(records):
        integrator = record_integrator(path, records)
        if integrator is None:
            continue
        kind = "torch" if path.name == TORCH_POLICY else "es"
        recorded = recorded_integrator(path, kind)
        if recorded is None:
            stamp(path, integrator)
            stamped += 1
        elif recorded != integrator:
            raise AnalysisError(
                f"{path} records the {recorded} integrator, its record's config {integrator}."
            )
        else:
            right += 1
    return stamped, right


def main(argv: Sequence[str] | None = None) -> int:
    parser = HelpParser("python -m pipeline.stamp", __doc__)
    parser.add_argument("--records", type=Path, required=True, help="a records folder")
    args = parser.parse_args(argv)

    def run() -> None:
        if not args.records.is_dir():
            raise AnalysisError(f"there is no records folder {args.records}.")
        stamped, right = stamp_records(args.records)
        print(f"[stamp] {stamped} agent files stamped, {right} already recorded theirs")

    return run_command(run)


if __name__ == "__main__":
    raise SystemExit(main())
