"""The keyed evaluation service of an ePOET run: what every step of the loop asks for (seeds,
terrains, scores, fine-tuned agents) and nothing about the pool it serves.

All randomness is keyed: a seed for (purpose, ids...) comes from one SeedSequence of the run's
seed (keys.py names ePOET's purposes; a loop extending ePOET's names its own, numbered after
them), so the order in which things are evaluated, the number of workers and a
checkpoint/resume never change what a run does. Each call to `run` (and so to `scores` and
`fine_tune`) is one call to the workers for every request it is given, so no worker waits at a
per-pair barrier.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any, NamedTuple

import numpy as np

from epoet.es.config import EsConfig
from epoet.es.obs_norm import ObsNormalizer
from epoet.es.optimizer import OpenAIES
from epoet.open_ended.keys import Key
from epoet.open_ended.pairs import Environment
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.engine import Episodes
from epoet.rollout.policy import Standardizer
from epoet.rollout.populations import Agents, Mirrored, Request
from epoet.terrain import Terrain, generator_for, make_terrain
from epoet.terrain.config import TerrainConfig


class FineTune(NamedTuple):
    """One proposal ES step: `theta` on `terrain` with `es`'s settings and state; `ids` key its
    noise and spawn seeds."""

    es: OpenAIES
    terrain: Terrain
    theta: np.ndarray
    ids: tuple[int, ...]


class Service:
    """Seeds, terrains and episodes for one run, over one evaluator; counts environment steps."""

    def __init__(
        self,
        evaluator: Evaluator,
        terrain: TerrainConfig,
        es: EsConfig,
        *,
        seed: int,
        n_pairs: int,
        eval_episodes: int,
    ) -> None:
        self.evaluator = evaluator
        self.terrain_cfg = terrain
        self.generator = generator_for(terrain.kind)  # encodes and mutates the environments
        self.es_cfg = es
        self.run_seed = seed
        self.n_pairs = n_pairs
        self.eval_episodes = eval_episodes
        self.layer_sizes = evaluator.layer_sizes  # the policy's, derived once: runner.py
        self.env_steps = 0  # counted here only: `run`, `count_steps`, `load_state_dict`
        # Observation normalisation: every theta of the pool acts on standardised observations
        # (one set of statistics per run, as Salimans et al.); what runs is `policy(theta)`.
        self.obs_norm = ObsNormalizer(self.layer_sizes[0]) if es.obs_norm_episodes else None
        # One iteration's terrains: every step of an iteration asks for the same ones, and a
        # child admitted (or a pair joined) at t keeps the terrain it was judged on until t ends.
        self._terrains: dict[int, Terrain] = {}
        self._terrains_at = -1

    # --- seeds ------------------------------------------------------------------------------
    def seeds(self, n: int, key: IntEnum, *ids: int) -> np.ndarray:
        """n non-negative int64 seeds, a function of the run seed, the key and the ids alone."""
        seq = np.random.SeedSequence([self.run_seed, int(key), *ids])
        return (seq.generate_state(n, np.uint64) >> np.uint64(1)).astype(np.int64)

    def seed(self, key: IntEnum, *ids: int) -> int:
        return int(self.seeds(1, key, *ids)[0])

    # --- environments and terrains ------------------------------------------------------------
    def root_genome(self, seed: int) -> Any:
        """The encoding of a new lineage (the terrain generator's)."""
        return self.generator.encode(self.terrain_cfg, seed)

    def child_genome(self, parent: Environment, seed: int) -> Any:
        """A valid mutation of `parent`'s encoding; MutationError when there is none."""
        return self.generator.mutate(self.terrain_cfg, parent.genome, seed)

    def terrain(self, env: Environment, t: int) -> Terrain:
        """The environment's heightmap at iteration t: its encoding rendered with a fresh bowl
        at S(t)."""
        terrains = self._iteration_terrains(t)
        if env.index not in terrains:
            terrains[env.index] = self.make_terrain(env, self.seed(Key.BOWL, env.index, t), t)
        return terrains[env.index]

    def keep_terrain(self, env: Environment, t: int, terrain: Terrain) -> None:
        """`env`'s terrain for the rest of iteration t (a child's: the one it was judged on)."""
        self._iteration_terrains(t)[env.index] = terrain

    def _iteration_terrains(self, t: int) -> dict[int, Terrain]:
        if t != self._terrains_at:
            self._terrains, self._terrains_at = {}, t
        return self._terrains

    def make_terrain(self, env: Environment, bowl_seed: int, t: int) -> Terrain:
        """Heightmap of `env` with its lineage in the terrain's provenance (saved artifacts)."""
        parent = None if env.parent is None else f"env{env.parent}"
        return make_terrain(
            self.terrain_cfg,
            seed=bowl_seed,
            iteration=t,
            genome=env.genome,
            generation=env.generation,
            parent_id=parent,
        )

    # --- the run's counters -------------------------------------------------------------------
    def count_steps(self, steps: int) -> None:
        """Environment steps taken outside the workers (a learner's own env)."""
        self.env_steps += steps

    def state_dict(self) -> dict[str, Any]:
        return {
            "env_steps": self.env_steps,
            "obs_norm": None if self.obs_norm is None else self.obs_norm.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """The counters of a checkpoint; the terrains are made again from their keys."""
        self.env_steps = state["env_steps"]
        if self.obs_norm is not None:
            self.obs_norm.load_state_dict(state["obs_norm"])
        self._terrains, self._terrains_at = {}, -1

    # --- agents -----------------------------------------------------------------------------
    def new_es(self, theta: np.ndarray, seed: int) -> OpenAIES:
        return OpenAIES(theta, seed, self.es_cfg, self.n_pairs)

    def optimizer_for(self, env: Environment, theta: np.ndarray) -> OpenAIES:
        """The ES of a pair admitted with `env`: its noise stream keyed by the environment."""
        return self.new_es(theta, self.seed(Key.OPTIMIZER, env.index, env.created_at))

    def standardizer(self) -> Standardizer | None:
        return None if self.obs_norm is None else self.obs_norm.standardizer(self.layer_sizes)

    def policy(self, theta: np.ndarray) -> np.ndarray:
        """The raw-observation policy parameters of ES parameters `theta` (P,) or (K, P)."""
        standardizer = self.standardizer()
        return theta if standardizer is None else standardizer.fold(theta)

    # --- episodes ---------------------------------------------------------------------------
    def run(self, requests: list[Request]) -> list[Episodes]:
        """One call to the workers for every request; counts the environment steps."""
        episodes = self.evaluator.run(requests)
        self.env_steps += sum(int(e.lengths.sum()) for e in episodes)
        return episodes

    def eval_request(
        self, terrain: Terrain, thetas: np.ndarray, key: IntEnum, *ids: int
    ) -> Request:
        """`eval_episodes` seeded episodes of each agent in `thetas` (K, P) on `terrain`."""
        return Request(
            terrain, Agents.of(self.policy(thetas), self.seeds(self.eval_episodes, key, *ids))
        )

    def es_requests(
        self,
        env: Environment,
        t: int,
        theta: np.ndarray,
        noise: np.ndarray,
        sigma: float,
        record: int,
    ) -> list[Request]:
        """One ES step of the pair on `env` at iteration t: its mirrored pairs spread in order over
        `terrain_variants` terrains (the first: the niche's own), each pair's two episodes on one
        terrain from one start; the transitions of the step's first `record` episodes recorded
        (`merge_variants` puts them back in the step's order)."""
        spawn = self.seeds(len(noise), Key.ES_SPAWN, env.index, t)
        chunks = np.array_split(np.arange(len(noise)), self.es_cfg.terrain_variants)
        if record > 2 * len(chunks[0]):
            raise ValueError(
                f"{record} recorded episodes do not fit the first terrain variant's "
                f"{2 * len(chunks[0])}: use fewer algo.es.terrain_variants."
            )
        return [
            Request(
                self.terrain(env, t)
                if v == 0
                else self.make_terrain(env, self.seed(Key.VARIANT_BOWL, env.index, t, v), t),
                Mirrored.of(theta, noise[c], sigma, spawn[c], self.standardizer()),
                record=record if v == 0 else 0,
            )
            for v, c in enumerate(chunks)
        ]

    @staticmethod
    def merge_variants(parts: list[Episodes]) -> Episodes:
        """One ES step's episodes from its variants' (`es_requests`), in the step's mirrored
        order: every variant's + episodes, then every variant's - episodes."""
        if len(parts) == 1:
            return parts[0]
        halves = [len(p.returns) // 2 for p in parts]
        fields = []
        for name in ("returns", "lengths", "finished"):
            arrays = [getattr(p, name) for p in parts]
            plus = [a[:h] for a, h in zip(arrays, halves)]
            minus = [a[h:] for a, h in zip(arrays, halves)]
            fields.append(np.concatenate(plus + minus))
        recorded = parts[0].transitions
        if recorded is not None:  # the first variant's episode e is the step's e or n + e - m
            local, m, n = recorded["episode"], halves[0], sum(halves)
            recorded = {**recorded, "episode": np.where(local < m, local, n + local - m)}
        return Episodes(fields[0], fields[1], fields[2], recorded)

    def scores(self, requests: list[Request]) -> list[np.ndarray]:
        """Mean return of each agent of each evaluation request."""
        return [e.returns.mean(axis=1) for e in self.run(requests)]

    def fine_tune(
        self, jobs: list[FineTune], noise_key: Key, spawn_key: Key, step: str
    ) -> list[np.ndarray]:
        """The theta each job's ES step (`step`: sgd | adam) proposes; no optimiser's state
        changes."""
        noise = [self.seeds(self.n_pairs, noise_key, *job.ids) for job in jobs]
        requests = [
            Request(
                job.terrain,
                Mirrored.of(
                    job.theta,
                    seeds,
                    job.es.sigma,
                    self.seeds(self.n_pairs, spawn_key, *job.ids),
                    self.standardizer(),
                ),
            )
            for job, seeds in zip(jobs, noise)
        ]
        return [
            job.es.propose(
                seeds, e.returns[: len(seeds)], e.returns[len(seeds) :], theta=job.theta, step=step
            )
            for job, seeds, e in zip(jobs, noise, self.run(requests))
        ]
