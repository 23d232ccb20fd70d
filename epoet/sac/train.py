"""`algo=sac`: SAC's learner (learner.py) as the baseline run (epoet/rl/baseline_run.py) trains
it on its own TorchRL collector (paper Table 3). Settings: conf/algo/sac.yaml (collection and
updates) over conf/learner/sac.yaml (schema: config.py `SacConfig`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from epoet.config import Config
from epoet.rl import baseline_run
from epoet.rl.harness import BatchPlan, TrainResult
from epoet.rl.policy_file import CRITICS_FILE, export_critics
from epoet.sac.config import SacConfig
from epoet.sac.learner import SacLearner

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


class SacBaseline:
    """SAC's learner as the baseline run (baseline_run.py) runs it for `algo=sac`: each collector
    batch is stored and followed by `updates` updates (the config's per-batch count, scaled to
    the batch: harness.BatchPlan); the first `random_frames` frames are uniform random actions
    (Table 3's pre-training epoch); the critics go beside the policy at the end, where
    ePOET-SAC's warm start (`algo.sac_init`) loads them."""

    def __init__(self, algo: SacConfig, env: EnvBase, plan: BatchPlan) -> None:
        self.sac = SacLearner(algo, env)
        self.actor, self.loss = self.sac.actor, self.sac.loss
        self.updates = plan.scaled(algo.updates_per_batch, minimum=1)
        self.random_frames = plan.scaled(algo.init_random_frames)
        self.hidden, self.activation = algo.hidden, algo.activation

    def learn(self, batch: TensorDictBase) -> dict[str, float]:
        return self.sac.learn(batch, self.updates)

    def artifacts(self, run_dir: Path) -> list[Path]:
        return [
            export_critics(run_dir / CRITICS_FILE, self.loss.critics, self.hidden, self.activation)
        ]

    def state_dict(self) -> dict[str, Any]:
        return self.sac.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.sac.load_state_dict(state)


def train(
    cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
) -> TrainResult:
    """The `algo=sac` runner (its record: config.py `SAC`)."""
    algo = SacConfig.of(cfg)
    return baseline_run.train(
        cfg, tracker, run_dir, resume, lambda env, plan: SacBaseline(algo, env, plan)
    )
