r"""The pieces of the V-MPO loss that need no TorchRL module: the E-step weights, the
temperature and trust-region terms, the KL to the collecting policy, the entropy and the
tensordict keys. :class:`~epoet.vmpo.loss.VMPOLoss` assembles them on a batch.

The loss of Song et al. (Sec. 3) is

.. math::

    \mathcal{L}(\phi, \theta, \eta, \alpha) = \mathcal{L}_V(\phi)
        + \mathcal{L}_\pi(\theta) + \mathcal{L}_\eta(\eta) + \mathcal{L}_\alpha(\theta, \alpha)

on a batch :math:`\mathcal{D}` of transitions, with

* the E-step (Sec. 3.2): :math:`\tilde{\mathcal{D}}` is the half of :math:`\mathcal{D}` with
  the largest advantages :math:`A`, and
  :math:`\psi(s, a) = \exp(A(s, a)/\eta) / \sum_{\tilde{\mathcal{D}}} \exp(A/\eta)` on
  :math:`\tilde{\mathcal{D}}`, 0 elsewhere (:func:`top_half_weights`);
* the policy loss :math:`\mathcal{L}_\pi = -\sum_{\tilde{\mathcal{D}}} \psi(s, a)
  \log \pi_\theta(a \mid s)`;
* the temperature loss :math:`\mathcal{L}_\eta = \eta \epsilon_\eta + \eta \log\big[
  \frac{1}{|\tilde{\mathcal{D}}|} \sum_{\tilde{\mathcal{D}}} \exp(A/\eta)\big]`;
* the M-step trust region :math:`\mathcal{L}_\alpha = \alpha\,(\epsilon_\alpha -
  \mathrm{sg}[D_{KL}]) + \mathrm{sg}[\alpha]\, D_{KL}` with
  :math:`D_{KL} = \frac{1}{|\mathcal{D}|} \sum_s \mathrm{KL}(\pi_{old}(\cdot \mid s)
  \,\|\, \pi_\theta(\cdot \mid s))`;
* the value loss (Sec. 3.1) :math:`\mathcal{L}_V = \frac{1}{2|\mathcal{D}|}
  \sum (V_\phi(s) - G)^2`, :math:`G` the value target.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict.nn import composite_lp_aggregate
from tensordict.utils import NestedKey
from torch import distributions as d
from torchrl.modules.distributions import has_analytic_entropy, has_analytic_kl
from torchrl.modules.distributions.utils import sample_and_log_prob

CRITIC_LOSS_TYPES = ("l1", "l2", "smooth_l1")


def check_settings(top_fraction: float, loss_critic_type: str, **positive: float) -> None:
    """Refuse settings V-MPO cannot run with (ValueError): a kept fraction outside (0, 1],
    an unknown critic loss, or one of `positive` (temperatures, bounds, the value loss's
    factor) not a finite number > 0."""
    if not 0.0 < top_fraction <= 1.0:
        raise ValueError(f"top_fraction must be in (0, 1], got {top_fraction}.")
    for name, value in positive.items():
        if not (value > 0 and math.isfinite(value)):
            raise ValueError(f"{name} must be a finite number > 0, got {value}.")
    if loss_critic_type not in CRITIC_LOSS_TYPES:
        raise ValueError(
            f"loss_critic_type must be one of {CRITIC_LOSS_TYPES}, got {loss_critic_type!r}."
        )


def top_half_weights(
    advantage: torch.Tensor,
    eta: torch.Tensor | float,
    fraction: float = 0.5,
    valid: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    r"""Non-parametric E-step of V-MPO: softmax weights on the best advantages.

    Song et al. (2019), Sec. 3.2: keep the subset :math:`\tilde{\mathcal{D}}` of the batch
    with the largest advantages and weight its samples by

    .. math::

        \psi(s, a) = \frac{\exp(A(s, a) / \eta)}
                          {\sum_{(s', a') \in \tilde{\mathcal{D}}} \exp(A(s', a') / \eta)},

    the rest of the batch gets weight 0. The paper keeps the top half (``fraction=0.5``).

    Args:
        advantage (torch.Tensor): the advantages; every entry, whatever the shape, is one
            sample of the batch.
        eta (torch.Tensor or float): the temperature :math:`\eta > 0`. It is detached: the
            weights are targets for the policy and carry no gradient.
        fraction (float, optional): share of the batch kept, in ``(0, 1]``: the
            ``floor(fraction * N)`` largest advantages of the ``N`` valid samples, at least
            one. Defaults to ``0.5``.
        valid (torch.Tensor, optional): boolean mask shaped like ``advantage``; invalid
            (e.g. padded) samples are never kept and do not count in ``N``.

    Returns:
        ``(weights, mask)``, both shaped like ``advantage``: ``mask`` marks
        :math:`\tilde{\mathcal{D}}`, ``weights`` sums to one over it and is zero elsewhere.

    Examples:
        >>> weights, mask = top_half_weights(torch.tensor([0.0, 2.0, 1.0, -1.0]), eta=1.0)
        >>> mask
        tensor([False,  True,  True, False])
        >>> weights  # softmax([2, 1]) on the kept half
        tensor([0.0000, 0.7311, 0.2689, 0.0000])
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}.")
    flat = advantage.detach().reshape(-1)
    eta = torch.as_tensor(eta, dtype=flat.dtype, device=flat.device).detach()
    if not bool((eta > 0).all()):
        raise ValueError(f"eta must be > 0, got {eta}.")
    if valid is None:
        num_valid = flat.numel()
    else:
        valid = valid.reshape(-1)
        # -inf never wins a top-k against a finite advantage
        flat = flat.masked_fill(~valid, float("-inf"))
        num_valid = int(valid.sum())
    if num_valid == 0:
        raise ValueError("top_half_weights needs at least one valid sample.")
    # floor rather than ceil: with fraction=0.5 an odd batch keeps its strictly better half
    num_kept = max(1, int(fraction * num_valid))
    mask = torch.zeros_like(flat, dtype=torch.bool)
    mask[flat.topk(num_kept).indices] = True
    weights = (flat / eta).masked_fill(~mask, float("-inf")).softmax(0)
    return weights.view_as(advantage), mask.view_as(advantage)


def sum_event_dims(value: torch.Tensor, batch_ndim: int) -> torch.Tensor:
    """One value per sample: distributions without an ``Independent`` wrapper (e.g. torch's
    ``Normal``) give one log-prob or KL per action dimension; the action's is their sum."""
    if value.ndim == batch_ndim:
        return value
    return value.flatten(batch_ndim).sum(-1)


def temperature_loss(
    kept_advantage: torch.Tensor, eta: torch.Tensor, eps_eta: float
) -> torch.Tensor:
    r""":math:`\mathcal{L}_\eta = \eta \epsilon_\eta + \eta \log\big[
    \frac{1}{|\tilde{\mathcal{D}}|} \sum_{\tilde{\mathcal{D}}} \exp(A/\eta)\big]` on the
    advantages the E-step kept: the dual of the E-step's KL constraint
    :math:`\mathrm{KL}(\psi \,\|\, \mathcal{U}) < \epsilon_\eta`. Its gradient in
    :math:`\eta` is :math:`\epsilon_\eta - \mathrm{KL}(\psi \,\|\, \mathcal{U})`, so
    :math:`\eta` grows while :math:`\psi` is more peaked than allowed and shrinks otherwise.
    """
    return eta * eps_eta + eta * (
        torch.logsumexp(kept_advantage / eta, dim=0) - math.log(kept_advantage.numel())
    )


def trust_region_loss(kl: torch.Tensor, alpha: torch.Tensor, eps_alpha: float) -> torch.Tensor:
    r""":math:`\mathcal{L}_\alpha = \alpha\,(\epsilon_\alpha - \mathrm{sg}[D_{KL}])
    + \mathrm{sg}[\alpha]\, D_{KL}`, the M-step trust region: the policy is penalised by
    :math:`\alpha D_{KL}` and :math:`\alpha` grows while :math:`D_{KL} > \epsilon_\alpha`.
    Both terms live in this one loss, as in the paper."""
    return alpha * (eps_alpha - kl.detach()) + alpha.detach() * kl


def policy_kl(
    old_dist: d.Distribution,
    dist: d.Distribution,
    log_prob: torch.Tensor,
    old_log_prob: Callable[[], torch.Tensor],
) -> torch.Tensor:
    r"""Per-sample KL(pi_old || pi_theta), differentiable in theta.

    The closed form when torch registers one (``Normal``, ``IndependentNormal``,
    ``TanhNormal`` -- whose shared tanh bijection leaves the KL of the underlying Gaussians
    unchanged --, ``Categorical``, ...); otherwise it is estimated from the batch itself: the
    actions were drawn from :math:`\pi_{old}`, so the batch mean of
    ``sample_log_prob - log pi(action)`` is an unbiased estimate. `old_log_prob` (that
    ``sample_log_prob``) is read only then.
    """
    if has_analytic_kl(old_dist, dist):
        return sum_event_dims(d.kl_divergence(old_dist, dist), log_prob.ndim)
    # No closed form: the batch's actions were sampled from pi_old, so
    # log pi_old(a) - log pi_theta(a) averages to KL(pi_old || pi_theta).
    return sum_event_dims(old_log_prob().detach(), log_prob.ndim) - log_prob


def policy_entropy(dist: d.Distribution, batch_ndim: int) -> torch.Tensor:
    """Per-sample entropy of `dist`: the closed form, else a one-sample estimate."""
    if has_analytic_entropy(dist):
        value = dist.entropy()
    else:
        value = -sample_and_log_prob(dist)[1]
    return sum_event_dims(value, batch_ndim)


@dataclass
class VMPOKeys:
    """The tensordict keys :class:`~epoet.vmpo.loss.VMPOLoss` reads and writes, with their
    defaults.

    The loss's ``_AcceptedKeys``: each can be set with ``.set_keys(key_name=key_value)``.

    Attributes:
        advantage (NestedKey): the input key of the advantage. Defaults to
            ``"advantage"``.
        value_target (NestedKey): the input key of the value target. Defaults to
            ``"value_target"``.
        value (NestedKey): the key of the state value the critic writes. Defaults to
            ``"state_value"``.
        sample_log_prob (NestedKey): the input key of the collecting policy's
            log-probability of the action, read when the KL has no closed form.
            Defaults to the actor's log-prob key (``"action_log_prob"`` unless
            :func:`~tensordict.nn.composite_lp_aggregate` is set, then
            ``"sample_log_prob"``).
        action (NestedKey): the input key of the action. Defaults to the actor's
            sample key, ``"action"``.
        reward (NestedKey): the reward key, for the value estimator. Defaults to
            ``"reward"``.
        done (NestedKey): the done key, for the value estimator. Defaults to
            ``"done"``.
        terminated (NestedKey): the terminated key, for the value estimator. Defaults
            to ``"terminated"``.
    """

    advantage: NestedKey = "advantage"
    value_target: NestedKey = "value_target"
    value: NestedKey = "state_value"
    sample_log_prob: NestedKey | None = None
    action: NestedKey = "action"
    reward: NestedKey = "reward"
    done: NestedKey = "done"
    terminated: NestedKey = "terminated"

    def __post_init__(self) -> None:
        if self.sample_log_prob is None:
            self.sample_log_prob = (
                "sample_log_prob" if composite_lp_aggregate(nowarn=True) else "action_log_prob"
            )
