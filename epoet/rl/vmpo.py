"""V-MPO on the hexapod (Song et al. 2019; REFERENCE.md section 8), read top to bottom.

PPO's on-policy update (`OnPolicyLearner` in ppo.py: GAE, then epochs of shuffled minibatches)
with the V-MPO loss of vmpo_loss.py: the E-step keeps the top fraction of each minibatch's
advantages with a learned temperature eta, the M-step fits them under a KL trust region with a
learned multiplier alpha. Actor and critic are tanh networks as PPO's, on running-normalised
observations; the actor's loc and scale are written into the batch at collection time, which is
how VMPOLoss rebuilds the old policy for the KL. Settings: conf/algo/vmpo.yaml.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from epoet.config import Config, VmpoConfig
from epoet.rl.ppo import OnPolicyLearner
from epoet.rl.run_state import TrainingRun, TrainResult
from epoet.rl.setup import make_actor, make_value
from epoet.rl.vmpo_loss import VMPOLoss

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def train(cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
          ) -> TrainResult:
    """The `algo=vmpo` runner (see epoet.run.RUNNERS)."""
    algo: VmpoConfig = cfg.algo
    with TrainingRun(cfg, tracker, run_dir, resume) as run:
        actor = make_actor(run.env, algo.hidden, algo.activation, state_independent_scale=True)
        critic = make_value(run.env, algo.hidden, algo.activation)
        loss = VMPOLoss(
            actor, critic, top_fraction=algo.top_fraction, eta_init=algo.eta_init,
            eps_eta=algo.eps_eta, alpha_init=algo.alpha_init, eps_alpha=algo.eps_alpha,
            critic_coeff=algo.critic_coeff)
        learner = OnPolicyLearner(algo, run.plan, actor, critic, loss)

        collector = run.start(actor, learner)
        for batch in run.batches(collector):
            learned = learner.learn(batch)
            run.log(batch, learned)
            run.evaluate_if_due(actor)
            run.checkpoint_if_due(learner)
        return run.finish(actor, learner)
