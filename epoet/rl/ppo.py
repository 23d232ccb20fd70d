"""PPO on the hexapod (paper Table 2): the whole run, read top to bottom in `train`.

Per collector batch: GAE advantages, then epochs of shuffled minibatches on TorchRL's
ClipPPOLoss (clipped objective + entropy bonus + value loss), the on-policy update of
on_policy.py that V-MPO (vmpo.py) runs with its own loss; a tanh actor with a state-independent
log-std and a tanh critic, both reading running-normalised observations. Sizes and
coefficients: conf/algo/ppo.yaml. What every baseline's run shares (seeds, envs, counters,
evaluation, checkpoints): harness.py.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl.objectives import ClipPPOLoss

from epoet.config import Config
from epoet.core.lifecycle import raise_if_stopped
from epoet.rl.config import PpoConfig
from epoet.rl.env import OBS
from epoet.rl.harness import Harness, TrainResult, make_collector
from epoet.rl.nets import make_actor, make_value
from epoet.rl.on_policy import OnPolicyLearner

if TYPE_CHECKING:  # the tracking module imports mlflow; algorithms only report through it
    from epoet.tracking import Tracker


def train(
    cfg: Config, tracker: Tracker, run_dir: Path, resume: dict[str, Any] | None
) -> TrainResult:
    """The `algo=ppo` runner (its record: epoet/rl/config.py `PPO`)."""
    algo = PpoConfig.of(cfg)
    with Harness(cfg, tracker, run_dir, resume) as run:  # threads, seeds, envs, counters
        actor = make_actor(run.env, algo.hidden, algo.activation, state_independent_scale=True)
        critic = make_value(run.env, algo.hidden, algo.activation)
        loss = ClipPPOLoss(
            actor,
            critic,
            clip_epsilon=algo.clip,
            entropy_coeff=algo.entropy_coeff,
            critic_coeff=algo.critic_coeff,
            loss_critic_type="l2",
            normalize_advantage=algo.normalize_advantage,
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
