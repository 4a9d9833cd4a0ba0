"""
IRL-Plus (Hugessen, Wiltzer and Berseth, "Simplifying constraint inference with inverse reinforcement learning",
NeurIPS 2024): single-level inverse RL on a cost treated as a negative reward, with an L2 penalty on the expert's
costs, a cost critic of its own, and periodic resets of the policy's output layers.
"""

from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import GymEnv
from torch import nn

from sb3_icrl.common.policies import CostActorCriticPolicy
from sb3_icrl.constraints.losses import irl_plus_loss
from sb3_icrl.constraints.networks import CostNet, _ConstraintNet
from sb3_icrl.icrl.base import DemonstrationsLike, LagrangianICRL
from sb3_icrl.icrl.off_policy import OffPolicyICRL
from sb3_icrl.icrl.trainer import ICRLTrainer, Minibatch
from sb3_icrl.sac_lagrangian import CostSACPolicy

#: The reference's weight of the cost in the policy objective: a multiplier held at 1 (``lr`` 0)
IRLPLUS_LAGRANGE_KWARGS: dict[str, Any] = {"init": 1.0, "lr": 0.0, "optimizer": "sgd"}


class IRLPlusTrainer(ICRLTrainer):
    """
    IRL-Plus's cost update (:func:`~sb3_icrl.constraints.irl_plus_loss`): lower the cost of expert pairs, raise that
    of the learner's, and penalise the expert's squared costs. The model is a :class:`~sb3_icrl.constraints.CostNet`;
    the logged feasibilities are ``exp(-c)``. Other arguments: see :class:`~sb3_icrl.icrl.ICRLTrainer`.

    :param l2_coef: Weight of the L2 penalty on the expert's costs (reference: 0.1; 0: the ablation without it)
    :param warmup_timesteps: Timesteps before the first update, while the learner follows the reward alone (the
        model starts at cost 0 everywhere). The reference waits 50 epochs of 5000 steps
    """

    constraint_net_type: ClassVar[type[_ConstraintNet]] = CostNet

    def __init__(self, *args: Any, l2_coef: float = 0.1, warmup_timesteps: int = 0, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if not l2_coef >= 0:
            raise ValueError(f"`l2_coef` must be >= 0 (0: no penalty), got {l2_coef}.")
        if warmup_timesteps < 0:
            raise ValueError(f"`warmup_timesteps` must be >= 0 (0: update from the start), got {warmup_timesteps}.")
        self.l2_coef = float(l2_coef)
        self.warmup_timesteps = int(warmup_timesteps)

    def _on_rollout_end(self) -> None:
        # During the warm-up the recorder keeps the finished episodes: the first update takes the latest ones
        if self.num_timesteps < self.warmup_timesteps:
            return
        super()._on_rollout_end()

    def loss(self, batch: Minibatch) -> tuple[th.Tensor, dict[str, float]]:
        assert isinstance(self.constraint_net, CostNet)
        expert_cost = self.constraint_net.cost_tensor(batch.expert_obs, batch.expert_acts)
        nominal_cost = self.constraint_net.cost_tensor(batch.nominal_obs, batch.nominal_acts)
        parts = irl_plus_loss(expert_cost, nominal_cost, self.l2_coef)
        return parts.total, {
            "expert_cost": float(expert_cost.mean().item()),
            "nominal_cost": float(nominal_cost.mean().item()),
            "l2_penalty": float(parts.regularizer.item()),
        }

    def _feasibility(self, obs: np.ndarray, acts: np.ndarray) -> np.ndarray:
        return self.constraint_net.predict_feasibility(obs, acts)


def _reset_linear(module: nn.Module) -> None:
    """Draw new weights for a linear layer, as torch initialises it."""
    assert isinstance(module, nn.Linear), f"expected a linear output layer, got {type(module).__name__}"
    module.reset_parameters()


class _IRLPlusOptions:
    """The settings of IRL-Plus that its SAC and PPO learners share: the trainer's, the multiplier's, the resets."""

    num_timesteps: int
    update_every: int | None

    def _init_irlplus(
        self,
        policy: Any,
        env: Any,
        demonstrations: DemonstrationsLike | None,
        l2_coef: float,
        policy_resets: bool,
        reset_every: int | None,
        warmup_timesteps: int,
        trainer_kwargs: dict[str, Any] | None,
        lagrange_kwargs: dict[str, Any] | None,
        _init_setup_model: bool,
        **kwargs: Any,
    ) -> None:
        """
        Check and keep the settings, then build the ICRL algorithm these options are listed before in the bases with
        IRL-Plus's trainer and multiplier arguments.

        :param policy: The policy model
        :param env: The environment
        :param demonstrations: Expert demonstrations
        :param l2_coef: Weight of the L2 penalty on the expert's costs
        :param policy_resets: Reset the output layers every ``reset_every`` timesteps
        :param reset_every: Timesteps between resets (``None``: the constraint update interval)
        :param warmup_timesteps: Timesteps before the first cost update
        :param trainer_kwargs: Further arguments of the trainer
        :param lagrange_kwargs: Multiplier arguments (``None``: :data:`IRLPLUS_LAGRANGE_KWARGS`)
        :param _init_setup_model: Set the model up now
        :param kwargs: The ICRL algorithm's other arguments
        """
        if reset_every is not None and (isinstance(reset_every, bool) or not isinstance(reset_every, int) or reset_every < 1):
            raise ValueError(
                f"`reset_every` must be a number of timesteps >= 1 or None (once per constraint update), got {reset_every!r}."
            )
        self.l2_coef = float(l2_coef)
        self.policy_resets = bool(policy_resets)
        self.reset_every = reset_every
        self.warmup_timesteps = int(warmup_timesteps)
        self._last_reset = 0
        super().__init__(  # type: ignore[call-arg]
            policy,
            env,
            demonstrations=demonstrations,
            trainer_kwargs={"l2_coef": l2_coef, "warmup_timesteps": warmup_timesteps, **(trainer_kwargs or {})},
            lagrange_kwargs=dict(IRLPLUS_LAGRANGE_KWARGS) if lagrange_kwargs is None else lagrange_kwargs,
            _init_setup_model=_init_setup_model,
            **kwargs,
        )

    def reset_policy_layers(self) -> None:
        raise NotImplementedError

    def _reset_if_due(self) -> None:
        """
        Reset once ``reset_every`` timesteps (default: the constraint update interval) have passed since the last, but
        for the last interval of a ``learn()`` call.
        """
        if not self.policy_resets:
            return
        if self.num_timesteps < self._last_reset:  # a new learn() that counts from 0 again
            self._last_reset = 0
        interval = self.reset_every
        if interval is None:
            interval = self.update_every if self.update_every is not None else self._default_update_every()  # type: ignore[attr-defined]
        # Not within the last interval of the run: the policy a run ends with has trained since its last reset
        remaining = getattr(self, "_total_timesteps", 0) - self.num_timesteps
        if self.num_timesteps - self._last_reset >= interval and remaining >= interval:
            self.reset_policy_layers()
            self._last_reset = self.num_timesteps


class IRLPlus(_IRLPlusOptions, OffPolicyICRL):
    """
    IRL-Plus on SAC (Hugessen et al., NeurIPS 2024): a cost ``c(s, a)`` (:class:`~sb3_icrl.constraints.CostNet`)
    learned single-level by :class:`IRLPlusTrainer`, and SAC maximising ``Q_r - Q_c`` with a cost critic
    ``Q_c`` of its own (:class:`~sb3_icrl.SACLagrangian`, the multiplier held at 1 as in the reference; pass
    ``lagrange_kwargs`` to let it adapt). The cost is charged as learned, as the reference charges it: where the net's
    output LeakyReLU dips below 0 (slope 0.01) it is a small bonus, and the ranking of pairs the update learnt there
    still reaches the learner. :class:`IRLPlusPPO` charges it the same way; only the grid's planner floors it at 0
    (:meth:`~sb3_icrl.constraints.CostNet.paid_cost`).

    Every ``reset_every`` timesteps the actor's output layers and the cost critics' last layers are drawn anew; the
    reward critics, the targets and the replay buffer are kept, so the policy relearns quickly from the stored
    experience without the bias of costs that have since changed. No reset falls in the last ``reset_every``
    timesteps of a ``learn()`` call, so the final policy has trained since its last.

    The three additions of IRL-Plus over plain inverse RL can be switched off, for the paper's ablations:
    ``l2_coef=0.0`` (no L2 penalty), ``separate_critics=False`` (one critic on ``r - c``; the resets then draw the
    reward critics' last layers anew instead), ``policy_resets=False``.

    :param policy: The policy model (``"MlpPolicy"`` or a ``CostSACPolicy`` subclass)
    :param env: The environment; flat Box or Discrete observations, Box actions
    :param demonstrations: Expert demonstrations (see :class:`~sb3_icrl.icrl.LagrangianICRL`)
    :param l2_coef: Weight of the L2 penalty on the expert's costs (reference: 0.1)
    :param separate_critics: A cost critic beside the reward critic (``False``: one critic on ``r - c``)
    :param policy_resets: Reset the output layers every ``reset_every`` timesteps
    :param reset_every: Timesteps between resets (default: ``update_every``, as the reference resets once per epoch)
    :param warmup_timesteps: Timesteps before the first cost update (see :class:`IRLPlusTrainer`)
    :param constraint_net_kwargs: Arguments of the :class:`~sb3_icrl.constraints.CostNet`
    :param constraint_learning_rate: Adam learning rate of the cost model
    :param lagrange_kwargs: Multiplier arguments (default :data:`IRLPLUS_LAGRANGE_KWARGS`: held at 1)
    :param trainer_kwargs: Further arguments of the trainer
    :param kwargs: The other arguments of :class:`~sb3_icrl.icrl.off_policy.OffPolicyICRL` (``update_every``,
        ``constraint_batch_size``...) and of SB3's ``SAC`` (``learning_rate``, ``batch_size``, ``seed``...)
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = CostNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = IRLPlusTrainer

    def __init__(
        self,
        policy: str | type[CostSACPolicy],
        env: GymEnv | str,
        demonstrations: DemonstrationsLike | None = None,
        l2_coef: float = 0.1,
        separate_critics: bool = True,
        policy_resets: bool = True,
        reset_every: int | None = None,
        warmup_timesteps: int = 0,
        constraint_learning_rate: float = 1e-3,
        lagrange_kwargs: dict[str, Any] | None = None,
        trainer_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        self._init_irlplus(
            policy,
            env,
            demonstrations,
            l2_coef,
            policy_resets,
            reset_every,
            warmup_timesteps,
            trainer_kwargs,
            lagrange_kwargs,
            _init_setup_model,
            constraint_learning_rate=constraint_learning_rate,
            separate_cost_critic=separate_critics,
            **kwargs,
        )

    @property
    def separate_critics(self) -> bool:
        """Whether the cost has a critic of its own (the ``separate_critics`` argument)."""
        return self.separate_cost_critic

    def reset_policy_layers(self) -> None:
        """Draw new weights for the actor's output layers and the last layers of the cost critics (of the reward
        critics without separate critics)."""
        _reset_linear(self.actor.mu)
        if isinstance(self.actor.log_std, nn.Module):  # (a parameter with gSDE: kept)
            _reset_linear(self.actor.log_std)
        critic = self.cost_critic if self.separate_cost_critic else self.critic
        for q_net in critic.q_networks:
            assert isinstance(q_net, nn.Sequential)
            _reset_linear(q_net[-1])

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self._reset_if_due()
        super().train(gradient_steps, batch_size)


class IRLPlusPPO(_IRLPlusOptions, LagrangianICRL):
    """
    IRL-Plus on PPO-Lagrangian: the cost model and update of :class:`IRLPlus`, and :class:`~sb3_icrl.PPOLagrangian`
    (which always has a cost critic of its own) maximising ``A_r - A_c`` (the multiplier held at 1 by default).
    The cost is charged as learned, as :class:`IRLPlus` charges it, its dip below 0 included (``signed_costs``): it is
    a penalty on the reward, not a count of violations. Every ``reset_every`` timesteps, before a policy update, the
    actor's output layer and the cost critic's last layer are drawn anew.

    :param policy: The policy model (``"MlpPolicy"`` or a ``CostActorCriticPolicy`` subclass)
    :param env: The environment; flat Box or Discrete spaces
    :param demonstrations: Expert demonstrations (see :class:`~sb3_icrl.icrl.LagrangianICRL`)
    :param l2_coef: Weight of the L2 penalty on the expert's costs (reference: 0.1)
    :param policy_resets: Reset the output layers every ``reset_every`` timesteps
    :param reset_every: Timesteps between resets (default: ``update_every``, or one rollout)
    :param warmup_timesteps: Timesteps before the first cost update (see :class:`IRLPlusTrainer`)
    :param constraint_steps: Passes over the nominal data per update (reference: 1)
    :param lagrange_kwargs: Multiplier arguments (default :data:`IRLPLUS_LAGRANGE_KWARGS`: held at 1)
    :param trainer_kwargs: Further arguments of the trainer
    :param kwargs: The other arguments of :class:`~sb3_icrl.icrl.LagrangianICRL` and :class:`~sb3_icrl.PPOLagrangian`
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = CostNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = IRLPlusTrainer
    # A learned cost floored at 0 hides every difference the update makes below 0 (where the LeakyReLU's slope is
    # 0.01): once the learner's costs sank there, it was charged nothing and the update never brought them back
    signed_costs: ClassVar[bool] = True

    def __init__(
        self,
        policy: str | type[CostActorCriticPolicy],
        env: GymEnv | str,
        demonstrations: DemonstrationsLike | None = None,
        l2_coef: float = 0.1,
        policy_resets: bool = True,
        reset_every: int | None = None,
        warmup_timesteps: int = 0,
        constraint_steps: int = 1,
        lagrange_kwargs: dict[str, Any] | None = None,
        trainer_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        if isinstance(kwargs.get("cost_budget"), str):
            raise ValueError(
                f"IRLPlusPPO charges its cost as a penalty on the reward, signed (the multiplier held at 1): a budget "
                f"read from the expert's learned cost (cost_budget={kwargs['cost_budget']!r}) dips below 0 with it and "
                "means nothing here. Pass a number (default 0), with lagrange_kwargs if the multiplier should adapt."
            )
        self._init_irlplus(
            policy,
            env,
            demonstrations,
            l2_coef,
            policy_resets,
            reset_every,
            warmup_timesteps,
            trainer_kwargs,
            lagrange_kwargs,
            _init_setup_model,
            constraint_steps=constraint_steps,
            **kwargs,
        )

    def reset_policy_layers(self) -> None:
        """Draw new weights for the actor's output layer and the cost critic's last layer, as SB3 initialises them."""
        policy: ActorCriticPolicy = self.policy
        for module, gain in ((policy.action_net, 0.01), (self.policy.cost_value_net, 1.0)):
            _reset_linear(module)
            if policy.ortho_init:
                policy.init_weights(module, gain=gain)

    def train(self) -> None:
        self._reset_if_due()
        super().train()
