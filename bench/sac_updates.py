"""Gradient updates per second: our SAC update vs the same update in plain PyTorch.

"Ours" is exactly the runner's code path, `epoet.sac.learner.SacLearner.gradient_steps`: uniform
samples from its TorchRL replay buffer, our SacLoss (epoet/sac/loss.py), the learner's fused
Adam and its soft target update.
"Plain" is a CleanRL-style SAC written below: twin Q networks, a tanh-Gaussian actor, automatic
entropy tuning and a soft target update, one Adam per part (CleanRL's layout). Same sizes:
batch 256, [256, 256] ReLU, 53-dim observations, 18-dim actions. Rounds alternate between the
two so that a change in machine load hits both; the ratio is of summed wall-clock times. Both
run with the runner's torch threads (`workers.num`, default all usable cores; --threads
overrides). Updates per CPU second of this process are printed too: on a machine shared with
other work they show the cost without the time other processes held the cores.

    .venv/bin/python bench/sac_updates.py [--rounds 20] [--updates 25] [--threads N]

Prints one line per round and, last, `sac/plain = X` (>= 1.0: ours is at least as fast).
"""
from __future__ import annotations

import argparse
import math
import time

import torch
import torch.nn.functional as F
from tensordict import TensorDict
from torch import nn

from epoet.config import load
from epoet.envs.spaces import robot_sizes
from epoet.rl.env import make_env
from epoet.rl.harness import set_threads
from epoet.sac.learner import SacLearner

BUFFER = 10_000
OBS_DIM, ACT_DIM = robot_sizes(load([]).agent)  # the default robot's: the hexapod's 53 and 18


class PlainActor(nn.Module):
    """CleanRL's SAC actor: mean and log-std heads, log-std squashed into [-5, 2]."""

    def __init__(self, hidden: int = 256) -> None:
        super().__init__()
        self.body = nn.Sequential(nn.Linear(OBS_DIM, hidden), nn.ReLU(),
                                  nn.Linear(hidden, hidden), nn.ReLU())
        self.mean = nn.Linear(hidden, ACT_DIM)
        self.log_std = nn.Linear(hidden, ACT_DIM)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.body(obs)
        log_std = -5.0 + 3.5 * (torch.tanh(self.log_std(h)) + 1.0)
        std = log_std.exp()
        noise = torch.randn_like(std)
        pre = self.mean(h) + std * noise
        action = torch.tanh(pre)
        log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        log_prob = log_prob - torch.log1p(-action.pow(2) + 1e-6).sum(-1)
        return action, log_prob


def q_net(hidden: int = 256) -> nn.Module:
    return nn.Sequential(nn.Linear(OBS_DIM + ACT_DIM, hidden), nn.ReLU(),
                         nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))


class PlainSac:
    """The plain-PyTorch reference update (CleanRL sac_continuous_action.py, one step)."""

    def __init__(self, lr: float = 3e-4, gamma: float = 0.99, tau: float = 0.005) -> None:
        self.actor = PlainActor()
        self.q1, self.q2 = q_net(), q_net()
        self.q1_target, self.q2_target = q_net(), q_net()
        self.q1_target.load_state_dict(self.q1.state_dict())
        self.q2_target.load_state_dict(self.q2.state_dict())
        self.log_alpha = torch.zeros(1, requires_grad=True)
        self.q_opt = torch.optim.Adam([*self.q1.parameters(), *self.q2.parameters()], lr=lr)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=lr)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=lr)
        self.gamma, self.tau, self.target_entropy = gamma, tau, -float(ACT_DIM)

    def update(self, obs, action, reward, next_obs, terminated) -> None:
        alpha = self.log_alpha.exp().detach()
        with torch.no_grad():
            next_action, next_log_prob = self.actor(next_obs)
            x = torch.cat([next_obs, next_action], -1)
            next_q = torch.min(self.q1_target(x), self.q2_target(x)).squeeze(-1)
            target = reward + (1.0 - terminated) * self.gamma * (next_q - alpha * next_log_prob)
        x = torch.cat([obs, action], -1)
        q_loss = F.mse_loss(self.q1(x).squeeze(-1), target) + F.mse_loss(
            self.q2(x).squeeze(-1), target)
        self.q_opt.zero_grad()
        q_loss.backward()
        self.q_opt.step()

        new_action, log_prob = self.actor(obs)
        x = torch.cat([obs, new_action], -1)
        actor_loss = (alpha * log_prob - torch.min(self.q1(x), self.q2(x)).squeeze(-1)).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        self.actor_opt.step()

        alpha_loss = -(self.log_alpha.exp() * (log_prob.detach() + self.target_entropy)).mean()
        self.alpha_opt.zero_grad()
        alpha_loss.backward()
        self.alpha_opt.step()

        with torch.no_grad():
            for net, target_net in ((self.q1, self.q1_target), (self.q2, self.q2_target)):
                for p, tp in zip(net.parameters(), target_net.parameters()):
                    tp.data.copy_(self.tau * p.data + (1 - self.tau) * tp.data)


def make_ours(threads: int | None) -> tuple[SacLearner, int]:
    """The runner's SAC learner from the `algo=sac` config; torch threads set as the runner does
    (`workers.num`, default: the cores this process may use). Returns it and the thread count."""
    overrides = ["algo=sac", f"budget.frames={BUFFER}"]
    if threads is not None:
        overrides.append(f"workers.num={threads}")
    cfg = load(overrides)
    threads = set_threads(cfg)
    env = make_env(cfg, obs_norm=cfg.algo.obs_norm, seed=0)
    learner = SacLearner(cfg.algo, env)
    env.close()
    return learner, threads


def random_transitions(n: int) -> TensorDict:
    return TensorDict({
        "observation": torch.randn(n, OBS_DIM), "action": torch.rand(n, ACT_DIM) * 2 - 1,
        "next": {"observation": torch.randn(n, OBS_DIM), "reward": torch.randn(n, 1),
                 "done": torch.zeros(n, 1, dtype=torch.bool),
                 "terminated": torch.zeros(n, 1, dtype=torch.bool)}}, [n])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=20)
    parser.add_argument("--updates", type=int, default=25, help="updates per round and side")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads for both (default: as the runner, all usable cores)")
    args = parser.parse_args()
    torch.manual_seed(0)
    ours, threads = make_ours(args.threads)
    print(f"torch threads: {threads}, batch {ours.batch_size}, [256, 256] networks")
    data = random_transitions(BUFFER)
    ours.buffer.extend(data)
    plain = PlainSac()
    flat = {k: data.get(k) for k in ("observation", "action")}
    nxt = data["next"]

    def plain_batch():
        idx = torch.randint(BUFFER, (ours.batch_size,))
        return (flat["observation"][idx], flat["action"][idx], nxt["reward"][idx, 0],
                nxt["observation"][idx], nxt["terminated"][idx, 0].float())

    def run_ours(n: int) -> tuple[float, float]:
        wall, cpu = time.perf_counter(), time.process_time()
        ours.gradient_steps(n)
        return time.perf_counter() - wall, time.process_time() - cpu

    def run_plain(n: int) -> tuple[float, float]:
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(n):
            plain.update(*plain_batch())
        return time.perf_counter() - wall, time.process_time() - cpu

    run_ours(10), run_plain(10)  # warm-up: allocator, vmap and autograd caches
    ours_wall = ours_cpu = plain_wall = plain_cpu = 0.0
    for r in range(args.rounds):
        # alternate who goes first, so a load change within a round hits both sides alike
        if r % 2 == 0:
            (ow, oc), (pw, pc) = run_ours(args.updates), run_plain(args.updates)
        else:
            (pw, pc), (ow, oc) = run_plain(args.updates), run_ours(args.updates)
        ours_wall, ours_cpu, plain_wall, plain_cpu = (
            ours_wall + ow, ours_cpu + oc, plain_wall + pw, plain_cpu + pc)
        print(f"round {r}: ours {args.updates / ow:.1f} updates/s, "
              f"plain {args.updates / pw:.1f} updates/s", flush=True)
    n = args.rounds * args.updates
    print(f"ours {n / ours_wall:.1f} updates/s, plain {n / plain_wall:.1f} updates/s; "
          f"per CPU second: ours {n / ours_cpu:.1f}, plain {n / plain_cpu:.1f} "
          f"(ratio {plain_cpu / ours_cpu:.3f})")
    print(f"sac/plain = {plain_wall / ours_wall:.3f}")


if __name__ == "__main__":
    main()
