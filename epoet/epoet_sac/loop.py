"""ePOET-SAC (paper Section 3): the ePOET loop with a SAC learner beside the pool.

`EpoetSac` extends ePOET's loop (epoet/open_ended/loop.py) with Algorithm 1's red steps: `pretrain`
(before iteration 0), ePOET's `reproduce`, its `optimize` with the first episodes of every ES
step recorded for SAC's replay, `sac` (Algorithm 2), ePOET's `transfer` then
`update_actor_from_pool`, and at t mod (k N_transfer) = k N_transfer - 2 the `join` with
Algorithm 3's crossover. The steps between the actor and the pool are exchange.py's.
docs/algorithms/epoet-sac.md writes the steps out and gives every decision the paper leaves
open.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs import EnvBase

from epoet.config import Config
from epoet.core.timing import PhaseTimer
from epoet.epoet_sac.bridge import ReplacedAgent
from epoet.epoet_sac.collect import collect, es_transitions
from epoet.epoet_sac.config import EpoetSacConfig
from epoet.epoet_sac.exchange import ActorExchange
from epoet.epoet_sac.keys import SacKey
from epoet.epoet_sac.replay_mix import ReplayMix
from epoet.epoet_sac.warm_start import WarmStart, scale_mapping_for, warm_start_alpha
from epoet.open_ended.loop import Epoet, Step, every_iteration, loop_settings
from epoet.open_ended.pairs import Environment, Pair
from epoet.rl.env import episode_metrics, make_env, terrain_env
from epoet.rl.harness import set_threads
from epoet.rl.policy_file import export_policy
from epoet.rollout.agent_files import write_es_policy
from epoet.rollout.backends.base import Evaluator
from epoet.rollout.engine import Episodes
from epoet.sac.learner import SacLearner
from epoet.terrain import Terrain, make_terrain
from epoet.terrain.config import TerrainConfig


class EpoetSac(Epoet):
    """The ePOET loop (its pool, service and steps), a SAC learner and the steps that move agents
    between them."""

    cfg: EpoetSacConfig
    EVENTS = (*Epoet.EVENTS, "joined", "replaced")

    def __init__(
        self,
        algo: EpoetSacConfig,
        terrain: TerrainConfig,
        evaluator: Evaluator,
        sac_env: EnvBase,
        *,
        seed: int,
        n_pairs: int,
        eval_episodes: int,
        score_scale: float,
        warm_start: WarmStart | None = None,
    ) -> None:
        super().__init__(
            algo,
            terrain,
            evaluator,
            seed=seed,
            n_pairs=n_pairs,
            eval_episodes=eval_episodes,
            score_scale=score_scale,
        )
        torch.manual_seed(self.service.seed(SacKey.SAC))  # the networks' initial weights
        self.sac_env = sac_env
        # With the pool's observation statistics, the actor and critics standardise inside
        # (the same statistics, `sync_obs_statistics`); the replay keeps raw observations.
        # A warm start fine-tunes (algo.warm): the actor at its own learning rate, the
        # temperature its source finished at, the critics first fitted to this pool's terrains.
        warm = algo.warm if algo.sac_init else None
        self.learner = SacLearner(
            algo.sac,
            sac_env,
            standardize=self.service.obs_norm is not None,
            scale_mapping=scale_mapping_for(algo.sac_init),
            actor_lr=None if warm is None else warm.actor_lr,
            anchor_weight=0.0 if warm is None else warm.anchor,
        )
        if warm_start is not None:  # not on resume: the checkpoint holds the learner
            self.learner.warm_start(
                warm_start.actor, warm_start.critics, warm_start_alpha(warm_start, algo.warm)
            )
        self.critic_updates = 0 if warm is None else warm.critic_updates
        # a warm-started actor acts from the first frame; a cold one after uniform actions
        self.random_frames = 0 if algo.sac_init else algo.sac.init_random_frames
        self.actor_net = self.learner.loss.policy_net  # raw obs -> (loc, scale)
        # The SAC actor's deterministic scores step SAC's gym env directly (every Train_SAC
        # resets it): reset(seed=s) gives the spawn of the workers' episodes with spawn seed s,
        # so both kinds of agent share the starts.
        self.score_env = terrain_env(sac_env)
        self.act_dim = sac_env.action_spec.shape[-1]
        self.sac_threads = torch.get_num_threads()  # from_config's (algo.sac_threads)
        self.frames_per_iteration = algo.frames_per_iteration
        self.updates_per_iteration = round(algo.frames_per_iteration * algo.updates_per_frame)
        self.mix = ReplayMix(algo.sac.buffer_size)
        self.exchange = ActorExchange(
            self.service,
            self.pool,
            self.actor_net,
            self.score_env,
            self.learner.buffer,
            algo.distill,
            algo.dagger,
        )
        self.join_of: dict[int, int] = {}  # env index -> k, for the k-th join's pair
        self.recorded: list[Episodes] = []  # this iteration's ES episodes, for the replay

    @classmethod
    def from_config(
        cls, cfg: Config, evaluator: Evaluator, warm_start: WarmStart | None = None
    ) -> EpoetSac:
        """The `algo=epoet_sac` loop of a run: torch threads `algo.sac_threads` (null: as the
        workers; they take turns), SAC's own env (`close` closes it), the budget's population,
        evaluations and scale."""
        set_threads(cfg)
        algo = EpoetSacConfig.of(cfg)
        if algo.sac_threads is not None:
            torch.set_num_threads(algo.sac_threads)
        sac_env = make_env(cfg, obs_norm=False, seed=cfg.seed, resample_terrain=False)
        return cls(
            algo, cfg.terrain, evaluator, sac_env, **loop_settings(cfg), warm_start=warm_start
        )

    # --- one iteration: Algorithm 1 ------------------------------------------------------------
    def steps(self) -> list[Step]:
        """ePOET's steps (reproduce, optimize, transfer) with SAC's around them."""
        reproduce, optimize, transfer = super().steps()
        return [
            Step("pretrain", self.pretrain_due, lambda t: self.pretrain()),
            reproduce,
            optimize,
            Step("sac", every_iteration, self.sac_step),
            transfer,
            Step("join", self.join_due, self.join),
        ]

    def pretrain_due(self, t: int) -> bool:
        """Before iteration 0, when the run pre-trains (the reference; Algorithm 1 does not)."""
        return t == 0 and self.cfg.pretrain_iterations > 0

    def optimize(self, t: int) -> dict[str, float]:
        """ePOET's, the first `es_episodes_per_pair` episodes of every pair's ES step recorded
        (in the workers) for the replay."""
        metrics, self.recorded = self.es_step(t, record=self.cfg.es_episodes_per_pair)
        metrics.update(self.evaluate_pairs(t))
        return metrics

    def sac_step(self, t: int) -> dict[str, float]:
        """The learner takes the pool's statistics and the recorded ES transitions, then
        Train_SAC (Algorithm 2)."""
        self.sync_obs_statistics()
        self.add_to_replay(self.recorded)
        self.recorded = []
        return self.train_sac(t)

    def transfer_step(self, t: int) -> dict[str, float]:
        """ePOET's transfer, then Algorithm 1's update of the actor from the pool."""
        moves = self.transfer_moves(t)  # {target env: source env}
        metrics = {
            "transfers": float(len(moves)),
            "transfers/from_joined": float(
                sum(source in self.join_of for source in moves.values())
            ),
        }
        metrics.update(self.exchange.update_actor_from_pool(t))
        if metrics["sac/updated_from_pool"]:  # the pool's agent is the new anchor
            self.learner.loss.reset_anchor()
        return metrics

    def end_iteration(
        self, metrics: dict[str, float], timer: PhaseTimer, start: tuple[float, int]
    ) -> dict[str, float]:
        """ePOET's metrics and what the replay holds."""
        metrics.update(
            {
                "sac/buffer_size": float(len(self.learner.buffer)),
                "sac/es_transitions": float(self.mix.added["es"]),
                "sac/own_transitions": float(self.mix.added["sac"]),
                "sac/es_share": self.mix.share("es"),
            }
        )
        return super().end_iteration(metrics, timer, start)

    def novel_pairs(self) -> list[Pair]:
        """The environment copies the joins pair with are not novel (not in ANNECS)."""
        return [p for p in self.pool.pairs if p.env.index not in self.join_of]

    def progress(self, metrics: dict[str, float]) -> str:
        """ePOET's events, the actor's score and the join's mapped score against the actor's."""
        line = super().progress(metrics)
        if "sac/score" in metrics:
            line += f" sac_score={metrics['sac/score']:.1f}"
        if "join/mapped_score" in metrics:
            line += (
                f" join: {self.cfg.mapping} mapping scored {metrics['join/mapped_score']:.1f}"
                f" vs the SAC actor's {metrics['join/sac_score']:.1f}"
            )
        return line

    def join_due(self, t: int) -> bool:
        """Algorithm 1: t > 0 and t mod (k N_transfer) = k N_transfer - 2, with
        k = `join_every_transfers` and N_transfer the transfer interval."""
        period = self.cfg.join_every_transfers * self.transfer_interval
        return t > 0 and t % period == period - 2

    @property
    def joins(self) -> int:
        """Joins so far (each made one pair, and pairs are never dropped)."""
        return len(self.join_of)

    def lineage(self, pair: Pair) -> int:
        """The k-th join made the pair (0: the ES lineage): the paper's ePOET-SAC_gen<k>
        curves."""
        return self.join_of.get(pair.env.index, 0)

    # --- the shared replay and Train_SAC (Algorithm 2) ---------------------------------------
    def sync_obs_statistics(self) -> None:
        """The learner standardises with the pool's statistics of this iteration (updated by
        the ES step), its networks' raw-observation functions kept (SacLearner)."""
        stats = self.service.obs_norm
        if stats is not None:
            self.learner.set_obs_statistics(
                torch.from_numpy(stats.mean), torch.from_numpy(stats.std)
            )

    def add_to_replay(self, episodes: list[Episodes]) -> None:
        """The recorded ES transitions (float32, from the workers) into SAC's replay buffer."""
        data = es_transitions(episodes)
        if data is not None:
            self.learner.add(data)
            self.mix.add("es", data.numel())

    def sac_pair(self, t: int) -> Pair:
        """The active pair whose environment SAC uses at iteration t (paper: sampled)."""
        rng = np.random.default_rng(self.service.seed(SacKey.SAC_ENV, t))
        return self.pool.active[int(rng.integers(len(self.pool.active)))]

    def train_sac(self, t: int) -> dict[str, float]:
        """Train_SAC on the sampled environment's terrain (or a bowl, `sac_terrain=bowl`)."""
        pair = self.sac_pair(t)
        if self.cfg.sac_terrain == "bowl":
            terrain = make_terrain(
                dataclasses.replace(self.service.terrain_cfg, kind="bowl"),
                seed=self.service.seed(SacKey.SAC_BOWL, t),
                iteration=t,
            )
        else:
            terrain = self.service.terrain(pair.env, t)
        metrics = self._train_sac(
            terrain, self.service.seed(SacKey.SAC, t), self.service.seed(SacKey.SAC_SPAWN, t)
        )
        metrics["sac/env"] = float(pair.env.index)
        return metrics

    def pretrain(self) -> dict[str, float]:
        """The reference's pre-training: Train_SAC iterations on the root environment before
        iteration 0 (0 by default: Algorithm 1 has none)."""
        metrics: dict[str, float] = {}
        for i in range(self.cfg.pretrain_iterations):
            metrics = self._train_sac(
                self.service.terrain(self.pool.active[0].env, 0),
                self.service.seed(SacKey.PRETRAIN, i, 0),
                self.service.seed(SacKey.PRETRAIN, i, 1),
            )
        return metrics

    def _train_sac(self, terrain: Terrain, torch_seed: int, spawn_seed: int) -> dict[str, float]:
        """`frames_per_iteration` frames of the stochastic actor (uniform actions while fewer
        than `init_random_frames` were collected) on `terrain`, then the gradient updates."""
        terrain_env(self.sac_env).set_terrain(terrain)
        torch.manual_seed(torch_seed)
        data = self.collect(
            self.frames_per_iteration,
            spawn_seed,
            explore=self.mix.added["sac"] >= self.random_frames,
        )
        # a warm start's critics learn this pool's terrains before the actor first moves
        first = not self.mix.added["sac"]
        learned = self.learner.learn(
            data, self.updates_per_iteration, self.critic_updates if first else 0
        )
        self.mix.add("sac", data.numel())
        self.service.count_steps(data.numel())
        return {f"sac/{k}": v for k, v in {**episode_metrics(data), **learned}.items()}

    def collect(self, frames: int, spawn_seed: int, explore: bool) -> TensorDict:
        """SAC's frames on its env's terrain (collect.py): the stochastic actor's, or uniform
        actions (`explore` False)."""
        return collect(
            self.score_env, self.actor_net if explore else None, frames, spawn_seed, self.act_dim
        )

    def join(self, t: int) -> dict[str, float]:
        """The SAC actor joins the pool as a new pair, then crosses over with every other active
        agent. Logs the mapped agent's score next to the SAC actor's on the same terrain and
        starts: the gap is what the mapping loses (the paper's stated limitation)."""
        home = self.sac_pair(t)
        terrain = self.service.terrain(home.env, t)
        mapped = self.exchange.map_and_score(t, terrain, self.cfg.mapping, t)
        joins = self.joins + 1
        env = Environment(
            index=self.pool.next_index,
            genome=home.env.genome,
            generation=home.env.generation,
            parent=home.env.index,
            created_at=t,
        )
        pair = self.pool.admit(env, self.service.optimizer_for(env, mapped.theta))
        self.join_of[env.index] = joins
        self.service.keep_terrain(env, t, terrain)
        self.pool.record(pair, mapped.score)
        outcome = self.exchange.crossover_with(
            [p for p in self.pool.active if p is not pair], mapped.theta, t
        )
        metrics = {
            "joined": float(joins),
            "join/env": float(env.index),
            "join/sac_score": mapped.sac_score,
            "join/mapped_score": mapped.score,
            "join/mapping_error": mapped.error,
            **{f"join/{k}": v for k, v in mapped.cost.items()},
            "replaced": float(sum(new > old for old, new in outcome.values())),
        }
        for index, (old, new) in outcome.items():
            metrics[f"crossover/env{index}_old"] = old
            metrics[f"crossover/env{index}_new"] = new
            metrics[f"crossover/env{index}_replaced"] = float(new > old)
        return metrics

    # --- artifacts, checkpoints -----------------------------------------------------------------
    def artifacts(self, run_dir: Path, choice: str = "best") -> list[tuple[Path, str | None]]:
        """The pool's, plus the SAC actor as a policy file and the agents crossover replaced."""
        files = super().artifacts(run_dir, choice)
        sac = self.cfg.sac
        policy = export_policy(
            run_dir / "sac_policy.pt", self.learner.actor, self.sac_env, sac.hidden, sac.activation
        )
        files.append((policy, None))
        if self.exchange.replaced:
            folder = run_dir / "replaced"
            folder.mkdir(exist_ok=True)
            for agent in self.exchange.replaced:
                write_es_policy(
                    folder / f"env{agent.env}_it{agent.iteration}.npz",
                    agent.theta,
                    agent.score,
                    self.service.layer_sizes,
                    self.service.evaluator.agent,
                )
            files.append((folder, "replaced"))
        return files

    def close(self) -> None:
        self.sac_env.close()

    def state_dict(self) -> dict[str, Any]:
        return {
            **super().state_dict(),
            "sac": self.learner.state_dict(),
            "mix": self.mix.state_dict(),
            "replaced": [dataclasses.asdict(a) for a in self.exchange.replaced],
            "join_of": dict(self.join_of),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.learner.load_state_dict(state["sac"])
        self.mix.load_state_dict(state["mix"])
        self.exchange.replaced[:] = [ReplacedAgent(**a) for a in state["replaced"]]
        # checkpoints of format 2 kept the join number on each pair
        self.join_of = state.get("join_of") or {
            s["env"].index: s["sac_join"]
            for s in state["active"] + state["archived"]
            if s.get("sac_join")
        }
