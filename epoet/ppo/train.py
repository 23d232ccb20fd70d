"""PPO on the hexapod (paper Table 2): its learner, which the baseline run
(epoet/rl/baseline_run.py) trains.

Per collector batch: GAE advantages, then epochs of shuffled minibatches on TorchRL's
ClipPPOLoss (clipped objective + entropy bonus + value loss), the on-policy update of
epoet/rl/on_policy.py that V-MPO (epoet/vmpo/) runs with its own loss; a tanh actor with a state-independent
log-std and a tanh critic, both reading running-normalised observations. Sizes and
coefficients: conf/algo/ppo.yaml (schema: config.py `PpoConfig`).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss

from epoet.config import Config
from epoet.ppo.config import PpoConfig
from epoet.rl import baseline_run
from epoet.rl.harness import TrainResult
from epoet.rl.on_policy import OnPolicyLearner

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def clipped_loss(algo: PpoConfig, actor: ProbabilisticActor, critic: ValueOperator) -> ClipPPOLoss:
    """PPO's loss: the clipped objective, an entropy bonus and the critic's squared error."""
    return ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=algo.clip,
        entropy_coeff=algo.entropy_coeff,
        critic_coeff=algo.critic_coeff,
        loss_critic_type="l2",
        normalize_advantage=algo.normalize_advantage,
    )


def train(
    cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
) -> TrainResult:
    """The `algo=ppo` runner (its record: config.py `PPO`)."""
    algo = PpoConfig.of(cfg)
    loss = partial(clipped_loss, algo)
    return baseline_run.train(
        cfg, tracker, run_dir, resume, lambda env, plan: OnPolicyLearner(algo, env, plan, loss)
    )
