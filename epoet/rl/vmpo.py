"""V-MPO on the hexapod (Song et al. 2019; docs/reference.md "ePOET-SAC and the baselines"): the
whole run, read top to bottom in `train`.

Per collector batch PPO's on-policy update (on_policy.py: GAE, then epochs of shuffled
minibatches) on the V-MPO loss of vmpo_loss.py. The E-step keeps the top fraction of each
minibatch's advantages with a learned temperature eta, the M-step fits them under a KL trust
region with a learned multiplier alpha. Actor and critic are tanh networks as PPO's, on
running-normalised observations; the actor's loc and scale are written into the batch at
collection time, which is how VMPOLoss rebuilds the old policy for the KL. Settings:
conf/algo/vmpo.yaml. What every baseline's run shares (seeds, envs, counters, evaluation,
checkpoints): harness.py.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from epoet.config import Config
from epoet.core.lifecycle import raise_if_stopped
from epoet.rl.config import VmpoConfig
from epoet.rl.env import OBS
from epoet.rl.harness import Harness, TrainResult, make_collector
from epoet.rl.nets import make_actor, make_value
from epoet.rl.on_policy import OnPolicyLearner
from epoet.rl.vmpo_loss import VMPOLoss

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def train(
    cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
) -> TrainResult:
    """The `algo=vmpo` runner (its record: epoet/rl/config.py `VMPO`)."""
    algo = VmpoConfig.of(cfg)
    with Harness(cfg, tracker, run_dir, resume) as run:  # threads, seeds, envs, counters
        actor = make_actor(run.env, algo.hidden, algo.activation, state_independent_scale=True)
        critic = make_value(run.env, algo.hidden, algo.activation)
        loss = VMPOLoss(
            actor,
            critic,
            top_fraction=algo.top_fraction,
            eta_init=algo.eta_init,
            eps_eta=algo.eps_eta,
            alpha_init=algo.alpha_init,
            eps_alpha=algo.eps_alpha,
            critic_coeff=algo.critic_coeff,
        )
        learner = OnPolicyLearner(algo, run.plan, actor, critic, loss)
        collector = make_collector(run.env, actor, run.plan)
        run.start(collector, learner, actor)  # a resumed run continues from its checkpoint

        state = run.state
        if state.frames >= state.next_eval:  # frame 0
            run.evaluate(actor)
        batches = iter(collector)
        while not run.budget_spent():  # budget.frames or budget.hours
            started = time.perf_counter()
            batch = next(batches)  # collect
            learned = learner.learn(batch)  # learn
            if run.obs_stats is not None:  # after learning: one normalisation per batch
                run.obs_stats.update(batch[OBS])
            run.log(batch, learned, started)  # log
            if state.frames >= state.next_eval:  # evaluate
                run.evaluate(actor)
            if run.checkpoint_due():  # checkpoint
                run.checkpoint(learner)
                raise_if_stopped(f"at frame {state.frames}")  # a stop signal ends the run here
                collector.reset()  # checkpoints end the running episode (harness.py)
        if state.last_eval_frames != state.frames:  # the final policy, unless just evaluated
            run.evaluate(actor)
        return run.finish(learner)
