"""MECL (Malik et al. 2021): maximum-entropy constraint learning with importance weights and a KL early stop."""

from typing import Any, ClassVar

import torch as th

from sb3_icrl.constraints.losses import ImportanceWeights, mecl_importance_weights, mecl_loss, mecl_should_stop
from sb3_icrl.constraints.networks import FeasibilityNet, _ConstraintNet
from sb3_icrl.icrl.base import DemonstrationsLike, LagrangianICRL
from sb3_icrl.icrl.recorder import NominalData
from sb3_icrl.icrl.trainer import ICRLTrainer, Minibatch


class MECLTrainer(ICRLTrainer):
    """
    MECL's constraint update (:func:`~sb3_icrl.constraints.mecl_loss`): the maximum-entropy likelihood of the expert
    data with the ``delta`` regulariser, nominal pairs re-weighted by per-trajectory importance weights
    ``prod phi_new / phi_old`` (recomputed before each pass), and the update stopped once either KL estimate between
    the old and the new feasibility exceeds its bound. Other arguments: see :class:`~sb3_icrl.icrl.ICRLTrainer`.

    :param regularizer_coef: ``delta``, weight of ``E[1 - phi]`` (reference: 0.5 to 0.6)
    :param use_importance_weights: Re-weight the nominal pairs (``False``: all weights 1)
    :param per_step_importance_weights: Per-step ratios instead of trajectory products
    :param target_kl_old_new: Bound on KL(old || new), ``None``: none
    :param target_kl_new_old: Bound on KL(new || old), ``None``: none
    """

    def __init__(
        self,
        *args: Any,
        regularizer_coef: float = 0.6,
        use_importance_weights: bool = True,
        per_step_importance_weights: bool = False,
        target_kl_old_new: float | None = 10.0,
        target_kl_new_old: float | None = 2.5,
        **kwargs: Any,
    ):
        super().__init__(*args, **kwargs)
        if regularizer_coef < 0:
            raise ValueError(f"`regularizer_coef` (delta) must be >= 0, got {regularizer_coef}.")
        self.regularizer_coef = float(regularizer_coef)
        self.use_importance_weights = use_importance_weights
        self.per_step_importance_weights = per_step_importance_weights
        self.target_kl_old_new = target_kl_old_new
        self.target_kl_new_old = target_kl_new_old
        self._old_feasibility: th.Tensor | None = None
        self._importance: ImportanceWeights | None = None
        self._stopped_early = False

    constraint_net_type: ClassVar[type[_ConstraintNet]] = FeasibilityNet

    def _current_feasibility(self, nominal: NominalData) -> th.Tensor:
        assert isinstance(self.constraint_net, FeasibilityNet)
        with th.no_grad():
            return self.constraint_net.feasibility(nominal.obs, nominal.acts)

    def _before_update(self, nominal: NominalData) -> None:
        self._old_feasibility = self._current_feasibility(nominal)
        self._importance = None
        self._stopped_early = False

    def _should_stop(self, nominal: NominalData) -> bool:
        assert self._old_feasibility is not None
        self._importance = mecl_importance_weights(
            self._old_feasibility,
            self._current_feasibility(nominal),
            nominal.episode_lengths,
            per_step=self.per_step_importance_weights,
        )
        self._stopped_early = mecl_should_stop(self._importance, self.target_kl_old_new, self.target_kl_new_old)
        return self._stopped_early

    def loss(self, batch: Minibatch) -> tuple[th.Tensor, dict[str, float]]:
        assert isinstance(self.constraint_net, FeasibilityNet) and self._importance is not None
        weights = self._importance.weights[th.as_tensor(batch.nominal_idx)] if self.use_importance_weights else None
        result = mecl_loss(
            self.constraint_net.feasibility(batch.expert_obs, batch.expert_acts),
            self.constraint_net.feasibility(batch.nominal_obs, batch.nominal_acts),
            nominal_weights=weights,
            regularizer_coef=self.regularizer_coef,
        )
        return result.total, {
            "loss_expert": float(result.expert.item()),
            "loss_nominal": float(result.nominal.item()),
            "regularizer": float(result.regularizer.item()),
        }

    def _after_update_stats(self, nominal: NominalData) -> dict[str, Any]:
        # The weights and KLs between the feasibility before and after this update
        self._should_stop(nominal)
        assert self._importance is not None
        weights = self._importance.weights
        return {
            "is_weight_min": float(weights.min()),
            "is_weight_max": float(weights.max()),
            "is_weight_std": float(weights.std()) if len(weights) > 1 else 0.0,
            "kl_old_new": float(self._importance.kl_old_new),
            "kl_new_old": float(self._importance.kl_new_old),
        }

    def update(self, nominal: NominalData) -> dict[str, float]:
        stats = super().update(nominal)
        stats["stopped_early"] = float(stats["n_passes"] < self.constraint_steps)
        return stats


class MECL(LagrangianICRL):
    """
    Maximum Entropy Constraint Learning (Malik et al. 2021; the paper's section 3.2): a feasibility net trained with
    :class:`MECLTrainer`, and a PPO-Lagrangian policy on the cost ``1 - phi``. Other arguments: see
    :class:`~sb3_icrl.icrl.LagrangianICRL` (``trainer_kwargs`` overrides the ones below).

    :param regularizer_coef: ``delta``
    :param target_kl_old_new: Bound on KL(old || new) of the early stop (``None``: none)
    :param target_kl_new_old: Bound on KL(new || old) of the early stop (``None``: none)
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = FeasibilityNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = MECLTrainer

    def __init__(
        self,
        policy: Any,
        env: Any,
        demonstrations: DemonstrationsLike | None = None,
        regularizer_coef: float = 0.6,
        target_kl_old_new: float | None = 10.0,
        target_kl_new_old: float | None = 2.5,
        trainer_kwargs: dict[str, Any] | None = None,
        **kwargs: Any,
    ):
        defaults = dict(
            regularizer_coef=regularizer_coef, target_kl_old_new=target_kl_old_new, target_kl_new_old=target_kl_new_old
        )
        super().__init__(policy, env, demonstrations, trainer_kwargs={**defaults, **(trainer_kwargs or {})}, **kwargs)
