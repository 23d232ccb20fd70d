"""The policy a baseline run exports as its own (`selection`, epoet/rollout/selection.py): among
its policies at every evaluation point so far and its last one.

The authors kept their baselines' best checkpoint; a run that only exports its last policy
loses an earlier, better one (PPO's agents fell from 45-65 % of the paper's terrains at 30 CPU
minutes to 32-34 % at 60: docs/RESULTS.md). Each evaluation point's policy is kept in
`<run folder>/candidates/frames<N>.pt`; at every CPU-time snapshot and at the end the
candidates walk the run's held-out terrains (each once: its result is cached in
`candidates/held_out.json`, since a kept policy never changes; the last policy, which does,
walks them every time) and the chosen one is written as the folder's `policy.pt`, the last
policy beside it as `policy_last.pt` where they differ, and both choices in `choice.json`.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from epoet.core.files import atomic_write
from epoet.rl.policy_file import POLICY_FILE
from epoet.rollout.agent_files import LAST_POLICY
from epoet.rollout.selection import LAST, best_of, policy_held_out, write_choice
from epoet.rollout.torch_policy import load_policy

if TYPE_CHECKING:
    from epoet.config import Config

CANDIDATES = "candidates"
HELD_OUT = "held_out.json"


class Candidates:
    """A baseline run's kept policies and their held-out results."""

    def __init__(self, cfg: Config, run_dir: Path) -> None:
        self.cfg, self.folder = cfg, Path(run_dir) / CANDIDATES
        self.folder.mkdir(parents=True, exist_ok=True)

    def keep(self, frames: int, export: Callable[[Path], Path]) -> None:
        """The policy of the evaluation point at `frames`, written by `export(path)`."""
        export(self.folder / f"frames{frames}.pt")

    def held_out(self, paths: dict[str, Path]) -> dict[str, Any]:
        """Held-out results of `paths` (name -> policy file), from the cache where it has them."""
        sel = self.cfg.selection
        cache_file = self.folder / HELD_OUT
        cache = json.loads(cache_file.read_text()) if cache_file.is_file() else {}
        new = [name for name in paths if name == LAST or name not in cache]
        if new:
            fresh = policy_held_out(
                [load_policy(paths[name]) for name in new],
                new,
                self.cfg.agent,
                self.cfg.terrain,
                sel,
                self.cfg.seed,
                self.cfg.budget.score_scale,
            )["candidates"]
            cache.update({k: v for k, v in fresh.items() if k != LAST})
            with atomic_write(cache_file) as file:
                file.write(json.dumps(cache, indent=1).encode())
            cache = {**cache, **fresh}
        return {name: cache[name] for name in paths}

    def export(self, folder: Path) -> dict[str, Any]:
        """Choose among the kept policies and the last one (the folder's policy.pt, just
        exported), write the chosen as the folder's policy.pt (the last beside it where they
        differ) and the choice record; returns the record."""
        started = time.process_time()
        last = folder / POLICY_FILE
        kept = sorted(self.folder.glob("frames*.pt"), key=lambda p: int(p.stem[6:]))
        paths = {**{p.stem: p for p in kept}, LAST: last}
        record: dict[str, Any] = {"rule": self.cfg.selection.rule, "own": LAST}
        if self.cfg.selection.terrains:
            results = self.held_out(paths)
            record.update(validation=best_of(results), candidates=results)
        exported = record["validation"] if self.cfg.selection.rule == "validation" else LAST
        if exported == LAST:
            (folder / LAST_POLICY).unlink(missing_ok=True)
        else:
            for path, source in ((folder / LAST_POLICY, last), (last, paths[exported])):
                data = source.read_bytes()
                with atomic_write(path) as file:
                    file.write(data)
        record.update(
            exported=exported,
            selection=asdict(self.cfg.selection),
            cpu_s=time.process_time() - started,
        )
        write_choice(folder, record)
        return record
