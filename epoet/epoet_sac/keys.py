"""What each keyed seed of ePOET-SAC's own steps is for (epoet.open_ended.keys names ePOET's):
with the ids after it, a key names one random stream of the run seed (epoet.open_ended.service
`Service.seeds`).
The numbers continue after ePOET's, so no stream of one is a stream of the other."""

from __future__ import annotations

from enum import IntEnum


class SacKey(IntEnum):
    """What a keyed seed of ePOET-SAC's steps is for; with the ids after it, it names one random
    stream."""

    SAC_ENV = 18  # (iteration,): which active environment Train_SAC uses
    SAC = 19  # torch's stream: () initial weights, (iteration,) Train_SAC,
    # (iteration, 1 | 2) the transfer step's replay states | distillation
    SAC_SPAWN = 20  # (iteration,): starts of SAC's own episodes
    SAC_BOWL = 21  # (iteration,): the bowl of `sac_terrain=bowl`
    JOIN = 22  # (iteration,) random mapping, (iteration, 0 | 1 | 2) distillation's
    # initial ES vector | replay states | shuffling
    JOIN_EVAL = 23  # (iteration,): the mapped agent and the SAC actor on one terrain
    CROSSOVER = 24  # (env, iteration): the coin flips of Algorithm 3
    CROSSOVER_EVAL = 25  # (env, iteration): old and new agent on the same starts
    PRETRAIN = 26  # (i, 0 | 1): the i-th pre-training Train_SAC's torch | spawn seed
    DAGGER = 27  # (mapping, round): starts of DAgger's round (0: the actor's), (mapping,) its
    # minibatch order; `mapping` is the join's iteration
