"""The ePOET loop (paper Algorithm 1 without the SAC steps; docs/reference.md).

Each iteration, as in Enhanced POET's `poet_algo.py`:
1. every `reproduce_interval` iterations, `reproduce`: eligible parents propose mutated children,
   the minimal criterion filters them, and the most novel are admitted with the best agent
   (its parts: reproduction.py);
2. `optimize`: every active pair takes one ES step on its environment and is evaluated;
3. every `transfer_interval` iterations, `transfer`: agents move between environments.

All randomness is keyed: a seed for (purpose, ids...) comes from one SeedSequence of the run's
seed, so the order in which things are evaluated, the number of workers and a checkpoint/resume
never change what a run does. The work of each step (every pair's ES episodes, every evaluation)
goes to the workers as one call, so no worker waits at a per-pair barrier.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from epoet.core.timing import PhaseTimer
from epoet.es.obs_norm import ObsNormalizer
from epoet.es.optimizer import OpenAIES
from epoet.poet.config import PoetConfig
from epoet.poet.keys import Key
from epoet.poet.pairs import Environment, FineTune, Pair, Thresholds
from epoet.poet.reproduction import Reproduction
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.engine import Episodes
from epoet.rollout.policy import Standardizer, init_params
from epoet.rollout.populations import Agents, Mirrored, Request
from epoet.terrain import Terrain, make_terrain, new_genome
from epoet.terrain.config import TerrainConfig

if TYPE_CHECKING:  # the tracking module imports mlflow; the loop only reports through it
    from epoet.tracking import Tracker


class EPOET(Reproduction):
    """The pool of environment-agent pairs and the three things that change it."""

    record_per_pair = 0  # ES-step episodes per pair whose transitions come back (ePOET: none)

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
        self.thresholds = Thresholds(algo.mc_lower * score_scale, algo.mc_upper * score_scale,
                                     algo.repro_threshold * score_scale)
        self.transfer_interval = algo.iterations_before_transfer
        self.reproduce_interval = algo.adjust_interval * algo.iterations_before_transfer
        self.later_reproduce_interval = algo.later_adjust_interval * algo.iterations_before_transfer
        self.iteration = 0
        self.active: list[Pair] = []
        self.archived: list[Pair] = []
        self.next_index = 0
        self.transfers = 0
        self.env_steps = 0
        self.elapsed = 0.0  # seconds of iterations, summed over resumes
        self.best_score = -np.inf  # the best `score` (best active pair's) of any iteration so far
        # Observation normalisation: every theta of the pool acts on standardised observations
        # (one set of statistics per run, as Salimans et al.); what runs is `policy(theta)`.
        self.obs_norm = ObsNormalizer(layer_sizes[0]) if algo.es.obs_norm_episodes else None
        self._terrains: dict[tuple[int, int], Terrain] = {}
        root = Environment(index=0, genome=new_genome(terrain.cppn, self._seed(Key.ROOT_GENOME, 0)),
                           generation=0, parent=None, created_at=0)
        self._admit(root, init_params(self._seed(Key.ROOT_AGENT, 0), layer_sizes))

    def _seeds(self, n: int, key: Key, *ids: int) -> np.ndarray:
        """n non-negative int64 seeds, a function of the run seed, the key and the ids alone."""
        seq = np.random.SeedSequence([self.seed, int(key), *ids])
        return (seq.generate_state(n, np.uint64) >> np.uint64(1)).astype(np.int64)

    def _seed(self, key: Key, *ids: int) -> int:
        return int(self._seeds(1, key, *ids)[0])

    # --- environments -------------------------------------------------------------------------
    def terrain(self, env: Environment, iteration: int | None = None) -> Terrain:
        """The environment's heightmap at an iteration: its CPPN, a fresh bowl, S(iteration)."""
        t = self.iteration if iteration is None else iteration
        key = (env.index, t)
        if key not in self._terrains:
            if len(self._terrains) > 4 * (len(self.active) + len(self.archived)) + 16:
                self._terrains.clear()  # bounded cache: only the current iteration is reused
            self._terrains[key] = self._make_terrain(env, self._seed(Key.BOWL, env.index, t), t)
        return self._terrains[key]

    def _make_terrain(self, env: Environment, bowl_seed: int, iteration: int) -> Terrain:
        """Heightmap of `env` with its lineage in the terrain's provenance (saved artifacts)."""
        parent = None if env.parent is None else f"env{env.parent}"
        return make_terrain(self.terrain_cfg, seed=bowl_seed, iteration=iteration,
                            genome=env.genome, generation=env.generation, parent_id=parent)

    def _new_es(self, theta: np.ndarray, seed: int) -> OpenAIES:
        return OpenAIES(theta, seed, self.cfg.es, self.n_pairs)

    def _admit(self, env: Environment, theta: np.ndarray) -> Pair:
        pair = Pair(env=env, es=self._new_es(theta, self._seed(Key.OPTIMISER, env.index,
                                                                env.created_at)))
        self.active.append(pair)
        self.next_index = max(self.next_index, env.index + 1)
        if len(self.active) > self.cfg.max_num_envs:
            self.archived.append(self.active.pop(0))  # the oldest pair leaves the active pool
        return pair

    # --- episodes -------------------------------------------------------------------------------
    def _standardizer(self) -> Standardizer | None:
        return None if self.obs_norm is None else self.obs_norm.standardizer(self.layer_sizes)

    def policy(self, theta: np.ndarray) -> np.ndarray:
        """The raw-observation policy parameters of ES parameters `theta` (P,) or (K, P)."""
        return theta if self.obs_norm is None else self._standardizer().fold(theta)

    def _run(self, requests: list[Request]) -> list[Episodes]:
        """One call to the workers for every request; counts the environment steps."""
        episodes = self.evaluator.run(requests)
        self.env_steps += sum(int(e.lengths.sum()) for e in episodes)
        return episodes

    def _eval_request(self, terrain: Terrain, thetas: np.ndarray, key: Key, *ids: int
                      ) -> Request:
        """`eval_episodes` seeded episodes of each agent in `thetas` (K, P) on `terrain`."""
        return Request(terrain, Agents.of(self.policy(thetas),
                                          self._seeds(self.eval_episodes, key, *ids)))

    def _scores(self, requests: list[Request]) -> list[np.ndarray]:
        """Mean return of each agent of each evaluation request."""
        return [e.returns.mean(axis=1) for e in self._run(requests)]

    def _fine_tune(self, jobs: list[FineTune], noise_key: Key, spawn_key: Key
                   ) -> list[np.ndarray]:
        """The theta each job's ES step proposes; no optimiser's state changes."""
        noise = [self._seeds(self.n_pairs, noise_key, *job.ids) for job in jobs]
        requests = [Request(job.terrain,
                            Mirrored.of(job.theta, seeds, job.es.sigma,
                                        self._seeds(self.n_pairs, spawn_key, *job.ids),
                                        self._standardizer()))
                    for job, seeds in zip(jobs, noise)]
        return [job.es.propose(seeds, e.returns[:len(seeds)], e.returns[len(seeds):],
                               theta=job.theta, step=self.cfg.proposal_step)
                for job, seeds, e in zip(jobs, noise, self._run(requests))]

    # --- one iteration ----------------------------------------------------------------------
    def iterate(self) -> dict[str, float]:
        """Run iteration `self.iteration` and return its metrics (`time/<step>`: where the
        iteration's wall time went)."""
        start, steps0 = time.perf_counter(), self.env_steps
        timer = PhaseTimer()
        metrics = self.steps(self.iteration, timer)
        elapsed = time.perf_counter() - start
        self.elapsed += elapsed
        metrics.update(timer.metrics())
        metrics.update(self.generation_scores())
        score = max(p.score for p in self.active)
        self.best_score = max(self.best_score, score)
        metrics.update({
            "best_score": self.best_score,
            "active_envs": float(len(self.active)),
            "archived_envs": float(len(self.archived)),
            "annecs": float(self.annecs),
            "env_steps": float(self.env_steps),
            "steps_per_second": (self.env_steps - steps0) / elapsed,
            "time/iteration": elapsed,
            # The axes and the score every algorithm logs (the baselines: their evaluation
            # return), so MLflow charts can put ePOET and the baselines side by side.
            "elapsed": self.elapsed,
            "score": score,
        })
        self.iteration += 1
        return metrics

    def steps(self, t: int, timer: PhaseTimer) -> dict[str, float]:
        """Algorithm 1's ES steps: reproduce, optimise (an ES step and the evaluation of every
        pair), transfer. ePOET-SAC adds its steps at `after_optimize` and `after_transfer`."""
        metrics: dict[str, float] = {}
        if self.reproduce_due(t):
            with timer("reproduce"):
                metrics["admitted"] = float(self.reproduce())
        with timer("optimize"):
            es_metrics, episodes = self.es_step(record=self.record_per_pair)
            metrics.update(es_metrics)
            metrics.update(self.evaluate_pairs())
        metrics.update(self.after_optimize(t, episodes, timer))
        if self.transfer_due(t):
            with timer("transfer"):
                metrics["transfers"] = float(self.transfer())
                metrics.update(self.after_transfer(t))
        return metrics

    def after_optimize(self, t: int, episodes: list[Episodes], timer: PhaseTimer
                       ) -> dict[str, float]:
        """A hook after the ES step (ePOET: nothing)."""
        return {}

    def after_transfer(self, t: int) -> dict[str, float]:
        """A hook inside the transfer step, after the transfers (ePOET: nothing)."""
        return {}

    def reproduce_due(self, t: int) -> bool:
        """At the first interval, then every later interval (the reference: 75, then every 15;
        the paper: every 75)."""
        first = self.reproduce_interval
        return t > 0 and t % (first if t <= first else self.later_reproduce_interval) == 0

    def transfer_due(self, t: int) -> bool:
        return len(self.active) > 1 and t % self.transfer_interval == 0

    def es_step(self, record: int = 0) -> tuple[dict[str, float], list[Episodes]]:
        """One ES step of every active pair; the transitions of each pair's first `record`
        episodes come back with its episodes."""
        t = self.iteration
        noise = [pair.es.sample_seeds() for pair in self.active]
        standardizer = self._standardizer()
        if self.obs_norm is not None:
            record = max(record, self.cfg.es.obs_norm_episodes)
        requests = [Request(self.terrain(pair.env),
                            Mirrored.of(pair.theta, seeds, pair.es.sigma,
                                        self._seeds(len(seeds), Key.ES_SPAWN, pair.env.index, t),
                                        standardizer),
                            record=record)
                    for pair, seeds in zip(self.active, noise)]
        metrics: dict[str, float] = {}
        results = self._run(requests)
        for pair, seeds, episodes in zip(self.active, noise, results):
            n = len(seeds)
            stats = pair.es.tell(seeds, episodes.returns[:n], episodes.returns[n:])
            prefix = f"pair{pair.env.index}"
            metrics.update({f"{prefix}/return_mean": float(episodes.returns.mean()),
                            f"{prefix}/return_max": float(episodes.returns.max()),
                            f"{prefix}/lr": stats["lr"], f"{prefix}/sigma": stats["sigma"]})
        if self.obs_norm is not None:  # the new statistics take effect from the evaluation on
            for episodes in results:
                self.obs_norm.update(episodes.transitions["obs"])
            metrics["obs_norm/count"] = float(self.obs_norm.count)
        return metrics, results

    def evaluate_pairs(self) -> dict[str, float]:
        """Each active agent's score on its own environment this iteration."""
        t = self.iteration
        scores = self._scores([self._eval_request(self.terrain(p.env), p.theta[None], Key.EVAL,
                                                  p.env.index, t) for p in self.active])
        metrics: dict[str, float] = {}
        for pair, score in zip(self.active, scores):
            self._record(pair, float(score[0]))
            metrics[f"pair{pair.env.index}/score"] = pair.score
        return metrics

    def generation_scores(self) -> dict[str, float]:
        """`gen<g>/score`: the best active score of each lineage g (paper Figure 2's
        <algorithm>_gen<g> curves)."""
        best: dict[int, float] = {}
        for pair in self.active:
            g = self.lineage(pair)
            best[g] = max(best.get(g, -np.inf), pair.score)
        return {f"gen{g}/score": score for g, score in sorted(best.items())}

    def lineage(self, pair: Pair) -> int:
        """ePOET's generations: the environment's (root 0, a child its parent's + 1)."""
        return pair.env.generation

    def _replace_agent(self, pair: Pair, theta: np.ndarray, score: float) -> None:
        """A new agent for the pair (a transfer, a crossover child); its score, measured this
        iteration, stands in place of the old agent's."""
        pair.es.reset(theta)
        pair.scores.pop()
        self._record(pair, score)

    def _record(self, pair: Pair, score: float) -> None:
        pair.scores.append(score)
        if score > pair.best_score:
            pair.best_score, pair.best_theta = score, np.array(self.policy(pair.theta))
        pair.env.solved |= score >= self.thresholds.repro

    # --- transfer ---------------------------------------------------------------------------
    def transfer(self) -> int:
        """Try every other agent on each environment; the best fine-tuned one that beats the
        incumbent's recent best replaces it, resetting its optimiser.

        As the reference: direct transfers are evaluated first; those that beat the target's
        best score over its last `transfer_bar_window` evaluations are refined by one proposal
        ES step (`proposal_step`) at the target's sigma, and only a proposal that also beats
        that bar can be accepted (an untuned direct transfer never replaces an agent).
        """
        t = self.iteration
        thetas = np.stack([p.theta for p in self.active])  # agents before any replacement
        others = [[j for j in range(len(self.active)) if j != m] for m in range(len(self.active))]
        bars = [max(p.scores[-self.cfg.transfer_bar_window:]) for p in self.active]
        direct = self._scores([self._eval_request(self.terrain(target.env), thetas[others[m]],
                                                  Key.TRANSFER, target.env.index, t, 0)
                               for m, target in enumerate(self.active)])
        candidates = [(m, j) for m in range(len(self.active))
                      for j, score in zip(others[m], direct[m]) if score > bars[m]]
        if not candidates:
            return 0
        proposals = self._fine_tune([FineTune(self.active[m].es, self.terrain(self.active[m].env),
                                              thetas[j], (self.active[m].env.index, t, j))
                                     for m, j in candidates],
                                    Key.PROPOSAL_NOISE, Key.PROPOSAL_SPAWN)
        scores = self._scores([self._eval_request(self.terrain(self.active[m].env),
                                                  proposal[None], Key.TRANSFER,
                                                  self.active[m].env.index, t, j + 1)
                               for (m, j), proposal in zip(candidates, proposals)])
        best: dict[int, tuple[float, np.ndarray]] = {}
        for (m, _), proposal, score in zip(candidates, proposals, scores):
            if score[0] > max(bars[m], best.get(m, (-np.inf,))[0]):
                best[m] = (float(score[0]), proposal)
        for m, (score, theta) in best.items():
            self._replace_agent(self.active[m], theta, score)
        self.transfers += len(best)
        return len(best)

    # --- reproduction -----------------------------------------------------------------------
    def reproduce(self) -> int:
        """Propose children of eligible environments and admit the most novel that pass."""
        parents = [p for p in self.active if p.score >= self.thresholds.repro]
        if not parents:
            return 0
        passing = self._minimal_criterion(self._propose_children(parents))
        if not passing:
            return 0
        return self._admit_most_novel(passing)

    @property
    def annecs(self) -> int:
        """Admitted novel environments (not the root) whose agent later reached the threshold."""
        return sum(p.env.solved for p in self.active + self.archived
                   if p.env.index > 0 and self.novel(p))

    def novel(self, pair: Pair) -> bool:
        """Whether the pair's environment was admitted as new (ePOET: every one)."""
        return True

    def close(self) -> None:
        """Release what the loop holds besides its evaluator (ePOET: nothing)."""

    def log_artifacts(self, run_dir: Path, tracker: Tracker, choice: str = "best") -> None:
        """Each environment's terrain (npz + PNG) and each agent's parameters: `theta` and
        `score` are the `choice` (its best evaluated, or its final); both are kept."""
        terrains, policies = run_dir / "terrains", run_dir / "policies"
        for folder in (terrains, policies):
            folder.mkdir(exist_ok=True)
        for status, pairs in (("active", self.active), ("archived", self.archived)):
            for pair in pairs:
                name = f"env{pair.env.index}"
                terrain = self.terrain(pair.env, self.iteration - 1)  # the last one trained on
                terrain.save(terrains / f"{name}.npz")
                terrain.to_png(terrains / f"{name}.png")
                final = self.policy(pair.theta)
                best = pair.best_theta if pair.best_theta is not None else final
                chosen = (best, pair.best_score) if choice == "best" else (final, pair.score)
                np.savez(policies / f"{name}.npz", theta=chosen[0], score=chosen[1],
                         choice=choice, best_theta=best, best_score=pair.best_score,
                         final_theta=final, final_score=pair.score,
                         layer_sizes=np.array(self.layer_sizes),
                         status=status, generation=pair.env.generation,
                         parent=-1 if pair.env.parent is None else pair.env.parent)
        tracker.log_artifact(terrains, "terrains")
        tracker.log_artifact(policies, "policies")

    # --- checkpointing ----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        def pair_state(p: Pair) -> dict[str, Any]:
            return {"env": p.env, "es": p.es.state_dict(), "scores": list(p.scores),
                    "best_score": p.best_score,
                    "best_theta": p.best_theta}
        return {"iteration": self.iteration, "next_index": self.next_index,
                "transfers": self.transfers, "env_steps": self.env_steps,
                "elapsed": self.elapsed, "best_score": self.best_score,
                "obs_norm": None if self.obs_norm is None else self.obs_norm.state_dict(),
                "active": [pair_state(p) for p in self.active],
                "archived": [pair_state(p) for p in self.archived]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        def restore(s: dict[str, Any]) -> Pair:
            es = self._new_es(s["es"]["theta"], 0)
            es.load_state_dict(s["es"])
            return Pair(env=s["env"], es=es, scores=list(s["scores"]),
                        best_score=s["best_score"], best_theta=s["best_theta"])
        for name in ("iteration", "next_index", "transfers", "env_steps", "elapsed"):
            setattr(self, name, state[name])
        # checkpoints older than the run-level best: the pairs' bests are the closest record
        self.best_score = state.get("best_score", max(
            s["best_score"] for s in state["active"] + state["archived"]))
        if self.obs_norm is not None:
            self.obs_norm.load_state_dict(state["obs_norm"])
        self.active = [restore(s) for s in state["active"]]
        self.archived = [restore(s) for s in state["archived"]]
        self._terrains.clear()
