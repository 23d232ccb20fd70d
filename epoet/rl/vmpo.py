"""V-MPO on the hexapod (Song et al. 2019; docs/reference.md): PPO's loop and on-policy
update (ppo.py: GAE, then epochs of shuffled minibatches) with the V-MPO loss of vmpo_loss.py.

The E-step keeps the top fraction of each minibatch's advantages with a learned temperature eta,
the M-step fits them under a KL trust region with a learned multiplier alpha. Actor and critic
are tanh networks as PPO's, on running-normalised observations; the actor's loc and scale are
written into the batch at collection time, which is how VMPOLoss rebuilds the old policy for the
KL. Settings: conf/algo/vmpo.yaml.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl.modules import ProbabilisticActor, ValueOperator

from epoet.config import Config
from epoet.rl.config import VmpoConfig
from epoet.rl import ppo
from epoet.rl.run_state import TrainResult
from epoet.rl.vmpo_loss import VMPOLoss

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def vmpo_loss(algo: VmpoConfig, actor: ProbabilisticActor, critic: ValueOperator) -> VMPOLoss:
    return VMPOLoss(actor, critic, top_fraction=algo.top_fraction, eta_init=algo.eta_init,
                    eps_eta=algo.eps_eta, alpha_init=algo.alpha_init, eps_alpha=algo.eps_alpha,
                    critic_coeff=algo.critic_coeff)


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
          ) -> TrainResult:
    """The `algo=vmpo` runner (see epoet.run.RUNNERS)."""
    return ppo.train(cfg, tracker, run_dir, resume, make_loss=vmpo_loss)
