"""ePOET-SAC's steps between the SAC actor and the pool, over the pool's service (paper Algorithms
1 and 3): the actor's deterministic score on a pool environment, the mapping of the actor into
an ES agent (by bridge.py's functions or DAgger), Algorithm 1's update of the actor from the
best pool agent, and Algorithm 3's crossover of a donor with pool agents. `EpoetSac` (loop.py)
calls these from its transfer and join steps."""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn
from torchrl.data import ReplayBuffer

from epoet.envs.terrain_env import TerrainEnv
from epoet.epoet_sac.bridge import (
    Mapped,
    ReplacedAgent,
    crossover,
    distill_into_actor,
    distill_into_es,
    random_mapping,
)
from epoet.epoet_sac.config import DaggerConfig, DistillConfig
from epoet.epoet_sac.dagger import dagger_into_es
from epoet.epoet_sac.keys import SacKey
from epoet.open_ended.keys import Key
from epoet.open_ended.pairs import Pair, Pool
from epoet.open_ended.service import Service
from epoet.rl.env import OBS
from epoet.rollout.policy import init_params
from epoet.rollout.populations import Agents, Request
from epoet.terrain import Terrain


@dataclass
class ActorExchange:
    """The SAC actor (`actor_net`, scored on `score_env`, SAC's own gym env), the pool and its
    service, the replay the mappings are fitted on, and the agents crossover replaced."""

    service: Service
    pool: Pool
    actor_net: nn.Module  # raw obs -> (loc, scale)
    score_env: TerrainEnv
    buffer: ReplayBuffer
    distill: DistillConfig
    dagger_cfg: DaggerConfig
    replaced: list[ReplacedAgent] = field(default_factory=list)

    def actor_episodes(self, terrain: Terrain, spawn_seeds: np.ndarray) -> tuple[list, np.ndarray]:
        """Episodes of the SAC actor's deterministic policy, tanh(loc(s)), on `terrain`, one per
        spawn seed: their returns and the raw observations the actor acted on."""
        env, returns, states = self.score_env, [], []
        env.set_terrain(terrain)  # kept by every reset below (SAC's env never resamples)
        with torch.no_grad():
            for seed in spawn_seeds:
                obs, _ = env.reset(seed=int(seed))
                total, done = 0.0, False
                while not done:
                    states.append(obs)
                    loc, _ = self.actor_net(torch.as_tensor(obs, dtype=torch.float32))
                    obs, reward, terminated, truncated, info = env.step(torch.tanh(loc).numpy())
                    total += reward
                    done = terminated or truncated
                self.service.count_steps(info["steps"])
                returns.append(total)
        return returns, np.asarray(states)

    def actor_score(self, terrain: Terrain, spawn_seeds: np.ndarray) -> float:
        """Mean return of the SAC actor's deterministic policy on `terrain`, one episode per
        spawn seed."""
        return float(np.mean(self.actor_episodes(terrain, spawn_seeds)[0]))

    @torch.no_grad()
    def actor_actions(self, states: np.ndarray) -> np.ndarray:
        """The actor's deterministic actions tanh(loc(s)) on raw observations (N, obs)."""
        loc, _ = self.actor_net(torch.as_tensor(states, dtype=torch.float32))
        return torch.tanh(loc).double().numpy()

    def dagger(self, t: int, terrain: Terrain) -> tuple[np.ndarray, float, dict[str, float]]:
        """The actor mapped by DAgger on `terrain` (dagger.py; keyed by t), its final action
        error and its cost: episodes and environment steps (the actor's and the student's) and
        seconds."""
        service, d = self.service, self.dagger_cfg
        started = time.perf_counter()
        returns, teacher_states = self.actor_episodes(
            terrain, service.seeds(d.episodes, SacKey.DAGGER, t, 0)
        )

        def roll_out(theta: np.ndarray, round_: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            seeds = service.seeds(d.episodes, SacKey.DAGGER, t, round_)
            agents = Agents.of(service.policy(theta[None]), seeds)
            episodes = service.run([Request(terrain, agents, record=d.episodes)])[0]
            assert episodes.transitions is not None  # every episode was recorded
            return episodes.transitions["obs"], episodes.returns.ravel(), episodes.lengths.ravel()

        mapped = dagger_into_es(
            self.actor_actions,
            teacher_states,
            roll_out,
            init_params(service.seed(SacKey.JOIN, t, 0), service.layer_sizes),
            service.layer_sizes,
            d,
            seed=service.seed(SacKey.DAGGER, t),
            standardizer=service.standardizer(),
        )
        cost = {
            "dagger/episodes": float(len(returns) + mapped.episodes),
            "dagger/env_steps": float(len(teacher_states) + mapped.env_steps),
            "dagger/states": float(mapped.states),
            "dagger/seconds": time.perf_counter() - started,
            "dagger/student_return": mapped.student_returns[-1],
        }
        return mapped.theta, mapped.error, cost

    def replay_states(self, torch_seed: int) -> np.ndarray:
        """`distill.states` observations drawn uniformly from the replay buffer."""
        torch.manual_seed(torch_seed)
        return self.buffer.sample(self.distill.states)[OBS].numpy()

    def _distill_kwargs(self, seed: int) -> dict[str, Any]:
        d = self.distill
        return {"epochs": d.epochs, "batch": d.batch, "lr": d.lr, "seed": seed}

    def update_actor_from_pool(self, t: int) -> dict[str, float]:
        """Algorithm 1's "SAC_Actor = theta_top" when the best pool agent beats the actor on that
        agent's environment (same starts as its evaluation). An ES agent cannot be copied into
        the actor (other layer sizes): the actor's mean is distilled from it on replay states,
        and the distilled actor is kept only if it then scores higher than the actor did, on the
        same terrain and starts (Algorithm 3's rule for a crossover child; a deviation: the
        paper's copy cannot fail, a distillation can, and a failed one would replace a walking
        actor by a falling one). `sac/updated_from_pool`: 1 when it was kept."""
        service = self.service
        top = max(self.pool.active, key=lambda p: p.score)
        terrain = service.terrain(top.env, t)
        seeds = service.seeds(service.eval_episodes, Key.EVAL, top.env.index, t)
        sac_score = self.actor_score(terrain, seeds)
        metrics = {"sac/score": sac_score, "sac/top_score": top.score, "sac/updated_from_pool": 0.0}
        if sac_score < top.score:
            before = copy.deepcopy(self.actor_net.state_dict())
            metrics["sac/distill_error"] = distill_into_actor(  # raw-observation agent
                self.actor_net,
                service.policy(top.theta),
                self.replay_states(service.seed(SacKey.SAC, t, 1)),
                service.layer_sizes,
                **self._distill_kwargs(service.seed(SacKey.SAC, t, 2)),
            )
            metrics["sac/distilled_score"] = self.actor_score(terrain, seeds)
            if metrics["sac/distilled_score"] > sac_score:
                metrics["sac/updated_from_pool"] = 1.0
            else:
                self.actor_net.load_state_dict(before)
        return metrics

    def map_actor(
        self, t: int, mapping: str, terrain: Terrain
    ) -> tuple[np.ndarray, float, dict[str, float]]:
        """The SAC actor as an ES vector by `mapping` (DAgger on `terrain`), the fit's action
        error (NaN for the random mapping) and what the mapping cost (DAgger's)."""
        service, sizes = self.service, self.service.layer_sizes
        if mapping == "random":
            rng = np.random.default_rng(service.seed(SacKey.JOIN, t))
            return random_mapping(self.actor_net, sizes, rng), float("nan"), {}
        if mapping == "dagger":
            return self.dagger(t, terrain)
        init = init_params(service.seed(SacKey.JOIN, t, 0), sizes)
        theta, error = distill_into_es(
            self.actor_net,
            self.replay_states(service.seed(SacKey.JOIN, t, 1)),
            sizes,
            init,
            standardizer=service.standardizer(),
            **self._distill_kwargs(service.seed(SacKey.JOIN, t, 2)),
        )
        return theta, error, {}

    def map_and_score(self, t: int, terrain: Terrain, mapping: str, *ids: int) -> Mapped:
        """Map the SAC actor (random draws keyed by t), then score the mapped agent and the
        actor on `terrain` from the same starts (keyed by `ids`)."""
        service = self.service
        theta, error, cost = self.map_actor(t, mapping, terrain)
        score = float(
            service.scores([service.eval_request(terrain, theta[None], SacKey.JOIN_EVAL, *ids)])[0][
                0
            ]
        )
        sac_score = self.actor_score(
            terrain, service.seeds(service.eval_episodes, SacKey.JOIN_EVAL, *ids)
        )
        return Mapped(theta, error, score, sac_score, cost)

    def crossover_with(
        self, pairs: list[Pair], donor: np.ndarray, t: int
    ) -> dict[int, tuple[float, float]]:
        """Algorithm 3: each agent and its crossover with `donor` are rolled out from the same
        starts on the agent's environment; the child replaces the agent only if its return is
        higher, and the original is archived. Returns {env index: (old, new) return}."""
        service = self.service
        children = [
            crossover(
                p.theta,
                donor,
                np.random.default_rng(service.seed(SacKey.CROSSOVER, p.env.index, t)),
            )
            for p in pairs
        ]
        scores = service.scores(
            [
                service.eval_request(
                    service.terrain(p.env, t),
                    np.stack([p.theta, child]),
                    SacKey.CROSSOVER_EVAL,
                    p.env.index,
                    t,
                )
                for p, child in zip(pairs, children)
            ]
        )
        outcome = {}
        for pair, child, (old, new) in zip(pairs, children, scores):
            outcome[pair.env.index] = (float(old), float(new))
            if new > old:
                self.replaced.append(
                    ReplacedAgent(pair.env.index, t, pair.theta.copy(), float(old))
                )
                self.pool.replace_agent(pair, child, float(new))
        return outcome
