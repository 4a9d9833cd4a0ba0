"""
The base of the ICRL algorithms whose forward solver is off-policy: :class:`~sb3_icrl.SACLagrangian` on a learned
cost, computed on each batch sampled from the replay buffer by the current constraint model.
"""

from typing import Any

from sb3_icrl.constraints.networks import _ConstraintNet
from sb3_icrl.icrl.base import DemonstrationsLike, ICRLAlgorithmMixin
from sb3_icrl.icrl.trainer import ICRLTrainer
from sb3_icrl.sac_lagrangian import CostSACPolicy, SACLagrangian

#: The default update interval of the off-policy ICRL algorithms (an epoch of the IRL-Plus reference runs)
DEFAULT_OFF_POLICY_UPDATE_EVERY = 5000


class OffPolicyICRL(ICRLAlgorithmMixin, SACLagrangian):
    """
    An ICRL algorithm whose forward solver is :class:`~sb3_icrl.SACLagrangian` on the learned cost (IRL-Plus). The
    constraint model is trained by the same :class:`~sb3_icrl.icrl.ICRLTrainer` callback as the on-policy methods,
    on the learner's most recent finished episodes (recorded by the env wrapper, raw observations and actions),
    every ``update_every`` timesteps. The learner never stores a learned cost: it computes the current model's cost
    on each batch sampled from its replay buffer, so old transitions are judged by the latest model. The env's true
    cost is moved to ``info["true_cost"]``, for logging only.

    :param policy: The policy model (``"MlpPolicy"`` or a ``CostSACPolicy`` subclass)
    :param env: The environment; flat Box or Discrete observations, Box actions
    :param demonstrations: Expert demonstrations (see :class:`~sb3_icrl.icrl.LagrangianICRL`)
    :param constraint_net: A built constraint model (default: one of ``constraint_net_class`` for the env's spaces)
    :param constraint_net_kwargs: Arguments of the default constraint model
    :param constraint_learning_rate: Adam learning rate of the constraint model
    :param constraint_steps: Passes over the nominal data per constraint update
    :param constraint_batch_size: Nominal pairs per constraint minibatch (``None``: all of them)
    :param update_every: Policy timesteps between constraint updates
    :param n_nominal_trajectories: Most recent learner trajectories per update (default: the number of expert ones)
    :param trainer_class: The :class:`~sb3_icrl.icrl.ICRLTrainer` subclass (default: the algorithm's)
    :param trainer_kwargs: Further arguments of the trainer
    :param allow_env_mismatch: Accept demonstrations recorded on another env id whose spaces fit this env's
    :param cost_budget: Budget on the learned cost (see :class:`~sb3_icrl.SACLagrangian`)
    :param budget_statistic: ``"critic"`` (the learned cost is only known on sampled batches)
    :param lagrange_kwargs: Multiplier arguments
    :param kwargs: The other arguments of :class:`~sb3_icrl.SACLagrangian` (``learning_rate``, ``batch_size``,
        ``lagrange_update``, ``separate_cost_critic``, ``seed``...), except ``cost_fn``: the constraint model is the cost
    """

    def __init__(
        self,
        policy: str | type[CostSACPolicy],
        env: Any,
        demonstrations: DemonstrationsLike | None = None,
        constraint_net: _ConstraintNet | None = None,
        constraint_net_kwargs: dict[str, Any] | None = None,
        constraint_learning_rate: float = 1e-3,
        constraint_steps: int = 1,
        constraint_batch_size: int | None = None,
        update_every: int | None = DEFAULT_OFF_POLICY_UPDATE_EVERY,
        n_nominal_trajectories: int | None = None,
        trainer_class: type[ICRLTrainer] | None = None,
        trainer_kwargs: dict[str, Any] | None = None,
        allow_env_mismatch: bool = False,
        cost_budget: float = 0.0,
        budget_statistic: str = "critic",
        lagrange_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        if budget_statistic != "critic":
            raise ValueError(
                f"{type(self).__name__} knows its learned cost on sampled batches only: budget_statistic must be "
                f"'critic', got {budget_statistic!r}."
            )
        self._init_icrl_learner(
            policy,
            env,
            demonstrations,
            constraint_net,
            constraint_net_kwargs,
            constraint_learning_rate,
            constraint_steps,
            constraint_batch_size,
            update_every,
            n_nominal_trajectories,
            trainer_class,
            trainer_kwargs,
            allow_env_mismatch,
            {"cost_budget": cost_budget, "budget_statistic": budget_statistic, "lagrange_kwargs": lagrange_kwargs, **kwargs},
            _init_setup_model,
        )

    def _setup_model(self) -> None:
        super()._setup_model()
        # Read at call time: always the current constraint model, after updates and loads alike
        self.set_cost_fn(self.constraint_cost)

    def _default_update_every(self) -> int:
        return DEFAULT_OFF_POLICY_UPDATE_EVERY

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "cost_fn"]
