"""The parts of ePOET's reproduce step (paper Algorithm 1; Enhanced POET's `reproduce`): propose
mutated children, keep those that pass the minimal criterion, and admit the most novel whose best
transferred agent also passes it. `EPOET.reproduce` (loop.py) runs them in that order; they live
here so that loop.py reads as the algorithm's named steps.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from epoet.poet.keys import Key
from epoet.poet.novelty import pata_ec, rank_by_novelty
from epoet.poet.pairs import Child, Environment, FineTune, Pair
from epoet.terrain import CppnMutationError, cppn_inputs, mutate_genome

if TYPE_CHECKING:
    from epoet.poet.loop import EPOET


class Reproduction:
    """The reproduce step's parts, mixed into `EPOET` (they use its seeds, terrains and runs)."""

    def _propose_children(self: EPOET, parents: list[Pair]) -> list[tuple[Child, Pair]]:
        """Up to `num_children` valid CPPN mutations of randomly chosen eligible parents."""
        t = self.iteration
        rng = np.random.default_rng(self._seed(Key.PARENTS, t))
        tc = self.terrain_cfg
        children = []
        for slot in range(self.cfg.num_children):
            parent = parents[int(rng.integers(len(parents)))]
            try:
                genome = mutate_genome(parent.env.genome, tc.cppn, tc.mutation,
                                       self._seed(Key.CHILD_GENOME, parent.env.index, t, slot),
                                       cppn_inputs(tc))
            except CppnMutationError:
                continue  # this parent yielded no valid child in max_tries; propose the next
            env = Environment(index=-1, genome=genome, generation=parent.env.generation + 1,
                              parent=parent.env.index, created_at=t)
            terrain = self._make_terrain(env, self._seed(Key.CHILD_BOWL, t, slot), t)
            children.append((Child(env, terrain, slot), parent))
        return children

    def _minimal_criterion(self: EPOET, children: list[tuple[Child, Pair]]) -> list[Child]:
        """Children on which their parent's agent neither fails nor already excels."""
        if not children:
            return []
        t = self.iteration
        scores = self._scores([self._eval_request(child.terrain, parent.theta[None], Key.MC, t,
                                                  child.slot) for child, parent in children])
        return [child for (child, _), score in zip(children, scores)
                if self.thresholds.passes_mc(float(score[0]))]

    def _admit_most_novel(self: EPOET, passing: list[Child]) -> int:
        """In order of PATA-EC novelty, admit children whose best transferred agent also passes
        the minimal criterion (the reference's rule), at most `max_admitted` of them."""
        t, th = self.iteration, self.thresholds
        pool = self.active + self.archived
        agents = np.stack([p.theta for p in pool])
        requests = ([self._eval_request(self.terrain(p.env), agents, Key.PATA, p.env.index, t)
                     for p in pool]
                    + [self._eval_request(c.terrain, agents, Key.CHILD_PATA, t, c.slot)
                       for c in passing])
        ranks = [pata_ec(s, th.mc_lower, th.mc_upper) for s in self._scores(requests)]
        order, _ = rank_by_novelty(np.stack(ranks[len(pool):]), np.stack(ranks[:len(pool)]),
                                   k=self.cfg.novelty_k)
        admitted = 0
        for i in order:
            child = passing[i]
            score, theta = self._best_agent_for(child)
            if not th.passes_mc(score):
                continue
            child.env.index = self.next_index
            self._admit(child.env, theta)
            self._terrains[(child.env.index, t)] = child.terrain
            admitted += 1
            if admitted == self.cfg.max_admitted:
                break
        return admitted

    def _best_agent_for(self: EPOET, child: Child) -> tuple[float, np.ndarray]:
        """(score, theta) of the best active agent on a child, directly or after one
        fine-tuning ES step (`proposal_step`) with a fresh optimiser, as the reference's
        candidate pair takes it."""
        t, slot = self.iteration, child.slot
        thetas = np.stack([p.theta for p in self.active])
        direct = self._scores([self._eval_request(child.terrain, thetas, Key.ADMIT, t, slot,
                                                  0)])[0]
        # A fresh optimiser per candidate: initial lr and sigma, no Adam state (its own noise
        # stream is unused: the step's noise comes from keyed seeds).
        tuned = self._fine_tune([FineTune(self._new_es(theta, 0), child.terrain, theta,
                                          (t, slot, j)) for j, theta in enumerate(thetas)],
                                Key.ADMIT_NOISE, Key.ADMIT_SPAWN)
        scores = self._scores([self._eval_request(child.terrain, theta[None], Key.ADMIT, t, slot,
                                                  j + 1) for j, theta in enumerate(tuned)])
        best = int(np.argmax(direct))
        best_score, best_theta = float(direct[best]), thetas[best]
        for theta, score in zip(tuned, scores):
            if score[0] > best_score:
                best_score, best_theta = float(score[0]), theta
        return best_score, best_theta.copy()
