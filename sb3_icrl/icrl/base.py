"""
The shared base of the ICRL algorithms: an SB3 on-policy learner (PPO-Lagrangian or PPO) plus a constraint model,
the wrappers that feed it to the learner and record nominal data, and the :class:`ICRLTrainer` callback.
"""

import os
import warnings
from collections.abc import Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_icrl.common.policies import CostActorCriticPolicy
from sb3_icrl.common.saved import CheckedLoadMixin, library_algorithm
from sb3_icrl.constraints.networks import FeasibilityNet, _ConstraintNet, _space_features
from sb3_icrl.constraints.wrappers import GACLRewardWrapper, LearnedCostVecEnvWrapper
from sb3_icrl.data.registry import load_demonstrations
from sb3_icrl.data.serialize import DemonstrationError, check_spaces
from sb3_icrl.data.types import Demonstrations, Trajectory
from sb3_icrl.icrl.callbacks import TrueConstraintLogger
from sb3_icrl.icrl.recorder import TrajectoryRecorderVecEnvWrapper
from sb3_icrl.icrl.trainer import ICRLTrainer, install_constraint
from sb3_icrl.ppo_lagrangian import PPOLagrangian
from sb3_icrl.ppo_lagrangian.ppo_lagrangian import check_total_timesteps

SelfICRL = TypeVar("SelfICRL", bound="ICRLAlgorithmMixin")

#: What can be passed as demonstrations: a dataset, trajectories, a shipped dataset's name or a file path
DemonstrationsLike = Demonstrations | Sequence[Trajectory] | str | os.PathLike


class ICRLAlgorithmMixin(CheckedLoadMixin):
    """
    Turns an SB3 algorithm, on-policy or off-policy, into an ICRL algorithm; listed first in the bases
    (``class BC2L(ICRLAlgorithmMixin, PPOLagrangian)``, ``class IRLPlus(ICRLAlgorithmMixin, SACLagrangian)``).

    The env is wrapped at its bottom, below any ``VecNormalize``, as
    ``constraint_wrapper(TrajectoryRecorderVecEnvWrapper(raw_venv))``: the recorder keeps the learner's raw
    observations and actions by trajectory (nominal data), the constraint wrapper moves the env's true cost to
    ``info["true_cost"]``, which only :class:`TrueConstraintLogger` reads, for logging (GACL's also writes
    ``r + log D`` into the reward). A Lagrangian learner prices its pairs with the model itself, through its
    ``cost_fn`` (:meth:`constraint_cost`): once per rollout on PPO, on each sampled batch on SAC.

    Saving: the constraint net's ``state_dict`` and its optimizer's go into the SB3 zip beside the policy's, its
    class and constructor arguments into the zip's data; ``load`` rebuilds it. The demonstrations are not saved: a
    dataset given by name or path is reloaded by ``load``; otherwise pass ``demonstrations=`` to ``load`` to train on.
    """

    #: Default constraint model class
    constraint_net_class: ClassVar[type[_ConstraintNet]] = FeasibilityNet
    #: Default trainer class
    default_trainer_class: ClassVar[type[ICRLTrainer]]
    #: The wrapper that feeds the constraint model to the learner (see :meth:`_make_constraint_wrapper`)
    constraint_wrapper_class: ClassVar[type[VecEnvWrapper]] = LearnedCostVecEnvWrapper

    # Attributes of the SB3 algorithm this mixin is combined with
    env: VecEnv | None
    observation_space: spaces.Space
    action_space: spaces.Space
    seed: int | None
    device: th.device
    n_steps: int
    n_envs: int

    def _init_icrl(
        self,
        demonstrations: DemonstrationsLike | None,
        constraint_net: _ConstraintNet | None,
        constraint_net_kwargs: dict[str, Any] | None,
        constraint_learning_rate: float,
        constraint_steps: int,
        constraint_batch_size: int | None,
        update_every: int | None,
        n_nominal_trajectories: int | None,
        trainer_class: type[ICRLTrainer] | None,
        trainer_kwargs: dict[str, Any] | None,
        allow_env_mismatch: bool = False,
    ) -> None:
        if constraint_net is not None and not isinstance(constraint_net, _ConstraintNet):
            raise TypeError(
                "`constraint_net` must be a FeasibilityNet, BetaFeasibilityNet or CostNet, got "
                f"{type(constraint_net).__name__}."
            )
        if constraint_net is not None and constraint_net_kwargs:
            raise ValueError("Give either `constraint_net` (a built model) or `constraint_net_kwargs`, not both.")
        if constraint_learning_rate <= 0:
            raise ValueError(f"`constraint_learning_rate` must be > 0, got {constraint_learning_rate}.")
        if trainer_class is not None and not (isinstance(trainer_class, type) and issubclass(trainer_class, ICRLTrainer)):
            raise TypeError(f"`trainer_class` must be a subclass of ICRLTrainer, got {trainer_class!r}.")
        self.demonstrations_source = os.fspath(demonstrations) if isinstance(demonstrations, (str, os.PathLike)) else None
        self.demonstrations: Demonstrations | None = None
        self.expert_obs: np.ndarray | None = None
        self.expert_acts: np.ndarray | None = None
        self._pending_demonstrations = demonstrations
        self.constraint_net: _ConstraintNet | None = constraint_net
        self.constraint_net_class_ = type(constraint_net) if constraint_net is not None else self.constraint_net_class
        self.constraint_net_kwargs = dict(constraint_net_kwargs or {})
        self.constraint_learning_rate = float(constraint_learning_rate)
        self.constraint_steps = int(constraint_steps)
        self.constraint_batch_size = constraint_batch_size
        self.update_every = update_every
        self.n_nominal_trajectories = n_nominal_trajectories
        self.trainer_class = trainer_class or self.default_trainer_class
        self.trainer_kwargs = dict(trainer_kwargs or {})
        #: Accept demonstrations whose metadata names another env id than the env's (their spaces must still fit)
        self.allow_env_mismatch = bool(allow_env_mismatch)
        #: Constraint updates made so far (kept by the trainer, saved with the model)
        self.n_constraint_updates = 0
        # Saved in the zip: ``load`` of another algorithm's model fails clearly
        self.sb3_icrl_algorithm = library_algorithm(type(self))
        self.constraint_optimizer: th.optim.Optimizer | None = None
        self.recorder: TrajectoryRecorderVecEnvWrapper | None = None
        self.constraint_wrapper: LearnedCostVecEnvWrapper | GACLRewardWrapper | None = None
        self.icrl_trainer: ICRLTrainer | None = None
        self.true_constraint_logger: TrueConstraintLogger | None = None

    def _init_icrl_learner(
        self,
        policy: Any,
        env: Any,
        demonstrations: DemonstrationsLike | None,
        constraint_net: _ConstraintNet | None,
        constraint_net_kwargs: dict[str, Any] | None,
        constraint_learning_rate: float,
        constraint_steps: int,
        constraint_batch_size: int | None,
        update_every: int | None,
        n_nominal_trajectories: int | None,
        trainer_class: type[ICRLTrainer] | None,
        trainer_kwargs: dict[str, Any] | None,
        allow_env_mismatch: bool,
        learner_kwargs: dict[str, Any],
        _init_setup_model: bool,
    ) -> None:
        """
        The constructor of an ICRL algorithm whose learner takes a cost function (PPO-Lagrangian, SAC-Lagrangian):
        refuse a ``cost_fn`` (the constraint model is the cost), keep the ICRL settings (:meth:`_init_icrl`), build
        the learner, then set the model up.

        :param policy: The learner's policy
        :param env: The environment
        :param demonstrations: See :meth:`_init_icrl` (so are the arguments up to ``allow_env_mismatch``)
        :param constraint_net: A built constraint model, or ``None``
        :param constraint_net_kwargs: Arguments of the default constraint model
        :param constraint_learning_rate: Learning rate of the constraint model
        :param constraint_steps: Passes over the nominal data per constraint update
        :param constraint_batch_size: Nominal pairs per constraint minibatch
        :param update_every: Policy timesteps between constraint updates
        :param n_nominal_trajectories: Most recent learner trajectories per update
        :param trainer_class: The trainer class, or ``None`` for the algorithm's
        :param trainer_kwargs: Further arguments of the trainer
        :param allow_env_mismatch: Accept demonstrations recorded on another env id
        :param learner_kwargs: The learner's other constructor arguments (the user's, with ``cost_fn`` refused)
        :param _init_setup_model: Set the model up now
        """
        if learner_kwargs.get("cost_fn") is not None:
            raise ValueError(f"{type(self).__name__} learns its cost: do not pass `cost_fn`.")
        learner_kwargs = {key: value for key, value in learner_kwargs.items() if key != "cost_fn"}
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
        # The learner's constructor: the class after this mixin in the algorithm's bases
        super().__init__(policy, env, _init_setup_model=False, **learner_kwargs)  # type: ignore[call-arg]
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up

    def _setup_model(self) -> None:
        super()._setup_model()  # type: ignore[misc]
        self._setup_icrl()

    def _setup_icrl(self) -> None:
        """Resolve the demonstrations, build (or rebuild, on ``load``) the constraint model and wrap the env."""
        if self.constraint_net is None:
            # ``load`` restores constraint_net_spec_ from the zip's data; a new model builds from the spaces
            spec = getattr(self, "constraint_net_spec_", None)
            if spec is not None:
                self.constraint_net = spec["class"].from_constructor_kwargs(spec["kwargs"])
            else:
                self.constraint_net = self.constraint_net_class_.from_spaces(
                    self.observation_space, self.action_space, **self.constraint_net_kwargs
                )
        self._check_constraint_net_spaces()
        self.constraint_net.to(self.device)
        self.constraint_net_spec_ = {"class": type(self.constraint_net), "kwargs": self.constraint_net.constructor_kwargs}
        self.constraint_optimizer = th.optim.Adam(self.constraint_net.parameters(), lr=self.constraint_learning_rate)
        pending = getattr(self, "_pending_demonstrations", None)
        if pending is None and self.demonstrations is not None and self.expert_obs is None:
            # ``load(..., demonstrations=...)`` sets the attribute directly
            pending = self.demonstrations
        if pending is not None:
            self.set_demonstrations(pending)
        elif self.demonstrations is None and self.demonstrations_source is not None:
            try:
                self.set_demonstrations(self.demonstrations_source)
            except DemonstrationError as error:
                warnings.warn(
                    f"Could not reload the demonstrations {self.demonstrations_source!r} ({error}); the model predicts, "
                    "but to train it pass `demonstrations=` to `load` or call `set_demonstrations(...)`."
                )
        self._check_trainer_arguments()
        self._wrap_icrl_env()

    def _check_trainer_arguments(self) -> None:
        """
        A throwaway trainer: bad trainer settings fail when the model is made, not in ``learn()``. It sees the expert
        data when it is loaded (settings such as ``expert_episode_lengths`` are checked against it), else one sampled
        pair.
        """
        assert self.constraint_net is not None and self.constraint_optimizer is not None
        if self.expert_obs is not None and self.expert_acts is not None:
            obs, acts = self.expert_obs, self.expert_acts
        else:
            obs = np.asarray(self.observation_space.sample())[None]
            acts = np.asarray(self.action_space.sample())[None]
        update_every = self.update_every if self.update_every is not None else self._default_update_every()
        try:
            self.trainer_class(
                self.constraint_net,
                self.constraint_optimizer,
                obs,
                acts,
                None,
                None,
                update_every=update_every,
                constraint_steps=self.constraint_steps,
                batch_size=self.constraint_batch_size,
                n_nominal_trajectories=1 if self.n_nominal_trajectories is None else self.n_nominal_trajectories,
                **self.trainer_kwargs,
            )
        except TypeError as error:
            if "unexpected keyword argument" not in str(error):
                raise  # e.g. a constraint net of the wrong kind: the trainer's message says it
            raise TypeError(f"Bad `trainer_kwargs` for {self.trainer_class.__name__}: {error}") from error

    def _default_update_every(self) -> int:
        """Policy timesteps between constraint updates when ``update_every`` is not given: one on-policy rollout."""
        return self.n_steps * self.n_envs

    def _check_constraint_net_spaces(self) -> None:
        assert self.constraint_net is not None
        net = self.constraint_net
        expected = (
            _space_features(self.observation_space, "observation"),
            _space_features(self.action_space, "action"),
        )
        if expected != ((net.obs_dim, net.discrete_obs), (net.action_dim, net.discrete_actions)):
            raise ValueError(
                f"The constraint net takes {net.obs_dim} observation and {net.action_dim} action features "
                f"(discrete: {net.discrete_obs}, {net.discrete_actions}), but the env has {self.observation_space} and "
                f"{self.action_space}: build it with `{type(net).__name__}.from_spaces(env.observation_space, "
                "env.action_space, ...)`."
            )

    def set_demonstrations(self, demonstrations: DemonstrationsLike, allow_env_mismatch: bool | None = None) -> None:
        """
        Use these expert demonstrations (checked against the env's spaces, or the constraint net's without an env).
        On a new model the constraint net's input normaliser is fitted on them.

        :param demonstrations: A :class:`~sb3_icrl.data.Demonstrations`, a list of trajectories, the name of a
            shipped dataset (``"GridWorldWall-v0"``) or the path of an ``.npz`` file
        :param allow_env_mismatch: Accept data whose metadata names another env id than the env's (spaces must fit);
            ``None``: the model's ``allow_env_mismatch``
        """
        if allow_env_mismatch is None:
            allow_env_mismatch = getattr(self, "allow_env_mismatch", False)
        if isinstance(demonstrations, (str, os.PathLike)):
            demos = load_demonstrations(demonstrations, env=self.env, allow_env_mismatch=allow_env_mismatch)
            self.demonstrations_source = os.fspath(demonstrations)
        elif isinstance(demonstrations, Demonstrations):
            demos = demonstrations
        elif isinstance(demonstrations, Sequence) and all(isinstance(t, Trajectory) for t in demonstrations):
            demos = Demonstrations([t for t in demonstrations if isinstance(t, Trajectory)])
        else:
            raise TypeError(
                "`demonstrations` must be a Demonstrations, a list of Trajectory, a shipped dataset name or an .npz path, "
                f"got {type(demonstrations).__name__}."
            )
        if len(demos) == 0:
            raise DemonstrationError("The demonstrations hold no trajectory.")
        transitions = demos.transitions
        # Without an env (a model loaded for prediction), the spaces saved with the model
        target = self.env if self.env is not None else self
        check_spaces(transitions.obs, transitions.acts, target, demos.metadata, allow_env_mismatch)  # type: ignore[arg-type]
        self.demonstrations = demos
        self._pending_demonstrations = None
        self.expert_obs, self.expert_acts = transitions.obs, transitions.acts
        assert self.constraint_net is not None
        normalizer = self.constraint_net.normalizer
        if normalizer is not None and not bool(normalizer.fitted):
            self.constraint_net.fit_normalizer(self.expert_obs, self.expert_acts)

    def _make_constraint_wrapper(self, venv: VecEnv) -> LearnedCostVecEnvWrapper | GACLRewardWrapper:
        """
        The wrapper between the env and the learner: by default one that moves the true cost out of the learner's
        sight; the learner computes the learned cost itself (``PPOLagrangian``'s ``cost_fn``, once per rollout).
        """
        return LearnedCostVecEnvWrapper(venv, None)

    def _configure_constraint_wrapper(self, wrapper: VecEnvWrapper) -> None:
        """
        Apply this model's settings to its constraint wrapper: called on a new wrapper and on one reused from another
        model of the same kind, so that the reused one follows this model's settings, not the other's (none here).

        :param wrapper: The constraint wrapper, new or reused
        """

    def _wrap_icrl_env(self) -> None:
        """Insert ``constraint_wrapper(recorder(raw_venv))`` at the bottom of the env, below any VecNormalize."""
        self.recorder = self.constraint_wrapper = None
        if self.env is None:
            return
        parent: VecEnvWrapper | None = None
        node: VecEnv = self.env
        while isinstance(node, VecEnvWrapper):
            if isinstance(node, (LearnedCostVecEnvWrapper, GACLRewardWrapper)):
                if type(node) is self.constraint_wrapper_class and isinstance(node.venv, TrajectoryRecorderVecEnvWrapper):
                    # The env of another model of this kind (or this model's own): reuse it, with this constraint
                    self.constraint_wrapper, self.recorder = node, node.venv
                    assert self.constraint_net is not None
                    install_constraint(node, self.constraint_net)
                    self._configure_constraint_wrapper(node)
                    return
                raise ValueError(
                    f"The env already contains a {type(node).__name__}; {type(self).__name__} adds its own "
                    f"{self.constraint_wrapper_class.__name__}: pass the env without it."
                )
            parent, node = node, node.venv
        self.recorder = TrajectoryRecorderVecEnvWrapper(node)
        self.constraint_wrapper = self._make_constraint_wrapper(self.recorder)
        self._configure_constraint_wrapper(self.constraint_wrapper)
        if parent is None:
            self.env = self.constraint_wrapper
        else:
            parent.venv = self.constraint_wrapper

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        super().set_env(env, force_reset)  # type: ignore[misc]
        self._wrap_icrl_env()

    # ------------------------------------------------------------------ training

    def _make_trainer(self) -> ICRLTrainer:
        assert self.constraint_net is not None and self.constraint_optimizer is not None
        assert self.recorder is not None and self.constraint_wrapper is not None and self.demonstrations is not None
        assert self.expert_obs is not None and self.expert_acts is not None
        update_every = self.update_every if self.update_every is not None else self._default_update_every()
        n_nominal = self.n_nominal_trajectories if self.n_nominal_trajectories is not None else len(self.demonstrations)
        return self.trainer_class(
            self.constraint_net,
            self.constraint_optimizer,
            self.expert_obs,
            self.expert_acts,
            self.recorder,
            self.constraint_wrapper,
            update_every=update_every,
            constraint_steps=self.constraint_steps,
            batch_size=self.constraint_batch_size,
            n_nominal_trajectories=n_nominal,
            **self.trainer_kwargs,
        )

    def learn(
        self: SelfICRL,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfICRL:
        """
        Alternate policy learning and constraint updates (see :class:`~sb3_icrl.icrl.ICRLTrainer`).

        :param total_timesteps: Policy timesteps
        :param callback: Callback(s) called at every step, as in SB3
        :param log_interval: Iterations between log dumps
        :param tb_log_name: TensorBoard run name (default: the class name)
        :param reset_num_timesteps: Whether to reset the timestep counter
        :param progress_bar: Display a progress bar
        :return: The trained model
        """
        check_total_timesteps(total_timesteps)
        if self.demonstrations is None:
            raise ValueError(
                f"{type(self).__name__} has no demonstrations to learn from: pass `demonstrations=` to the constructor or "
                "to `load`, or call `set_demonstrations(...)`."
            )
        if self.env is None:
            raise ValueError("This model has no env: call `set_env(env)` before `learn()`.")
        if self.icrl_trainer is None or self.icrl_trainer.recorder is not self.recorder:
            self.icrl_trainer = self._make_trainer()
        if self.true_constraint_logger is None:
            self.true_constraint_logger = TrueConstraintLogger()
        callbacks: list[BaseCallback] = [self.icrl_trainer, self.true_constraint_logger]
        if isinstance(callback, list):
            callbacks += callback
        elif isinstance(callback, BaseCallback):
            callbacks.append(callback)
        elif callback is not None:
            callbacks.append(ConvertCallback(callback))
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=CallbackList(callbacks),
            log_interval=log_interval,
            tb_log_name=type(self).__name__ if tb_log_name is None else tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def constraint_cost(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """
        The learned cost ``1 - phi`` of a batch (raw observations, actions as sent to the env).

        :param observations: ``(batch, obs_dim)`` (indices for a discrete space)
        :param actions: ``(batch, action_dim)`` (indices for a discrete space)
        :return: Costs, ``(batch,)``
        """
        assert self.constraint_net is not None
        return self.constraint_net.cost(observations, actions)

    # ------------------------------------------------------------------ saving

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()  # type: ignore[misc]
        return [*state_dicts, "constraint_net", "constraint_optimizer"], variables

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),  # type: ignore[misc]
            "demonstrations",
            "_pending_demonstrations",
            "expert_obs",
            "expert_acts",
            "recorder",
            "constraint_wrapper",
            "icrl_trainer",
            "true_constraint_logger",
        ]


#: The reference code's multiplier for the ICRL runs: plain gradient ascent (SGD), budget 0 on the per-step cost
DEFAULT_LAGRANGE_KWARGS: dict[str, Any] = {"init": 0.1, "lr": 0.05, "optimizer": "sgd"}


class LagrangianICRL(ICRLAlgorithmMixin, PPOLagrangian):
    """
    An ICRL algorithm whose forward solver is :class:`~sb3_icrl.PPOLagrangian` on the learned cost ``1 - phi``
    (BC2L, MECL, VICRL). The learner computes the learned cost itself, once per rollout on all of its pairs (its
    ``cost_fn`` is :meth:`constraint_cost`); the true cost is moved out of its sight.

    :param policy: The policy model (``"MlpPolicy"`` or a ``CostActorCriticPolicy`` subclass)
    :param env: The environment (a gymnasium env, a VecEnv or a registered id); flat Box or Discrete spaces
    :param demonstrations: Expert demonstrations: a :class:`~sb3_icrl.data.Demonstrations`, a list of trajectories,
        a shipped dataset's name (``"GridWorldWall-v0"``) or an ``.npz`` path; checked against the env's spaces.
        May be ``None`` only for a model that will not ``learn`` before ``set_demonstrations``.
    :param constraint_net: A built constraint model (default: one of ``constraint_net_class`` for the env's spaces)
    :param constraint_net_kwargs: Arguments of the default constraint model (``hidden_sizes``, ``obs_select_dim``...)
    :param constraint_learning_rate: Adam learning rate of the constraint model
    :param constraint_steps: Passes over the nominal data per constraint update
    :param constraint_batch_size: Nominal pairs per constraint minibatch (``None``: all of them)
    :param update_every: Policy timesteps between constraint updates (default: one rollout, ``n_steps * n_envs``)
    :param n_nominal_trajectories: Most recent learner trajectories per update (default: the number of expert ones)
    :param trainer_class: The :class:`~sb3_icrl.icrl.ICRLTrainer` subclass (default: the algorithm's)
    :param trainer_kwargs: Further arguments of the trainer
    :param allow_env_mismatch: Accept demonstrations recorded on another env id (their metadata's ``env_id``) whose
        spaces fit this env's; by default such data is refused
    :param cost_budget: Budget on the learned cost (reference: 0), or ``"expert"``: the expert's mean learned cost per
        step, re-set after each constraint update (see ``budget_from_expert`` of :class:`~sb3_icrl.icrl.ICRLTrainer`;
        needs ``budget_statistic="step"``)
    :param budget_statistic: ``"step"`` (mean per-step cost of the rollout, as the reference) or ``"episode"``
    :param lagrange_kwargs: Multiplier arguments (default :data:`DEFAULT_LAGRANGE_KWARGS`)
    :param kwargs: The other arguments of :class:`~sb3_icrl.PPOLagrangian` (``n_steps``, ``learning_rate``,
        ``tensorboard_log``, ``seed``, ...), except ``cost_fn``: the constraint model is the cost
    """

    def __init__(
        self,
        policy: str | type[CostActorCriticPolicy],
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
        cost_budget: float | str = 0.0,
        budget_statistic: str = "step",
        lagrange_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        if isinstance(cost_budget, str):
            if cost_budget != "expert":
                raise ValueError(f"`cost_budget` must be a float or 'expert', got {cost_budget!r}.")
            if budget_statistic != "step":
                raise ValueError(
                    f"cost_budget='expert' is a per-step budget: it needs budget_statistic='step', got {budget_statistic!r}."
                )
            trainer_kwargs = {"budget_from_expert": True, **(trainer_kwargs or {})}
            cost_budget = 0.0  # until the first install sets the expert's cost
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
            {
                "cost_budget": cost_budget,
                "budget_statistic": budget_statistic,
                "lagrange_kwargs": dict(DEFAULT_LAGRANGE_KWARGS) if lagrange_kwargs is None else lagrange_kwargs,
                **kwargs,
            },
            _init_setup_model,
        )

    def _setup_model(self) -> None:
        super()._setup_model()
        # Read at call time: always the current constraint model, after updates and loads alike
        self.cost_fn = self.constraint_cost
