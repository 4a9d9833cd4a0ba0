"""VICRL (the paper's method): a Beta distribution of the feasibility, learned by maximising an ELBO."""

from typing import Any, ClassVar

import numpy as np
import torch as th

from sb3_icrl.constraints.losses import beta_kl_divergence, vicrl_loss
from sb3_icrl.constraints.networks import BetaFeasibilityNet, _ConstraintNet
from sb3_icrl.icrl.base import DemonstrationsLike, LagrangianICRL
from sb3_icrl.icrl.trainer import ICRLTrainer, Minibatch


class VICRLTrainer(ICRLTrainer):
    """
    VICRL's constraint update (:func:`~sb3_icrl.constraints.vicrl_loss`): the negative ELBO, MECL's likelihood on
    one reparameterised Beta sample per pair plus ``kl_coef`` times the closed-form KL to the prior
    ``Beta(alpha0, beta0)``. No importance weights (as the reference). Other arguments: see
    :class:`~sb3_icrl.icrl.ICRLTrainer`; the constraint model must be a
    :class:`~sb3_icrl.constraints.BetaFeasibilityNet`. ``constraint/kl`` logs the unweighted KL.

    :param prior: ``(alpha0, beta0)``; the default has mean 0.9 (most pairs feasible)
    :param kl_coef: Weight of the KL term
    """

    constraint_net_type: ClassVar[type[_ConstraintNet]] = BetaFeasibilityNet

    def __init__(self, *args: Any, prior: tuple[float, float] = (0.9, 0.1), kl_coef: float = 1.0, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if len(prior) != 2 or not (prior[0] > 0 and prior[1] > 0):
            raise ValueError(f"`prior` is (alpha0, beta0) with both > 0, got {prior!r}.")
        if kl_coef < 0:
            raise ValueError(f"`kl_coef` must be >= 0, got {kl_coef}.")
        self.prior = (float(prior[0]), float(prior[1]))
        self.kl_coef = float(kl_coef)

    def loss(self, batch: Minibatch) -> tuple[th.Tensor, dict[str, float]]:
        assert isinstance(self.constraint_net, BetaFeasibilityNet)
        expert_alpha, expert_beta = self.constraint_net.alpha_beta(batch.expert_obs, batch.expert_acts)
        nominal_alpha, nominal_beta = self.constraint_net.alpha_beta(batch.nominal_obs, batch.nominal_acts)
        result = vicrl_loss(
            expert_alpha,
            expert_beta,
            th.distributions.Beta(expert_alpha, expert_beta).rsample(),
            nominal_alpha,
            nominal_beta,
            th.distributions.Beta(nominal_alpha, nominal_beta).rsample(),
            kl_coef=self.kl_coef,
            prior=self.prior,
        )
        if self.kl_coef > 0:
            kl = float(result.regularizer.item()) / self.kl_coef
        else:  # logged even when it does not enter the loss
            with th.no_grad():
                kl = float(
                    beta_kl_divergence(expert_alpha, expert_beta, *self.prior).mean()
                    + beta_kl_divergence(nominal_alpha, nominal_beta, *self.prior).mean()
                )
        return result.total, {
            "loss_expert": float(result.expert.item()),
            "loss_nominal": float(result.nominal.item()),
            "kl": kl,
        }

    def _feasibility(self, obs: np.ndarray, acts: np.ndarray) -> np.ndarray:
        assert isinstance(self.constraint_net, BetaFeasibilityNet)
        # The posterior mean: a sampled cost would make the logged feasibility noisy
        return self.constraint_net.predict_feasibility(obs, acts, cost_mode="mean")


class VICRL(LagrangianICRL):
    """
    Variational ICRL (the paper's section 3.3): ``phi(s, a) ~ Beta(alpha, beta)`` learned with :class:`VICRLTrainer`,
    and a PPO-Lagrangian policy on the cost ``1 - phi`` with ``phi`` a sample, the mean, or a risk measure of the
    Beta (``cost_mode``). Other arguments: see :class:`~sb3_icrl.icrl.LagrangianICRL` (``trainer_kwargs`` overrides
    ``prior`` and ``kl_coef``; ``constraint_net_kwargs`` overrides ``cost_mode`` and ``confidence``).

    :param prior: ``(alpha0, beta0)`` of the Beta prior
    :param kl_coef: Weight of the KL term of the ELBO
    :param cost_mode: ``"sample"``, ``"mean"``, ``"var"`` or ``"cvar"`` (of the default constraint net)
    :param confidence: Level of ``"var"`` and ``"cvar"``
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = BetaFeasibilityNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = VICRLTrainer

    def __init__(
        self,
        policy: Any,
        env: Any,
        demonstrations: DemonstrationsLike | None = None,
        prior: tuple[float, float] = (0.9, 0.1),
        kl_coef: float = 1.0,
        cost_mode: str = "sample",
        confidence: float = 0.5,
        constraint_net: _ConstraintNet | None = None,
        constraint_net_kwargs: dict[str, Any] | None = None,
        trainer_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ):
        if constraint_net is None:
            constraint_net_kwargs = {"cost_mode": cost_mode, "confidence": confidence, **(constraint_net_kwargs or {})}
        super().__init__(
            policy,
            env,
            demonstrations,
            constraint_net=constraint_net,
            constraint_net_kwargs=constraint_net_kwargs,
            trainer_kwargs={"prior": prior, "kl_coef": kl_coef, **(trainer_kwargs or {})},
            **kwargs,
        )
