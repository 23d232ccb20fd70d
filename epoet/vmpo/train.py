"""V-MPO on the hexapod (Song et al. 2019; docs/reference.md "ePOET-SAC and the baselines"): its
learner, which the baseline run (epoet/rl/baseline_run.py) trains.

Per collector batch PPO's on-policy update (epoet/rl/on_policy.py: GAE, then epochs of shuffled
minibatches) on the V-MPO loss of loss.py. The E-step keeps the top fraction of each
minibatch's advantages with a learned temperature eta, the M-step fits them under a KL trust
region with a learned multiplier alpha. Actor and critic are tanh networks as PPO's, on
running-normalised observations; the actor's loc and scale are written into the batch at
collection time, which is how VMPOLoss rebuilds the old policy for the KL. Settings:
conf/algo/vmpo.yaml (schema: config.py `VmpoConfig`).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl.modules import ProbabilisticActor, ValueOperator

from epoet.config import Config
from epoet.rl import baseline_run
from epoet.rl.harness import TrainResult
from epoet.rl.on_policy import OnPolicyLearner
from epoet.vmpo.config import VmpoConfig
from epoet.vmpo.loss import VMPOLoss

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def vmpo_loss(algo: VmpoConfig, actor: ProbabilisticActor, critic: ValueOperator) -> VMPOLoss:
    """V-MPO's loss (loss.py) with the run's settings."""
    return VMPOLoss(
        actor,
        critic,
        top_fraction=algo.top_fraction,
        eta_init=algo.eta_init,
        eps_eta=algo.eps_eta,
        alpha_init=algo.alpha_init,
        eps_alpha=algo.eps_alpha,
        critic_coeff=algo.critic_coeff,
    )


def train(
    cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
) -> TrainResult:
    """The `algo=vmpo` runner (its record: config.py `VMPO`)."""
    algo = VmpoConfig.of(cfg)
    loss = partial(vmpo_loss, algo)
    return baseline_run.train(
        cfg, tracker, run_dir, resume, lambda env, plan: OnPolicyLearner(algo, env, plan, loss)
    )
