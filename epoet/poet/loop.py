"""The ePOET loop (paper Algorithm 1 without the SAC steps; REFERENCE.md section 6).

Each iteration: every `adjust_interval * iterations_before_transfer` iterations the pool
reproduces (mutated children, minimal criterion, PATA-EC novelty, at most `max_admitted` child
admitted); then every active pair takes one ES step on its environment and is evaluated; every
`iterations_before_transfer` iterations agents are transferred between environments.

All randomness is keyed: a seed for (purpose, environment, iteration) comes from one
SeedSequence of the run's seed, so the order in which things are evaluated, the number of
workers and a checkpoint/resume never change what a run does.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from epoet.config import PoetConfig, TerrainConfig
from epoet.es.optimizer import OpenAIES
from epoet.es.policy import init_params
from epoet.es.workers import Evaluator
from epoet.poet.novelty import pata_ec, rank_by_novelty
from epoet.poet.pairs import Environment, Pair
from epoet.terrain import CppnMutationError, Terrain, make_terrain, mutate_genome, new_genome

# Purposes of keyed seeds.
_ES, _EVAL, _TRANSFER, _PROPOSAL, _CHILD, _MC, _PATA, _BOWL, _AGENT, _OPT, _ADMIT = range(11)


@dataclass
class Scaled:
    """Score thresholds scaled to the budget's episode length (paper values are for 2000 steps)."""

    mc_lower: float
    mc_upper: float
    repro_threshold: float


class EPOET:
    """The pool of environment-agent pairs and the three things that change it."""

    def __init__(self, algo: PoetConfig, terrain: TerrainConfig, evaluator: Evaluator, *,
                 seed: int, n_pairs: int, eval_episodes: int, score_scale: float,
                 layer_sizes: tuple[int, ...]) -> None:
        self.cfg = algo
        self.terrain_cfg = terrain
        self.evaluator = evaluator
        self.seed = seed
        self.n_pairs = n_pairs
        self.eval_episodes = eval_episodes
        self.layer_sizes = layer_sizes
        self.limits = Scaled(algo.mc_lower * score_scale, algo.mc_upper * score_scale,
                             algo.repro_threshold * score_scale)
        self.iteration = 0
        self.active: list[Pair] = []
        self.archived: list[Pair] = []
        self.next_index = 0
        self.transfers = 0
        self.env_steps = 0
        self._terrains: dict[tuple[int, int], Terrain] = {}
        root = Environment(index=0, genome=new_genome(terrain.cppn, self._seed(_CHILD, 0, 0)),
                           generation=0, parent=None, created_at=0)
        theta = init_params(self._seed(_AGENT, 0, 0), layer_sizes)
        self._admit(root, theta)

    # --- keyed randomness -------------------------------------------------------------------
    def _seeds(self, n: int, purpose: int, env: int, iteration: int, extra: int = 0) -> np.ndarray:
        """n non-negative int64 seeds, a function of the run seed and the key alone."""
        seq = np.random.SeedSequence([self.seed, purpose, env, iteration, extra])
        return (seq.generate_state(n, np.uint64) >> np.uint64(1)).astype(np.int64)

    def _seed(self, purpose: int, env: int, iteration: int, extra: int = 0) -> int:
        return int(self._seeds(1, purpose, env, iteration, extra)[0])

    # --- environments -------------------------------------------------------------------------
    def terrain(self, env: Environment, iteration: int | None = None) -> Terrain:
        """The environment's heightmap at an iteration: its CPPN, a fresh bowl, S(iteration)."""
        t = self.iteration if iteration is None else iteration
        key = (env.index, t)
        if key not in self._terrains:
            if len(self._terrains) > 4 * (len(self.active) + len(self.archived)) + 16:
                self._terrains.clear()  # bounded cache: only the current iteration is reused
            self._terrains[key] = self._make_terrain(env, self._seed(_BOWL, env.index, t), t)
        return self._terrains[key]

    def _make_terrain(self, env: Environment, bowl_seed: int, iteration: int) -> Terrain:
        """Heightmap of `env` with its lineage in the terrain's provenance (saved artifacts)."""
        parent = None if env.parent is None else f"env{env.parent}"
        return make_terrain(self.terrain_cfg, seed=bowl_seed, iteration=iteration,
                            genome=env.genome, generation=env.generation, parent_id=parent)

    def _new_es(self, theta: np.ndarray, seed: int) -> OpenAIES:
        c = self.cfg.es
        return OpenAIES(theta, seed, n_pairs=self.n_pairs, lr=c.lr, lr_decay=c.lr_decay,
                        lr_floor=c.lr_floor, sigma=c.sigma, sigma_decay=c.sigma_decay,
                        sigma_floor=c.sigma_floor, l2_coeff=c.l2_coeff)

    def _admit(self, env: Environment, theta: np.ndarray) -> Pair:
        pair = Pair(env=env, es=self._new_es(theta, self._seed(_OPT, env.index, env.created_at)))
        self.active.append(pair)
        self.next_index = max(self.next_index, env.index + 1)
        if len(self.active) > self.cfg.max_num_envs:
            self.archived.append(self.active.pop(0))  # the oldest pair leaves the active pool
        return pair

    # --- one iteration ----------------------------------------------------------------------
    def iterate(self) -> dict[str, float]:
        """Run iteration `self.iteration` and return its metrics."""
        t = self.iteration
        start, steps0 = time.perf_counter(), self.env_steps
        metrics: dict[str, float] = {}
        period = self.cfg.adjust_interval * self.cfg.iterations_before_transfer
        if t > 0 and t % period == 0:
            metrics["admitted"] = float(self.reproduce())
        for pair in self.active:
            metrics.update(self._es_step(pair))
        if len(self.active) > 1 and t % self.cfg.iterations_before_transfer == 0:
            metrics["transfers"] = float(self.transfer())
        elapsed = time.perf_counter() - start
        metrics.update({
            "best_score": max(p.score for p in self.active),
            "active_envs": float(len(self.active)),
            "archived_envs": float(len(self.archived)),
            "annecs": float(self.annecs),
            "env_steps": float(self.env_steps),
            "steps_per_second": (self.env_steps - steps0) / elapsed,
            "wall_time": elapsed,
        })
        self.iteration += 1
        return metrics

    def _es_step(self, pair: Pair) -> dict[str, float]:
        t, idx = self.iteration, pair.env.index
        terrain = self.terrain(pair.env)
        noise_seeds = pair.es.sample_seeds()
        spawn = self._seeds(len(noise_seeds), _ES, idx, t)
        r_pos, r_neg = self._es_returns(terrain, pair.theta, noise_seeds, pair.es.sigma, spawn)
        stats = pair.es.tell(noise_seeds, r_pos, r_neg)
        score = float(self._evaluate(terrain, pair.theta[None], _EVAL, idx)[0])
        self._record(pair, score)
        returns = np.concatenate([r_pos, r_neg])
        prefix = f"pair{idx}"
        return {f"{prefix}/return_mean": float(returns.mean()),
                f"{prefix}/return_max": float(returns.max()),
                f"{prefix}/score": score, f"{prefix}/lr": stats["lr"],
                f"{prefix}/sigma": stats["sigma"]}

    def _record(self, pair: Pair, score: float) -> None:
        pair.scores.append(score)
        pair.env.solved |= score >= self.limits.repro_threshold

    def _es_returns(self, terrain: Terrain, theta: np.ndarray, noise_seeds: np.ndarray,
                    sigma: float, spawn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        episodes = self.evaluator.es_episodes(terrain, theta, noise_seeds, sigma, spawn)
        self.env_steps += int(episodes.lengths.sum())
        n = len(noise_seeds)
        return episodes.returns[:n], episodes.returns[n:]

    def _evaluate(self, terrain: Terrain, thetas: np.ndarray, purpose: int, env: int,
                  extra: int = 0) -> np.ndarray:
        """Mean return of each theta over `eval_episodes` seeded episodes."""
        spawn = self._seeds(self.eval_episodes, purpose, env, self.iteration, extra)
        episodes = self.evaluator.evaluate(terrain, thetas, spawn)
        self.env_steps += int(episodes.lengths.sum())
        return episodes.returns.mean(axis=1)

    def _fine_tune(self, target: Pair, terrain: Terrain, theta: np.ndarray, purpose: int,
                   extra: int) -> np.ndarray:
        """One ES step of `theta` on `terrain` with the target's optimiser settings, leaving
        the target's ES untouched."""
        idx, t = target.env.index, self.iteration
        noise_seeds = self._seeds(self.n_pairs, purpose, idx, t, extra)
        spawn = self._seeds(self.n_pairs, purpose, idx, t, extra + 1_000_000)
        r_pos, r_neg = self._es_returns(terrain, theta, noise_seeds, target.es.sigma, spawn)
        return target.es.propose(noise_seeds, r_pos, r_neg, theta=theta)

    # --- transfer ---------------------------------------------------------------------------
    def transfer(self) -> int:
        """Try every other agent on each environment; the best that beats the incumbent wins.

        Direct transfers are evaluated first; those that beat the target's recent best are
        refined by one proposal ES step on the target (REFERENCE.md section 6), and the best of
        all candidates replaces the target's agent, resetting its optimiser.
        """
        accepted = 0
        thetas = np.stack([p.theta for p in self.active])  # agents before any replacement
        for m, target in enumerate(self.active):
            others = [j for j in range(len(self.active)) if j != m]
            terrain = self.terrain(target.env)
            bar = max(target.scores[-self.cfg.iterations_before_transfer:])
            direct = self._evaluate(terrain, thetas[others], _TRANSFER, target.env.index)
            best_score, best_theta = bar, None
            for j, score in zip(others, direct):
                if score <= bar:
                    continue
                if score > best_score:
                    best_score, best_theta = float(score), thetas[j]
                proposal = self._fine_tune(target, terrain, thetas[j], _PROPOSAL, extra=j)
                p_score = float(self._evaluate(terrain, proposal[None], _TRANSFER,
                                               target.env.index, extra=1 + j)[0])
                if p_score > best_score:
                    best_score, best_theta = p_score, proposal
            if best_theta is not None:
                target.es.reset(best_theta)
                target.scores.pop()  # the new agent's score stands for this iteration
                self._record(target, best_score)
                accepted += 1
        self.transfers += accepted
        return accepted

    # --- reproduction -----------------------------------------------------------------------
    def reproduce(self) -> int:
        """Propose mutated children of eligible environments and admit the most novel ones."""
        t, lim = self.iteration, self.limits
        parents = [p for p in self.active if p.score >= lim.repro_threshold]
        if not parents:
            return 0
        rng = np.random.default_rng(self._seed(_CHILD, 0, t, 1_000_000))
        passing: list[tuple[Environment, Terrain]] = []  # with the terrain the MC judged
        for c in range(self.cfg.num_children):
            parent = parents[int(rng.integers(len(parents)))]
            tc = self.terrain_cfg
            try:
                genome = mutate_genome(parent.env.genome, tc.cppn, tc.mutation,
                                       self._seed(_CHILD, parent.env.index, t, c), tc.grid)
            except CppnMutationError:
                continue  # this parent yielded no valid child in max_tries; propose the next
            child = Environment(index=-1, genome=genome, generation=parent.env.generation + 1,
                                parent=parent.env.index, created_at=t)
            terrain = self._child_terrain(child, c)
            # Minimal criterion: the parent's agent neither fails nor already masters the child.
            score = float(self._evaluate(terrain, parent.theta[None], _MC, parent.env.index,
                                         extra=c)[0])
            if lim.mc_lower <= score <= lim.mc_upper:
                passing.append((child, terrain))
        if not passing:
            return 0
        agents = np.stack([p.theta for p in self.active + self.archived])
        existing = np.stack([self._pata_ec(self.terrain(p.env), agents, p.env.index)
                             for p in self.active + self.archived])
        candidates = np.stack([self._pata_ec(terrain, agents, 10_000 + i)
                               for i, (_, terrain) in enumerate(passing)])
        order, _ = rank_by_novelty(candidates, existing, k=self.cfg.novelty_k)
        admitted = 0
        for i in order[: self.cfg.max_admitted]:
            child, terrain = passing[i]
            child.index = self.next_index
            self._admit(child, self._best_agent_for(terrain, child.index))
            self._terrains[(child.index, t)] = terrain
            admitted += 1
        return admitted

    def _child_terrain(self, child: Environment, slot: int) -> Terrain:
        return self._make_terrain(child, self._seed(_BOWL, 10_000 + slot, self.iteration),
                                  self.iteration)

    def _pata_ec(self, terrain: Terrain, agents: np.ndarray, key: int) -> np.ndarray:
        scores = self._evaluate(terrain, agents, _PATA, key)
        return pata_ec(scores, self.limits.mc_lower, self.limits.mc_upper)

    def _best_agent_for(self, terrain: Terrain, key: int) -> np.ndarray:
        """Best active agent on a new environment, directly or after one fine-tuning ES step."""
        thetas = np.stack([p.theta for p in self.active])
        direct = self._evaluate(terrain, thetas, _TRANSFER, key)
        best = int(np.argmax(direct))
        best_score, best_theta = float(direct[best]), thetas[best]
        for j, pair in enumerate(self.active):
            tuned = self._fine_tune(pair, terrain, thetas[j], _ADMIT, extra=j)
            score = float(self._evaluate(terrain, tuned[None], _TRANSFER, key, extra=1 + j)[0])
            if score > best_score:
                best_score, best_theta = score, tuned
        return best_theta.copy()

    # --- open-endedness measure ------------------------------------------------------------------
    @property
    def annecs(self) -> int:
        """Admitted environments (the root excluded) whose agent later reached the threshold."""
        return sum(p.env.solved for p in self.active + self.archived if p.env.index > 0)

    # --- checkpointing ----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        def pair_state(p: Pair) -> dict[str, Any]:
            return {"env": p.env, "es": p.es.state_dict(), "scores": list(p.scores)}
        return {"iteration": self.iteration, "next_index": self.next_index,
                "transfers": self.transfers, "env_steps": self.env_steps,
                "active": [pair_state(p) for p in self.active],
                "archived": [pair_state(p) for p in self.archived]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        def restore(s: dict[str, Any]) -> Pair:
            es = self._new_es(s["es"]["theta"], 0)
            es.load_state_dict(s["es"])
            return Pair(env=s["env"], es=es, scores=list(s["scores"]))
        self.iteration = state["iteration"]
        self.next_index = state["next_index"]
        self.transfers = state["transfers"]
        self.env_steps = state["env_steps"]
        self.active = [restore(s) for s in state["active"]]
        self.archived = [restore(s) for s in state["archived"]]
        self._terrains.clear()
