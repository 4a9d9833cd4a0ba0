"""GACL: a GAIL-style discriminator ``D(s, a)``, and plain PPO on the reward ``r + log D`` (no Lagrangian)."""

from typing import Any, ClassVar

import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_icrl.bc2l.bc2l import BC2LTrainer
from sb3_icrl.constraints.losses import ConstraintLoss, gacl_discriminator_loss
from sb3_icrl.constraints.networks import FeasibilityNet, _ConstraintNet
from sb3_icrl.constraints.wrappers import GACLRewardWrapper
from sb3_icrl.icrl.base import DemonstrationsLike, ICRLAlgorithmMixin
from sb3_icrl.icrl.trainer import ICRLTrainer

#: What the last step of a terminated episode adds to GACL's reward (see :class:`GACL`)
TERMINATION_REWARDS = ("zero", "repeat")


class GACLTrainer(BC2LTrainer):
    """
    GACL's discriminator update (:func:`~sb3_icrl.constraints.gacl_discriminator_loss`): binary cross-entropy with
    ``D = 1`` on expert pairs and 0 on nominal ones, the same form as BC2L's. Arguments: see
    :class:`~sb3_icrl.icrl.ICRLTrainer`; the discriminator is a :class:`~sb3_icrl.constraints.FeasibilityNet` (its
    ``feasibility`` is ``D``).
    """

    def binary_loss(self, expert_feasibility: th.Tensor, nominal_feasibility: th.Tensor) -> ConstraintLoss:
        return gacl_discriminator_loss(expert_feasibility, nominal_feasibility)


class GACL(ICRLAlgorithmMixin, PPO):
    """
    Generative Adversarial Constraint Learning (the paper's section 3.2): a discriminator ``D(s, a)`` trained with
    :class:`GACLTrainer` on expert vs the learner's pairs, and plain PPO on ``r'(s, a) = r + log D(s, a)``
    (``GACLRewardWrapper``; the env's reward is kept in ``info["env_reward"]``, its true cost moved to
    ``info["true_cost"]``, both for logging only).

    :param policy: The policy model (``"MlpPolicy"``...)
    :param env: The environment; flat Box or Discrete spaces
    :param demonstrations: Expert demonstrations (see :class:`~sb3_icrl.icrl.LagrangianICRL`)
    :param constraint_net: A built discriminator (default: a ``FeasibilityNet`` for the env's spaces)
    :param constraint_net_kwargs: Arguments of the default discriminator
    :param constraint_learning_rate: Adam learning rate of the discriminator
    :param constraint_steps: Passes over the nominal data per update
    :param constraint_batch_size: Nominal pairs per minibatch (``None``: all)
    :param update_every: Policy timesteps between updates (default: one rollout)
    :param n_nominal_trajectories: Most recent learner trajectories per update (default: the number of expert ones)
    :param trainer_class: The trainer class (default :class:`GACLTrainer`)
    :param trainer_kwargs: Further arguments of the trainer
    :param allow_env_mismatch: Accept demonstrations recorded on another env id whose spaces fit this env's
    :param log_d_eps: Smallest ``D`` inside the log of the reward
    :param termination_reward: What the last step of a terminated (not truncated) episode adds. ``"zero"``: nothing
        more, the paper's GACL; since every ``log D`` is <= 0, ending an episode early then saves the learner its
        future penalties. ``"repeat"``: ``gamma / (1 - gamma)`` times the final pair's ``log D``, as if the episode
        stayed in its final situation for ever (see :class:`~sb3_icrl.constraints.GACLRewardWrapper`)
    :param kwargs: The other arguments of SB3's ``PPO``
    """

    constraint_net_class: ClassVar[type[_ConstraintNet]] = FeasibilityNet
    default_trainer_class: ClassVar[type[ICRLTrainer]] = GACLTrainer
    constraint_wrapper_class: ClassVar[type[VecEnvWrapper]] = GACLRewardWrapper

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        demonstrations: DemonstrationsLike | None = None,
        constraint_net: _ConstraintNet | None = None,
        constraint_net_kwargs: dict[str, Any] | None = None,
        constraint_learning_rate: float = 1e-3,
        constraint_steps: int = 5,
        constraint_batch_size: int | None = None,
        update_every: int | None = None,
        n_nominal_trajectories: int | None = None,
        trainer_class: type[ICRLTrainer] | None = None,
        trainer_kwargs: dict[str, Any] | None = None,
        allow_env_mismatch: bool = False,
        log_d_eps: float = 1e-5,
        termination_reward: str = "zero",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        self._init_icrl(
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
        )
        self.log_d_eps = log_d_eps
        if termination_reward not in TERMINATION_REWARDS:
            raise ValueError(
                f"`termination_reward` must be one of {', '.join(map(repr, TERMINATION_REWARDS))}, got {termination_reward!r}."
            )
        self.termination_reward = termination_reward
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        if _init_setup_model:
            self._setup_model()

    def _make_constraint_wrapper(self, venv: VecEnv) -> GACLRewardWrapper:
        assert self.constraint_net is not None
        return GACLRewardWrapper(venv, self.constraint_net.predict_feasibility)

    def _setup_model(self) -> None:
        # Checked before the env is wrapped (and after ``load``, which sets it after the constructor); the wrapper's
        # own check then covers a value assigned later
        _check_log_d_eps(self.log_d_eps)
        super()._setup_model()

    def _configure_constraint_wrapper(self, wrapper: VecEnvWrapper) -> None:
        assert isinstance(wrapper, GACLRewardWrapper)
        wrapper.eps = self.log_d_eps
        wrapper.termination_gamma = self.gamma if self.termination_reward == "repeat" else None


def _check_log_d_eps(log_d_eps: float) -> None:
    """Fail clearly unless ``log_d_eps`` is a number in (0, 1)."""
    if isinstance(log_d_eps, bool) or not isinstance(log_d_eps, (int, float)) or not 0.0 < log_d_eps < 1.0:
        raise ValueError(f"`log_d_eps` must be in (0, 1), got {log_d_eps!r}: it is the smallest D inside log D.")
