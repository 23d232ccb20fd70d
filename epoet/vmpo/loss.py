r"""V-MPO as a TorchRL :class:`~torchrl.objectives.LossModule`.

Song, Abdolmaleki et al. (2019), "V-MPO: On-Policy Maximum a Posteriori Policy Optimization
for Discrete and Continuous Control" (ICLR 2020, arXiv:1909.12238). TorchRL 0.14 ships no
V-MPO (or MPO) loss; :class:`VMPOLoss` follows the shape of
:class:`~torchrl.objectives.ClipPPOLoss`: it takes an actor and a critic, reads an on-policy
batch whose advantages and value targets a TorchRL value estimator (GAE by default) has
written, and returns the loss terms as ``loss_*`` entries whose sum is what the trainer
backpropagates.

The equations and the pieces that need no TorchRL module (the E-step weights, the temperature
and trust-region terms, the KL, the keys) are in :mod:`epoet.vmpo.loss_parts`.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams, unravel_key
from tensordict.nn import (
    ProbabilisticTensorDictModule,
    ProbabilisticTensorDictSequential,
    TensorDictModule,
    dispatch,
)
from tensordict.utils import NestedKey
from torch import nn
from torchrl.objectives import LossModule
from torchrl.objectives.utils import (
    ValueEstimators,
    dispatch_value_estimator,
    distance_loss,
)

from epoet.vmpo.loss_parts import (
    VMPOKeys,
    check_settings,
    policy_entropy,
    policy_kl,
    sum_event_dims,
    temperature_loss,
    top_half_weights,
    trust_region_loss,
)

__all__ = ["VMPOLoss"]


class VMPOLoss(LossModule):
    r"""V-MPO loss (Song et al., 2019) with a learned temperature and KL multiplier.

    The terms, all computed from one batch :math:`\mathcal{D}` (see
    :mod:`epoet.vmpo.loss_parts` for the equations):

    - ``loss_policy``: :math:`\mathcal{L}_\pi = -\sum_{\tilde{\mathcal{D}}} \psi(s, a)
      \log \pi_\theta(a \mid s)`, the weighted maximum likelihood of the E-step's
      non-parametric policy :math:`\psi` (:func:`top_half_weights`, detached);
    - ``loss_eta``: :math:`\mathcal{L}_\eta`, the dual of the E-step's KL constraint on
      :math:`\psi`, which tunes the temperature :math:`\eta` (:func:`temperature_loss`);
    - ``loss_alpha``: :math:`\mathcal{L}_\alpha`, the M-step trust region: the policy is
      penalised by :math:`\alpha D_{KL}` and :math:`\alpha` grows while
      :math:`D_{KL} > \epsilon_\alpha`. Both terms live in this entry, as in the paper
      (:func:`trust_region_loss`);
    - ``loss_critic``: ``critic_coeff * distance(V(s), value_target)``, by default
      :math:`\frac{1}{2}(V_\phi(s) - G)^2` (Sec. 3.1).

    :math:`\eta` and :math:`\alpha` are ``exp`` of the free parameters ``log_eta`` and
    ``log_alpha`` (as :class:`~torchrl.objectives.SACLoss` learns its entropy
    coefficient): positive without projection, and optimisers step them multiplicatively,
    which suits a temperature whose scale follows the advantages'.

    :math:`\pi_{old}` in :math:`D_{KL}` is the policy that collected the batch. It is rebuilt
    from the distribution parameters its actor wrote into the batch at collection time
    (e.g. ``"loc"`` and ``"scale"``, as collectors store every actor output), through
    :meth:`~tensordict.nn.ProbabilisticTensorDictSequential.build_dist_from_params`, as
    :class:`~torchrl.objectives.KLPENPPOLoss` does. A frozen copy of the actor would need
    extra parameters and a sync at every collection; the stored parameters are exactly the
    data's policy at no cost, across all the epochs spent on the batch. The KL is the closed
    form when torch registers one, else an estimate from the batch (:func:`policy_kl`).

    Song et al. bound the Gaussian's mean and covariance with separate multipliers; this
    loss uses one KL and one multiplier :math:`\alpha`.

    Padded or otherwise invalid samples (see :attr:`loss_mask_key`) are left out of the
    top-half selection and of every mean.

    Args:
        actor_network (ProbabilisticTensorDictSequential): the policy, e.g. a
            :class:`~torchrl.modules.ProbabilisticActor`, with a single action
            distribution.
        critic_network (TensorDictModule): the state-value network, e.g. a
            :class:`~torchrl.modules.ValueOperator`.

    Keyword Args:
        top_fraction (float, optional): share of the batch, ranked by advantage, that the
            E-step keeps, in ``(0, 1]``. Defaults to ``0.5``.
        eta_init (float, optional): initial temperature :math:`\eta > 0`. Defaults to ``1.0``.
        eps_eta (float, optional): bound :math:`\epsilon_\eta > 0` on
            :math:`\mathrm{KL}(\psi \,\|\, \mathcal{U})`. Defaults to ``0.02``.
        alpha_init (float, optional): initial KL multiplier :math:`\alpha > 0`. Defaults to
            ``0.1``.
        eps_alpha (float, optional): trust-region bound :math:`\epsilon_\alpha > 0` on the
            mean KL between the collecting and the current policy. Defaults to ``0.01``.
        critic_coeff (float, optional): factor of the value loss, ``> 0``. Defaults to
            ``0.5``, the paper's :math:`\frac{1}{2}`.
        loss_critic_type (str, optional): ``"l2"``, ``"l1"`` or ``"smooth_l1"``, see
            :func:`~torchrl.objectives.utils.distance_loss`. Defaults to ``"l2"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
        >>> from torchrl.objectives.value import GAE
        >>> net = torch.nn.Sequential(
        ...     MLP(in_features=4, out_features=2, num_cells=[64, 64],
        ...         activation_class=torch.nn.Tanh),
        ...     AddStateIndependentNormalScale(2),
        ... )
        >>> actor = ProbabilisticActor(
        ...     TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        ...     in_keys=["loc", "scale"], distribution_class=TanhNormal, return_log_prob=True,
        ... )
        >>> critic = ValueOperator(MLP(in_features=4, out_features=1, num_cells=[64, 64]),
        ...                        in_keys=["observation"])
        >>> loss = VMPOLoss(actor, critic)
        >>> data = TensorDict({"observation": torch.randn(8, 4)}, [8])
        >>> with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        ...     data = actor(data)  # as a collector: writes loc, scale, action, action_log_prob
        >>> data["next"] = TensorDict({
        ...     "observation": torch.randn(8, 4), "reward": torch.randn(8, 1),
        ...     "done": torch.zeros(8, 1, dtype=torch.bool),
        ...     "terminated": torch.zeros(8, 1, dtype=torch.bool)}, [8])
        >>> data = GAE(gamma=0.99, lmbda=0.95, value_network=critic)(data)
        >>> out = loss(data)
        >>> sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        >>> sorted(out.keys())
        ['alpha', 'entropy', 'eta', 'kl', 'loss_alpha', 'loss_critic', 'loss_eta', 'loss_policy']
    """

    _AcceptedKeys = VMPOKeys
    default_keys = _AcceptedKeys
    tensor_keys: VMPOKeys
    default_value_estimator = ValueEstimators.GAE
    SUPPORTED_VALUE_ESTIMATORS = (
        ValueEstimators.TD0,
        ValueEstimators.TD1,
        ValueEstimators.TDLambda,
        ValueEstimators.GAE,
    )

    actor_network: ProbabilisticTensorDictSequential
    critic_network: TensorDictModule
    actor_network_params: TensorDictParams
    critic_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    target_critic_network_params: TensorDictParams

    def __init__(
        self,
        actor_network: ProbabilisticTensorDictSequential,
        critic_network: TensorDictModule,
        *,
        top_fraction: float = 0.5,
        eta_init: float = 1.0,
        eps_eta: float = 0.02,
        alpha_init: float = 0.1,
        eps_alpha: float = 0.01,
        critic_coeff: float = 0.5,
        loss_critic_type: str = "l2",
    ) -> None:
        if not isinstance(actor_network, ProbabilisticTensorDictSequential):
            raise TypeError(
                "actor_network must be a ProbabilisticTensorDictSequential (e.g. a "
                f"ProbabilisticActor), got {type(actor_network).__name__}."
            )
        if len(actor_network.log_prob_keys) != 1:
            raise ValueError(
                "VMPOLoss supports actors with a single action distribution, got "
                f"log-prob keys {actor_network.log_prob_keys}."
            )
        check_settings(
            top_fraction,
            loss_critic_type,
            eta_init=eta_init,
            eps_eta=eps_eta,
            alpha_init=alpha_init,
            eps_alpha=eps_alpha,
            critic_coeff=critic_coeff,
        )

        self._in_keys: list[NestedKey] | None = None
        super().__init__()
        self.convert_to_functional(actor_network, "actor_network")
        self.convert_to_functional(critic_network, "critic_network")
        device = next(self.parameters()).device
        self.log_eta = nn.Parameter(torch.tensor(math.log(eta_init), device=device))
        self.log_alpha = nn.Parameter(torch.tensor(math.log(alpha_init), device=device))
        self.top_fraction = top_fraction
        self.eps_eta = eps_eta
        self.eps_alpha = eps_alpha
        self.critic_coeff = critic_coeff
        self.loss_critic_type = loss_critic_type
        self.set_keys(
            sample_log_prob=actor_network.log_prob_keys[0],
            action=actor_network.dist_sample_keys[0],
        )

    @property
    def eta(self) -> torch.Tensor:
        """The current temperature :math:`\\eta` (detached)."""
        return self.log_eta.detach().exp()

    @property
    def alpha(self) -> torch.Tensor:
        """The current KL multiplier :math:`\\alpha` (detached)."""
        return self.log_alpha.detach().exp()

    def _set_in_keys(self) -> None:
        dist_module = next(
            module
            for module in reversed(list(self.actor_network.modules()))
            if isinstance(module, ProbabilisticTensorDictModule)
        )
        keys = [
            *self.actor_network.in_keys,
            *self.critic_network.in_keys,
            *(unravel_key(("next", key)) for key in self.critic_network.in_keys),
            *dist_module.in_keys,
            self.tensor_keys.action,
            self.tensor_keys.sample_log_prob,
            unravel_key(("next", self.tensor_keys.reward)),
            unravel_key(("next", self.tensor_keys.done)),
            unravel_key(("next", self.tensor_keys.terminated)),
        ]
        self._in_keys = list(dict.fromkeys(keys))

    @property
    def in_keys(self) -> list[NestedKey]:
        if self._in_keys is None:
            self._set_in_keys()
            assert self._in_keys is not None  # _set_in_keys sets it
        return self._in_keys

    @in_keys.setter
    def in_keys(self, values: list[NestedKey]) -> None:
        self._in_keys = values

    @property
    def out_keys(self) -> list[NestedKey]:
        return [
            "loss_policy",
            "loss_critic",
            "loss_eta",
            "loss_alpha",
            "eta",
            "alpha",
            "kl",
            "entropy",
        ]

    def make_value_estimator(
        self, value_type: ValueEstimators | None = None, **hyperparams
    ) -> VMPOLoss:
        """Builds the value estimator used when a batch comes without advantages.

        Defaults to GAE with TorchRL's default ``gamma=0.99, lmbda=0.95``; see
        :meth:`~torchrl.objectives.LossModule.make_value_estimator`.
        """
        value_type, hyperparams = self._prepare_value_estimator_kwargs(value_type, **hyperparams)
        if value_type is None:
            return self
        dispatch_value_estimator(
            self,
            value_type,
            supported=self.SUPPORTED_VALUE_ESTIMATORS,
            tensor_keys={
                "advantage": self.tensor_keys.advantage,
                "value_target": self.tensor_keys.value_target,
                "value": self.tensor_keys.value,
                "reward": self.tensor_keys.reward,
                "done": self.tensor_keys.done,
                "terminated": self.tensor_keys.terminated,
            },
            **hyperparams,
        )
        return self

    def _valid_mask(self, tensordict: TensorDictBase, like: torch.Tensor) -> torch.Tensor | None:
        # The masks LossModule._reduce_loss honours, combined once: the E-step's top-k
        # selection needs the mask itself, not only masked means.
        valid = None
        for key in self._loss_mask_keys():
            mask = tensordict.get(key, default=None)
            if mask is not None:
                mask = self._expand_loss_mask(mask.bool(), like)
                valid = mask if valid is None else valid & mask
        return valid

    def _masked_mean(self, value: torch.Tensor, valid: torch.Tensor | None) -> torch.Tensor:
        return self._reduce_loss(value, mask=valid, reduction="mean")

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Computes the V-MPO loss terms on one batch.

        Args:
            tensordict (TensorDictBase): the batch, with the actor's and critic's inputs,
                the action, the collecting actor's distribution parameters and, unless
                the value estimator should write them, ``advantage`` and ``value_target``
                (shaped ``[*batch, 1]`` as TorchRL's estimators write them).

        Returns:
            A tensordict with the scalar losses ``loss_policy``, ``loss_critic``,
            ``loss_eta`` and ``loss_alpha`` (to be summed and backpropagated) and the
            detached diagnostics ``eta``, ``alpha``, ``kl`` (the mean
            KL(pi_old || pi_theta)) and ``entropy`` (the current policy's mean entropy,
            a one-sample estimate when it has no closed form).
        """
        # Shallow copy: the actor and critic write their outputs (e.g. "loc", "scale")
        # into it, and the caller's batch keeps the collecting policy's parameters.
        tensordict = tensordict.copy()
        advantage = tensordict.get(self.tensor_keys.advantage, None)
        if advantage is None:
            self.value_estimator(
                tensordict,
                params=self.critic_network_params.detach(),
                target_params=self.target_critic_network_params,
            )
            advantage = tensordict.get(self.tensor_keys.advantage)
        # drop the value's trailing feature dimension: one advantage per sample
        advantage = advantage.detach().squeeze(-1)
        valid = self._valid_mask(tensordict, advantage)

        # pi_old, rebuilt before the current actor overwrites the stored parameters
        old_dist = self.actor_network.build_dist_from_params(tensordict.detach())
        with self.actor_network_params.to_module(self.actor_network, preserve_module_state=False):
            dist = self.actor_network.get_dist(tensordict)
        log_prob = sum_event_dims(
            dist.log_prob(tensordict.get(self.tensor_keys.action)), advantage.ndim
        )

        # E-step, policy loss L_pi and temperature loss L_eta on the kept samples only,
        # which also keeps non-finite values of padded samples out of the sums
        eta = self.log_eta.exp()
        weights, kept = top_half_weights(advantage, eta, self.top_fraction, valid)
        loss_policy = -(weights[kept] * log_prob[kept]).sum()
        loss_eta = temperature_loss(advantage[kept], eta, self.eps_eta)

        # M-step trust region L_alpha, over the whole batch
        kl = policy_kl(
            old_dist,
            dist,
            log_prob,
            lambda: tensordict.get(self.tensor_keys.sample_log_prob),
        )
        kl = self._masked_mean(kl, valid)
        alpha = self.log_alpha.exp()
        loss_alpha = trust_region_loss(kl, alpha, self.eps_alpha)

        with self.critic_network_params.to_module(self.critic_network, preserve_module_state=False):
            state_value = self.critic_network(tensordict).get(self.tensor_keys.value)
        value_target = tensordict.get(self.tensor_keys.value_target)
        loss_critic = self.critic_coeff * self._masked_mean(
            distance_loss(value_target, state_value, self.loss_critic_type), valid
        )

        with torch.no_grad():
            entropy = self._masked_mean(policy_entropy(dist, advantage.ndim), valid)

        return TensorDict(
            {
                "loss_policy": loss_policy,
                "loss_critic": loss_critic,
                "loss_eta": loss_eta,
                "loss_alpha": loss_alpha,
                "eta": eta.detach(),
                "alpha": alpha.detach(),
                "kl": kl.detach(),
                "entropy": entropy,
            }
        )
