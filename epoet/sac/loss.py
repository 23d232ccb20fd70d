"""SAC's loss (Haarnoja et al. 2018, with automatic entropy tuning) as one module: the twin Q
networks as one batched ensemble, the actor's tanh-Gaussian written out, the target critics as
plain tensors.

Why not TorchRL's SACLoss: it swaps functional parameters into the networks on every call,
builds a distribution object per forward and routes every tensor through TensorDicts, about
1.5-2 ms of overhead per update on this CPU against ~14 ms of compute, so it ran at 0.83x of a
plain-PyTorch SAC (bench/sac_updates.py). This module computes the same three losses as
SACLoss (v2, TD(0) targets, "l2" critic loss, `-log_alpha * (log_pi + target_entropy)` for the
temperature) with the same networks the collector's actor uses:

- critic: sum over the two Q networks of mean (Q(s, a) - y)^2,
  y = r + gamma (1 - terminated) (min_j Q'_j(s', a') - alpha log pi(a' | s')), a' ~ pi(s');
- actor: mean(alpha log pi(a~ | s) - min_j Q_j(s, a~)), a~ ~ pi(s) reparameterised, the Q
  networks' weights detached so this loss moves only the actor;
- temperature: mean(-log_alpha (log pi(a~ | s) + target_entropy)), log pi detached.

With `anchor_weight` > 0 (ePOET-SAC's warm start, `algo.warm.anchor`) the actor's loss adds
anchor_weight * mean|Q| * mean ||tanh(loc(s)) - tanh(loc_0(s))||^2, loc_0 a frozen copy of the
actor it started from (`reset_anchor`): behaviour regularisation towards that actor, scaled by
the critics' magnitude as TD3+BC scales its Q term (Fujimoto & Gu 2021), so the weight does not
depend on the reward scale. Why: critics loaded from another run fit this run's returns badly
at first, and the actor that follows their action gradients loses its gait within a few hundred
updates (docs/results/epoet-sac-warm-start/).

The three losses touch disjoint parameters, so one Adam over all trainable ones equals SAC's
three optimisers with one learning rate (Adam is per parameter).

With a `standardize` module (ePOET-SAC with observation normalisation) the critics read the
standardised observation, as the actor does (the module sits in the actor's network too); the
replay keeps raw observations.
"""

from __future__ import annotations

import copy
import math

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.modules import ProbabilisticActor

LOG_2 = math.log(2.0)
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


class TwinQ(nn.Module):
    """`n` Q networks with the same layout as one ensemble: layer l holds (n, in, out) weights,
    so all critics run in one batched matmul per layer. Initialised as nn.Linear layers are."""

    def __init__(
        self, in_features: int, hidden: list[int], activation: type[nn.Module], n: int = 2
    ) -> None:
        super().__init__()
        sizes = [in_features, *hidden, 1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for n_in, n_out in zip(sizes[:-1], sizes[1:]):
            bound = 1.0 / math.sqrt(n_in)
            self.weights.append(nn.Parameter(torch.empty(n, n_in, n_out).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(n, 1, n_out).uniform_(-bound, bound)))
        self.activation = activation()

    def forward(
        self, obs: torch.Tensor, action: torch.Tensor, detach: bool = False
    ) -> torch.Tensor:
        """Q values (n, batch); `detach` evaluates without a gradient path to the weights."""
        h = torch.cat([obs, action], -1)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            if detach:
                w, b = w.detach(), b.detach()
            h = torch.baddbmm(b, h, w) if h.dim() == 3 else torch.matmul(h, w) + b
            if i < last:
                h = self.activation(h)
        return h.squeeze(-1)


class SacLoss(nn.Module):
    """The three SAC losses of a batch (see the module docstring); holds the target critics and
    the learned log-temperature."""

    def __init__(
        self,
        actor: ProbabilisticActor,
        critics: TwinQ,
        *,
        obs_key: str,
        gamma: float,
        alpha_init: float,
        target_entropy: float,
        standardize: nn.Module | None = None,
        anchor_weight: float = 0.0,
    ) -> None:
        super().__init__()
        self.policy_net = actor.module[0].module  # obs -> (loc, scale): the collector's net
        # the anchor holds its own copy of any standardisation in front of the actor, so it
        # stays one function of the raw observation while the statistics move
        self.anchor_weight = anchor_weight
        self.anchor = (
            copy.deepcopy(self.policy_net).requires_grad_(False) if anchor_weight > 0 else None
        )
        self.critic_input = nn.Identity() if standardize is None else standardize
        self.critics = critics
        self.target_critics = copy.deepcopy(critics).requires_grad_(False)
        self.log_alpha = nn.Parameter(torch.tensor(math.log(alpha_init)))
        self.obs_key, self.gamma, self.target_entropy = obs_key, gamma, target_entropy
        self.in_keys = [
            obs_key,
            "action",
            ("next", obs_key),
            ("next", "reward"),
            ("next", "terminated"),
        ]

    @torch.no_grad()
    def reset_anchor(self) -> None:
        """The actor as it is now becomes the anchor (no-op without one)."""
        if self.anchor is not None:
            self.anchor.load_state_dict(self.policy_net.state_dict())

    def _sample(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A reparameterised tanh-Gaussian action, its log-probability (TorchRL's TanhNormal
        on [-1, 1]: Normal log-density minus the tanh log-Jacobian, in its stable form) and the
        Gaussian's mean."""
        loc, scale = self.policy_net(obs)
        noise = torch.empty_like(loc).normal_()  # the draw torch.distributions.Normal makes
        pre_tanh = loc + scale * noise
        log_prob = (
            -0.5 * noise.square()
            - scale.log()
            - HALF_LOG_2PI
            - 2.0 * (LOG_2 - pre_tanh - nn.functional.softplus(-2.0 * pre_tanh))
        ).sum(-1)
        return torch.tanh(pre_tanh), log_prob, loc

    def forward(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        return self.losses(
            batch[self.obs_key],
            batch["action"],
            batch["next", self.obs_key],
            batch["next", "reward"],
            batch["next", "terminated"],
        )

    def losses(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        next_obs: torch.Tensor,
        reward: torch.Tensor,
        terminated: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        """The three losses on plain tensors (what bench/epoet_sac_cost.py --compile compiles)."""
        alpha = self.log_alpha.exp().detach()
        with torch.no_grad():
            next_action, next_log_prob, _ = self._sample(next_obs)
            next_q = self.target_critics(self.critic_input(next_obs), next_action).min(0).values
            not_done = 1.0 - terminated.squeeze(-1).float()
            target = reward.squeeze(-1) + self.gamma * not_done * (next_q - alpha * next_log_prob)
        q_obs = self.critic_input(obs)
        loss_qvalue = (self.critics(q_obs, action) - target).square().mean(-1).sum()
        new_action, log_prob, loc = self._sample(obs)
        q_new = self.critics(q_obs, new_action, detach=True).min(0).values
        loss_actor = (alpha * log_prob - q_new).mean()
        if self.anchor is not None:
            with torch.no_grad():
                anchored = torch.tanh(self.anchor(obs)[0])
                weight = self.anchor_weight * q_new.abs().mean()
            gap = (torch.tanh(loc) - anchored).square().sum(-1).mean()
            loss_actor = loss_actor + weight * gap
        loss_alpha = -(self.log_alpha * (log_prob.detach() + self.target_entropy)).mean()
        return {
            "loss_actor": loss_actor,
            "loss_qvalue": loss_qvalue,
            "loss_alpha": loss_alpha,
            "alpha": alpha,
            "entropy": -log_prob.detach().mean(),
        }

    @torch.no_grad()
    def update_targets(self, tau: float) -> None:
        """Soft target update: target <- (1 - tau) target + tau online."""
        torch._foreach_lerp_(
            list(self.target_critics.parameters()), list(self.critics.parameters()), tau
        )
