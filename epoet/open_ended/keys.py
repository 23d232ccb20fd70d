"""What each keyed seed of an ePOET run is for: with the ids after it, a key names one random
stream, a function of the run seed alone (epoet.open_ended.service `Service.seeds`)."""

from __future__ import annotations

from enum import IntEnum


class Key(IntEnum):
    """What a keyed seed is for; with the ids after it, it names one random stream."""

    ROOT_GENOME = 0  # (0,)
    ROOT_AGENT = 1  # (0,)
    OPTIMIZER = 2  # (env, iteration admitted): the pair's ES noise stream
    BOWL = 3  # (env, iteration): the bowl part of an environment's terrain
    ES_SPAWN = 4  # (env, iteration): starts of the ES episodes
    EVAL = 5  # (env, iteration): starts of the evaluation episodes
    TRANSFER = 6  # (target env, iteration, candidate + 1 or 0 for direct transfers)
    PROPOSAL_NOISE = 7  # (target env, iteration, candidate)
    PROPOSAL_SPAWN = 8  # (target env, iteration, candidate)
    PARENTS = 9  # (iteration,): which eligible parent each child slot mutates
    CHILD_GENOME = 10  # (parent env, iteration, slot)
    CHILD_BOWL = 11  # (iteration, slot)
    MC = 12  # (iteration, slot)
    PATA = 13  # (env, iteration) for existing environments
    CHILD_PATA = 14  # (iteration, slot)
    ADMIT = 15  # (iteration, slot, candidate + 1 or 0 for direct transfers)
    ADMIT_NOISE = 16  # (iteration, slot, candidate)
    ADMIT_SPAWN = 17  # (iteration, slot, candidate)
    # numbered above the keys of loops that extend ePOET's, which continue from 18
    VARIANT_BOWL = 40  # (env, iteration, variant): the bowl of an ES step's terrain variant
