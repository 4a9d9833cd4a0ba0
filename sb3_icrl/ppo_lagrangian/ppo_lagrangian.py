"""PPO-Lagrangian: PPO with a cost critic and one Lagrange multiplier per constraint."""

from collections import deque
from collections.abc import Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv
from torch.nn import functional as F

from sb3_icrl.common.buffers import CostRolloutBuffer
from sb3_icrl.common.costs import CostError, CostFn, as_cost_array, costs_from_infos
from sb3_icrl.common.lagrange import LagrangeMultiplier, make_lagrange_multiplier
from sb3_icrl.common.policies import (
    CostActorCriticPolicy,
    check_finite,
    clip_grad_norms_,
    diverged_error,
    no_distribution_validation,
    without_distribution_validation,
)
from sb3_icrl.common.saved import CheckedLoadMixin, library_algorithm
from sb3_icrl.ppo_lagrangian.policies import CnnPolicy, MlpPolicy

SelfPPOLagrangian = TypeVar("SelfPPOLagrangian", bound="PPOLagrangian")

BUDGET_STATISTICS = ("episode", "step")
TERMINATION_COSTS = ("zero", "bootstrap", "budget")
# Observations per batched critic pass at the end of a rollout
VALUE_CHUNK = 4096


class PPOLagrangian(CheckedLoadMixin, PPO):
    """
    PPO-Lagrangian (Ray et al. 2019; the forward solver of the ICRL papers): PPO whose policy maximises
    ``(A_r - sum_i lambda_i A_c,i) / (1 + sum_i lambda_i)``, with a cost critic, cost GAE, and multipliers
    ``lambda_i >= 0`` updated on ``J_c,i - budget_i`` before each policy update.

    The per-step cost is read from ``info[cost_info_key]`` (a float, or one float per constraint), or computed by
    ``cost_fn(observations, actions)`` batched over the envs (e.g. a learned constraint model; swap it with
    :meth:`set_cost_fn` between ``learn()`` calls). With the multiplier held at 0 the update is exactly PPO's.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, or a ``CostActorCriticPolicy`` subclass)
    :param env: The environment to learn from (if registered in Gym, can be str)
    :param learning_rate: Learning rate (of the actor, reward critic and cost critic), can be a schedule
    :param n_steps: Steps per env per update
    :param batch_size: Minibatch size
    :param n_epochs: Epochs per update
    :param gamma: Discount factor of the reward
    :param gae_lambda: GAE lambda of the reward
    :param clip_range: PPO clipping parameter, can be a schedule
    :param clip_range_vf: Clipping of the reward and cost value functions (``None``: no clipping)
    :param normalize_advantage: Whether to normalise the combined advantage per minibatch (as PPO does)
    :param ent_coef: Entropy coefficient
    :param vf_coef: Reward value loss coefficient
    :param max_grad_norm: Max gradient norm, applied to the actor-critic and to the cost critic separately
    :param use_sde: Whether to use generalized State Dependent Exploration
    :param sde_sample_freq: Sample a new gSDE noise matrix every n steps (-1: only at the start of a rollout)
    :param rollout_buffer_class: Rollout buffer class (default: ``CostRolloutBuffer``)
    :param rollout_buffer_kwargs: Keyword arguments for the rollout buffer
    :param target_kl: Limit the KL divergence between updates (``None``: no limit)
    :param cost_budget: Budget per constraint (a float for one constraint, a sequence for several); its units
        follow ``budget_statistic``
    :param budget_statistic: ``"episode"``: ``J_c`` is the mean undiscounted cost of the episodes that ended since
        the last multiplier update (no update while none ended); ``"step"``: the mean per-step cost of the latest
        rollout (the ICRL reference code uses this with budget 0)
    :param cost_gamma: Discount factor of the costs (default: ``gamma``)
    :param cost_gae_lambda: GAE lambda of the costs (default: ``gae_lambda``)
    :param cost_vf_coef: Cost value loss coefficient
    :param termination_cost: What an episode that terminates (as opposed to a time-limit truncation) costs after its
        last step. ``"zero"``: nothing, the usual convention. ``"bootstrap"``: the cost stream goes on as if the episode
        had been truncated, bootstrapped with the cost critic's value of the final observation, so a learner cannot
        escape its costs by ending episodes on purpose (e.g. a robot falling when its learned cost exceeds the budget
        everywhere it goes). A float ``c >= 0``: the episode enters an absorbing state costing ``c`` per step forever,
        ``cost_gamma * c / (1 - cost_gamma)`` added to the last step's cost. ``"budget"`` (with
        ``budget_statistic="step"``): that absorbing state costs the current per-step budget, which turns the cost
        return into ``sum_t cost_gamma^t (c_t - budget)`` plus a constant the same for every episode: ending an
        episode is then neither cheaper nor dearer than going on at the budget. Rewards are not changed.
    :param lagrange_update: ``"gradient"`` (gradient ascent, SGD or Adam) or ``"pid"`` (Stooke et al. 2020)
    :param lagrange_kwargs: Arguments of the multiplier: ``init``, ``lr``, ``optimizer`` (``"adam"``/``"sgd"``),
        ``upper_bound`` for gradient; ``init``, ``kp``, ``ki``, ``kd``, ``d_delay``, ``delta_p_ema_alpha``,
        ``delta_d_ema_alpha``, ``upper_bound`` for PID (see ``sb3_icrl.common.lagrange``)
    :param cost_fn: Optional ``cost_fn(observations, actions) -> costs`` replacing ``info[cost_info_key]``;
        it sees the observations the env returned (before ``VecNormalize``) and the actions sent to the env. It is
        called once per rollout, on all of its ``n_steps * n_envs`` pairs (the function must not change during a
        rollout; callbacks see ``costs=None`` in the rollout's locals). Not saved with the model: set it again after
        ``load``.
    :param cost_info_key: The info key holding the per-step cost
    :param stats_window_size: Window size for the rollout logging (episodes)
    :param tensorboard_log: The log location for tensorboard (if None, no logging)
    :param policy_kwargs: Additional arguments passed to the policy on creation (e.g. ``cost_net_arch``)
    :param verbose: Verbosity level: 0 no output, 1 info messages (such as device or wrappers used), 2 debug messages
    :param seed: Seed for the pseudo random generators
    :param device: Device (cpu, cuda, ...) on which the code should be run.
    :param _init_setup_model: Whether or not to build the network at the creation of the instance
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
    }
    policy: CostActorCriticPolicy  # type: ignore[assignment]
    rollout_buffer: CostRolloutBuffer  # type: ignore[assignment]
    #: Whether ``cost_fn`` may return costs below 0: a learned cost charged as a penalty on the reward (IRL-Plus's),
    #: not a count of violations. Env costs are always checked to be >= 0
    signed_costs: ClassVar[bool] = False

    def __init__(
        self,
        policy: str | type[CostActorCriticPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 3e-4,
        n_steps: int = 2048,
        batch_size: int = 64,
        n_epochs: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        clip_range_vf: float | Schedule | None = None,
        normalize_advantage: bool = True,
        ent_coef: float = 0.0,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        target_kl: float | None = None,
        cost_budget: float | Sequence[float] = 0.0,
        budget_statistic: str = "episode",
        cost_gamma: float | None = None,
        cost_gae_lambda: float | None = None,
        cost_vf_coef: float = 0.5,
        termination_cost: str | float = "zero",
        lagrange_update: str = "gradient",
        lagrange_kwargs: dict[str, Any] | None = None,
        cost_fn: CostFn | None = None,
        cost_info_key: str = "cost",
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ):
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=batch_size,
            n_epochs=n_epochs,
            gamma=gamma,
            gae_lambda=gae_lambda,
            clip_range=clip_range,
            clip_range_vf=clip_range_vf,
            normalize_advantage=normalize_advantage,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=max_grad_norm,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs,
            target_kl=target_kl,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        try:
            budget = np.atleast_1d(np.asarray(cost_budget, dtype=np.float64))
        except (TypeError, ValueError):
            budget = np.array([np.nan])  # text or a mapping: refused below with the message of any bad budget
        if budget.ndim != 1 or budget.size == 0 or not np.all(np.isfinite(budget)):
            raise ValueError(f"`cost_budget` must be a finite float or a non-empty sequence of floats, got {cost_budget!r}.")
        for name, value in (
            ("gamma", gamma),
            ("gae_lambda", gae_lambda),
            ("cost_gamma", cost_gamma),
            ("cost_gae_lambda", cost_gae_lambda),
        ):
            if value is not None and not 0.0 <= value <= 1.0:
                raise ValueError(f"`{name}` must be in [0, 1], got {value!r}.")
        if cost_vf_coef < 0:
            raise ValueError(f"`cost_vf_coef` must be >= 0, got {cost_vf_coef!r}.")
        if not isinstance(cost_info_key, str):
            raise TypeError(f"`cost_info_key` is the info key of the per-step cost, a string; got {cost_info_key!r}.")
        if stats_window_size < 1:
            raise ValueError(f"`stats_window_size` must be >= 1 (episodes in the logged means), got {stats_window_size!r}.")
        if np.any(budget < 0):
            raise ValueError(
                f"`cost_budget` must be >= 0 (costs are non-negative, so no policy could meet it), got {cost_budget!r}."
            )
        if budget_statistic not in BUDGET_STATISTICS:
            raise ValueError(f"Unknown `budget_statistic` {budget_statistic!r}: use one of {BUDGET_STATISTICS}.")
        self.termination_cost = _check_termination_cost(termination_cost, gamma if cost_gamma is None else cost_gamma)
        if self.termination_cost == "budget" and budget_statistic != "step":
            raise ValueError(
                "termination_cost='budget' charges a terminated episode the per-step budget for ever, so it needs "
                f"budget_statistic='step' (got {budget_statistic!r}): use a float cost per step or 'bootstrap' instead."
            )
        self.cost_budget = budget
        self.n_costs = budget.size
        self.budget_statistic = budget_statistic
        self.cost_gamma = gamma if cost_gamma is None else cost_gamma
        self.cost_gae_lambda = gae_lambda if cost_gae_lambda is None else cost_gae_lambda
        self.cost_vf_coef = cost_vf_coef
        self.lagrange_update = lagrange_update
        self.lagrange_kwargs = lagrange_kwargs or {}
        self.cost_info_key = cost_info_key
        self.cost_fn: CostFn | None = None
        self.set_cost_fn(cost_fn)
        self.lagrange_multiplier: LagrangeMultiplier | None = None
        self.ep_cost_buffer: deque[np.ndarray] | None = None
        self._current_episode_costs: np.ndarray | None = None
        self._episode_costs_since_update: list[np.ndarray] = []
        self._rollout_mean_step_cost: np.ndarray | None = None
        self._env_names: list[str] = []
        # Saved in the zip: ``load`` of another algorithm's model fails clearly
        self.sb3_icrl_algorithm = library_algorithm(type(self))

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        if not (isinstance(self.policy_class, type) and issubclass(self.policy_class, CostActorCriticPolicy)):
            raise TypeError(
                f"PPOLagrangian needs a CostActorCriticPolicy (it adds the cost critic), got {self.policy_class!r}: "
                "use 'MlpPolicy', 'CnnPolicy' or a subclass of sb3_icrl.common.policies.CostActorCriticPolicy."
            )
        if isinstance(self.observation_space, spaces.Dict):
            raise NotImplementedError("PPOLagrangian does not support Dict observation spaces yet: flatten them first.")
        if self.policy_kwargs.get("n_costs", self.n_costs) != self.n_costs:
            raise ValueError(
                f"policy_kwargs['n_costs']={self.policy_kwargs['n_costs']} disagrees with the {self.n_costs} budget(s) "
                "in `cost_budget`: leave n_costs out of policy_kwargs, it follows cost_budget."
            )
        # Copies: SB3 keeps the caller's dicts, which may be shared with other models
        self.policy_kwargs = {**self.policy_kwargs, "n_costs": self.n_costs}
        if self.rollout_buffer_class is None:
            self.rollout_buffer_class = CostRolloutBuffer
        if not issubclass(self.rollout_buffer_class, CostRolloutBuffer):
            raise TypeError(f"PPOLagrangian needs a CostRolloutBuffer subclass, got {self.rollout_buffer_class.__name__}.")
        self.rollout_buffer_kwargs = {
            **self.rollout_buffer_kwargs,
            "n_costs": self.n_costs,
            "cost_gamma": self.cost_gamma,
            "cost_gae_lambda": self.cost_gae_lambda,
        }
        super()._setup_model()
        # ``load`` restores the multiplier before calling _setup_model: keep it
        if self.lagrange_multiplier is None:
            self.lagrange_multiplier = make_lagrange_multiplier(
                self.lagrange_update, self.cost_budget.tolist(), self.n_costs, **self.lagrange_kwargs
            )

    def set_cost_budget(self, cost_budget: float | Sequence[float]) -> None:
        """
        Use a new budget from the next multiplier update on (e.g. the expert's learned cost in ICRL), and with
        ``termination_cost="budget"`` in the termination charges of the next rollout; the multipliers keep their values.

        :param cost_budget: Budget per constraint, in the units of ``budget_statistic``
        """
        budget = np.atleast_1d(np.asarray(cost_budget, dtype=np.float64))
        if budget.shape != (self.n_costs,) or not np.all(np.isfinite(budget)) or np.any(budget < 0):
            raise ValueError(f"Expected {self.n_costs} finite budget(s) >= 0, one per constraint, got {cost_budget!r}.")
        self.cost_budget = budget
        if self.lagrange_multiplier is not None:
            self.lagrange_multiplier.cost_budget = budget.copy()

    def set_cost_fn(self, cost_fn: CostFn | None) -> None:
        """
        Use ``cost_fn(observations, actions) -> costs`` for the per-step costs from now on (``None``: read
        ``info[cost_info_key]``), called once per rollout on all of its pairs. Takes effect at the next rollout; the
        model is not rebuilt.

        :param cost_fn: The cost function
        """
        if cost_fn is not None and not callable(cost_fn):
            raise TypeError(f"`cost_fn` must be callable as cost_fn(observations, actions) -> costs, got {cost_fn!r}.")
        self.cost_fn = cost_fn

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer"], []

    def set_parameters(
        self,
        load_path_or_dict: str | dict[str, Any],
        exact_match: bool = True,
        device: th.device | str = "auto",
    ) -> None:
        """
        SB3's ``set_parameters``; also takes the parameters of a model saved when the cost critic had an optimizer of
        its own (``policy.cost_optimizer``), whose state joins the one optimizer's (:func:`merge_cost_optimizer`).

        :param load_path_or_dict: A saved model's zip, or a dict of state dicts (as ``get_parameters`` returns)
        :param exact_match: Whether the parameters must name every object that ``save`` writes
        :param device: Device on which the parameters are loaded
        """
        params = load_path_or_dict
        if not isinstance(params, dict):
            _, params, _ = load_from_zip_file(params, device=device, load_data=False)
        super().set_parameters(merge_cost_optimizer(params), exact_match=exact_match, device=device)  # type: ignore[arg-type]

    def _excluded_save_params(self) -> list[str]:
        # The cost function may be an arbitrary closure (e.g. over a learned constraint net saved elsewhere)
        return [*super()._excluded_save_params(), "cost_fn", "_env_names"]

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        env_reset = reset_num_timesteps or self._last_obs is None
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        if self.ep_cost_buffer is None or reset_num_timesteps:
            self.ep_cost_buffer = deque(maxlen=self._stats_window_size)
        if env_reset or self._current_episode_costs is None:
            self._current_episode_costs = np.zeros((self.n_envs, self.n_costs), dtype=np.float64)
            self._episode_costs_since_update = []
        assert self.env is not None
        self._env_names = [_env_name(self.env, idx) for idx in range(self.n_envs)]
        return result

    def _settle_deferred_costs(self, deferred: "_DeferredCosts", n_steps: int, rollout_buffer: CostRolloutBuffer) -> None:
        """
        The cost function's costs of the first ``n_steps`` steps of the rollout, in one batch: stored in the buffer and
        counted in the episode statistics, step by step as if they had come one step at a time.
        """
        assert self.cost_fn is not None
        if n_steps == 0:
            return
        obs, actions = deferred.pairs(n_steps)
        costs = _batch_costs(self.cost_fn(obs, actions), n_steps, self.n_envs, self.n_costs, self.signed_costs)
        rollout_buffer.costs[:n_steps] = costs
        for step in range(n_steps):
            self._update_cost_stats(costs[step], deferred.dones[step])  # type: ignore[index]

    def _update_cost_stats(self, costs: np.ndarray, dones: np.ndarray) -> None:
        assert self._current_episode_costs is not None and self.ep_cost_buffer is not None
        self._current_episode_costs += costs
        if not dones.any():
            return
        # Kept for the multiplier only where it reads episodes; under "step" it reads the rollout's mean, and a list
        # that nothing empties would grow with every episode (into every checkpoint)
        keep = self.budget_statistic != "step"
        for env_idx in np.flatnonzero(dones):
            episode_cost = self._current_episode_costs[env_idx].copy()
            self.ep_cost_buffer.append(episode_cost)
            if keep:
                self._episode_costs_since_update.append(episode_cost)
            self._current_episode_costs[env_idx] = 0.0

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
    ) -> bool:
        """
        Collect experiences and costs with the current policy and fill a ``CostRolloutBuffer``.

        SB3's on-policy loop plus per-step costs, with two changes that make it faster: the loop only runs the
        actor; the reward and cost values of every observation (and of the final observations of time-limit
        truncations, for bootstrapping) are computed in one batch when the rollout is complete, and so are the costs
        of a ``cost_fn``. Neither the critics nor the cost function change during a rollout, so the values are the same
        (up to float rounding of batched products). torch's
        argument checks of the policy's action distribution are off (they change no value and cost several tensor
        operations per step; callbacks keep torch's setting); the actions are checked for NaN instead.

        :param env: The training environment
        :param callback: Callback that will be called at each step (and at the beginning and end of the rollout)
        :param rollout_buffer: Buffer to fill with rollouts
        :param n_rollout_steps: Number of experiences to collect per environment
        :return: True if function returned with at least `n_rollout_steps` collected, False if callback
            terminated rollout prematurely.
        """
        assert isinstance(rollout_buffer, CostRolloutBuffer), "PPOLagrangian needs a CostRolloutBuffer"
        assert self._last_obs is not None, "No previous observation was provided"
        self.policy.set_training_mode(False)

        n_steps = 0
        rollout_buffer.reset()
        if self.use_sde:
            self.policy.reset_noise(env.num_envs)

        callback.on_rollout_start()
        # (step, env index, final observation) of time-limit truncations, bootstrapped after the loop; terminations
        # too when ``termination_cost`` charges them (their costs only)
        truncations: list[tuple[int, int, np.ndarray]] = []
        terminations: list[tuple[int, int, np.ndarray]] = []
        no_values = th.zeros(env.num_envs)
        # A cost function judges the whole rollout in one batch at its end: the pairs are kept until then
        deferred = _DeferredCosts(n_rollout_steps) if self.cost_fn is not None else None

        while n_steps < n_rollout_steps:
            if self.use_sde and self.sde_sample_freq > 0 and n_steps % self.sde_sample_freq == 0:
                self.policy.reset_noise(env.num_envs)

            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)  # type: ignore[arg-type]
                with no_distribution_validation():
                    action_tensor, log_probs = self.policy.act(obs_tensor)
            actions = action_tensor.cpu().numpy()
            check_finite(actions, "The policy's actions")

            clipped_actions = actions
            if isinstance(self.action_space, spaces.Box):
                if self.policy.squash_output:
                    clipped_actions = self.policy.unscale_action(clipped_actions)
                else:
                    clipped_actions = np.clip(actions, self.action_space.low, self.action_space.high)

            if deferred is not None:
                # The cost function judges (s, a) on the env's own observation, not the normalised one
                # (VecNormalize's raw observation read in place: ``add_pair`` copies it, no deepcopy needed)
                original_obs = self._vec_normalize_env.old_obs if self._vec_normalize_env else self._last_obs
                deferred.add_pair(n_steps, original_obs, clipped_actions)  # type: ignore[arg-type]

            new_obs, rewards, dones, infos = env.step(clipped_actions)
            costs = None  # while the cost function's costs wait for the end of the rollout
            if deferred is None:
                costs = costs_from_infos(infos, self.cost_info_key, self.n_costs, self._env_names)

            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                if deferred is not None:  # the steps completed before this one count, as with per-step costs
                    self._settle_deferred_costs(deferred, n_steps, rollout_buffer)
                return False

            self._update_info_buffer(infos, dones)
            if deferred is not None:
                deferred.add_dones(n_steps, dones)
            else:
                self._update_cost_stats(costs, dones)  # type: ignore[arg-type]
            n_steps += 1

            if isinstance(self.action_space, spaces.Discrete):
                actions = actions.reshape(-1, 1)

            # Time-limit truncation: bootstrap reward and costs with the values of the final observation (SB3 GH#633)
            for idx, done in enumerate(dones):
                if not done or infos[idx].get("terminal_observation") is None:
                    continue
                if infos[idx].get("TimeLimit.truncated", False):
                    truncations.append((n_steps - 1, idx, infos[idx]["terminal_observation"]))
                elif self.termination_cost != "zero":
                    terminations.append((n_steps - 1, idx, infos[idx]["terminal_observation"]))

            rollout_buffer.add(
                self._last_obs,  # type: ignore[arg-type]
                actions,
                rewards,
                self._last_episode_starts,  # type: ignore[arg-type]
                no_values,
                log_probs,
            )
            if costs is not None:
                rollout_buffer.add_costs(costs)
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones

        if deferred is not None:
            self._settle_deferred_costs(deferred, n_steps, rollout_buffer)
        self._rollout_mean_step_cost = rollout_buffer.costs.mean(axis=(0, 1)).astype(np.float64)
        last_values, last_cost_values = self._finish_values(
            rollout_buffer, new_obs, truncations, terminations  # type: ignore[arg-type]
        )
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=dones, last_cost_values=last_cost_values)

        callback.update_locals(locals())
        callback.on_rollout_end()

        return True

    def _finish_values(
        self,
        rollout_buffer: CostRolloutBuffer,
        last_obs: np.ndarray,
        truncations: list[tuple[int, int, np.ndarray]],
        terminations: Sequence[tuple[int, int, np.ndarray]] = (),
    ) -> tuple[th.Tensor, np.ndarray]:
        """
        One batched pass of both critics over the rollout's observations, the observations after its last step and
        the final observations of truncated episodes: stores the values, bootstraps the truncated rewards and
        costs, charges terminated episodes' costs as ``termination_cost`` says, and returns the values of the
        observations after the last step.
        """
        obs_shape = rollout_buffer.obs_shape
        stored = rollout_buffer.observations.reshape(-1, *obs_shape)
        batch = [stored, np.asarray(last_obs).reshape(-1, *obs_shape)]
        batch += [np.asarray(final_obs).reshape(-1, *obs_shape) for _, _, final_obs in truncations]
        if self.termination_cost == "bootstrap":
            batch += [np.asarray(final_obs).reshape(-1, *obs_shape) for _, _, final_obs in terminations]
        observations = np.concatenate(batch).astype(stored.dtype, copy=False)
        with th.no_grad():
            chunks = [
                self.policy.predict_all_values(obs_as_tensor(observations[start : start + VALUE_CHUNK], self.device))
                for start in range(0, len(observations), VALUE_CHUNK)
            ]
        values = th.cat([chunk[0] for chunk in chunks]).flatten().cpu().numpy()
        cost_values = th.cat([chunk[1] for chunk in chunks]).cpu().numpy()

        n_stored, n_envs = len(stored), self.n_envs
        rollout_buffer.values[:] = values[:n_stored].reshape(rollout_buffer.values.shape)
        rollout_buffer.set_cost_values(cost_values[:n_stored])
        for offset, (step, env_idx, _) in enumerate(truncations):
            final = n_stored + n_envs + offset
            rollout_buffer.rewards[step, env_idx] += self.gamma * values[final]
            rollout_buffer.costs[step, env_idx] += self.cost_gamma * cost_values[final]
        first_termination = n_stored + n_envs + len(truncations)
        for offset, (step, env_idx, _) in enumerate(terminations):
            if self.termination_cost == "bootstrap":
                rollout_buffer.costs[step, env_idx] += self.cost_gamma * cost_values[first_termination + offset]
            else:  # an absorbing state costing termination_cost (or the per-step budget) per step, for ever
                per_step = self.cost_budget if self.termination_cost == "budget" else float(self.termination_cost)
                rollout_buffer.costs[step, env_idx] += self.cost_gamma * per_step / (1.0 - self.cost_gamma)
        last = slice(n_stored, n_stored + n_envs)
        return th.as_tensor(values[last]), cost_values[last]

    def _constraint_values(self) -> np.ndarray | None:
        """``J_c`` per constraint in the units of the budget, or None when there is nothing to judge yet."""
        if self.budget_statistic == "step":
            return self._rollout_mean_step_cost
        if not self._episode_costs_since_update:
            return None
        values = np.mean(self._episode_costs_since_update, axis=0)
        self._episode_costs_since_update = []
        return values

    def _record_per_constraint(self, key: str, values: np.ndarray) -> None:
        if self.n_costs == 1:
            self.logger.record(key, float(values[0]))
        else:
            for idx, value in enumerate(values):
                self.logger.record(f"{key}_{idx}", float(value))

    @without_distribution_validation
    def train(self) -> None:
        """
        Update the multipliers on the latest constraint estimate, then the policy, reward critic and cost critic
        on the rollout buffer. torch's distribution argument checks are off here (they change no value); the losses
        of the minibatches applied are checked for NaN at the end instead.
        """
        assert self.lagrange_multiplier is not None
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        if self.clip_range_vf is not None:
            clip_range_vf = self.clip_range_vf(self._current_progress_remaining)  # type: ignore[operator]

        constraint_values = self._constraint_values()
        if constraint_values is not None:
            self.lagrange_multiplier.update(constraint_values)
            self._record_per_constraint("train/constraint_value", constraint_values)
        multipliers = th.as_tensor(self.lagrange_multiplier.value, dtype=th.float32, device=self.device)
        advantage_scale = 1.0 + multipliers.sum()  # fixed for the whole update: computed once, not per minibatch
        actor_critic_params = self.policy.actor_critic_parameters()
        cost_critic_params = self.policy.cost_critic_parameters()
        every_param = actor_critic_params + cost_critic_params
        applied_losses_finite = th.ones((), dtype=th.bool, device=self.device)  # a tensor: no sync per minibatch

        entropy_losses, pg_losses, value_losses, cost_value_losses, clip_fractions = [], [], [], [], []
        continue_training = True
        for epoch in range(self.n_epochs):
            approx_kl_divs = []
            for rollout_data in self.rollout_buffer.get(self.batch_size):
                actions = rollout_data.actions
                if isinstance(self.action_space, spaces.Discrete):
                    actions = rollout_data.actions.long().flatten()

                values, log_prob, entropy = self.policy.evaluate_actions(rollout_data.observations, actions)
                values = values.flatten()
                # Lagrangian advantage; equal to PPO's when every multiplier is 0
                advantages = (
                    rollout_data.advantages - (rollout_data.cost_advantages * multipliers).sum(dim=1)
                ) / advantage_scale
                if self.normalize_advantage and len(advantages) > 1:
                    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

                ratio = th.exp(log_prob - rollout_data.old_log_prob)
                policy_loss_1 = advantages * ratio
                policy_loss_2 = advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)
                policy_loss = -th.min(policy_loss_1, policy_loss_2).mean()
                # Statistics stay tensors until the end of train(): no synchronising .item() per minibatch
                pg_losses.append(policy_loss.detach())
                clip_fractions.append(th.mean((th.abs(ratio - 1) > clip_range).float()))

                cost_values = self.policy.predict_cost_values(rollout_data.observations)
                if self.clip_range_vf is None:
                    values_pred, cost_values_pred = values, cost_values
                else:
                    values_pred = rollout_data.old_values + th.clamp(
                        values - rollout_data.old_values, -clip_range_vf, clip_range_vf
                    )
                    cost_values_pred = rollout_data.old_cost_values + th.clamp(
                        cost_values - rollout_data.old_cost_values, -clip_range_vf, clip_range_vf
                    )
                value_loss = F.mse_loss(rollout_data.returns, values_pred)
                value_losses.append(value_loss.detach())
                cost_value_loss = F.mse_loss(rollout_data.cost_returns, cost_values_pred)
                cost_value_losses.append(cost_value_loss.detach())

                entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
                entropy_losses.append(entropy_loss.detach())

                loss = (
                    policy_loss
                    + self.ent_coef * entropy_loss
                    + self.vf_coef * value_loss
                    + self.cost_vf_coef * cost_value_loss
                )

                with th.no_grad():
                    log_ratio = log_prob - rollout_data.old_log_prob
                    approx_kl_div = th.mean((th.exp(log_ratio) - 1) - log_ratio)
                    approx_kl_divs.append(approx_kl_div)

                if self.target_kl is not None and approx_kl_div.item() > 1.5 * self.target_kl:
                    continue_training = False
                    if self.verbose >= 1:
                        print(f"Early stopping at step {epoch} due to reaching max kl: {approx_kl_div:.2f}")
                    break

                # What the optimiser's zero_grad() does (set_to_none), without its per-call overhead
                for param in every_param:
                    param.grad = None
                applied_losses_finite &= th.isfinite(loss)
                loss.backward()
                # Clip separately: the cost critic's gradients must not rescale the actor-critic's
                clip_grad_norms_([actor_critic_params, cost_critic_params], self.max_grad_norm)
                self.policy.optimizer.step()  # the actor, the reward critic and the cost critic

            self._n_updates += 1
            if not continue_training:
                break

        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
        cost_explained_var = explained_variance(
            self.rollout_buffer.cost_values.flatten(), self.rollout_buffer.cost_returns.flatten()
        )

        losses = {
            "entropy_loss": _mean(entropy_losses),
            "policy_gradient_loss": _mean(pg_losses),
            "value_loss": _mean(value_losses),
            "cost_value_loss": _mean(cost_value_losses),
        }
        if not applied_losses_finite:  # (a minibatch that target_kl stopped before its step does not count)
            raise diverged_error(f"The losses of the update at step {self.num_timesteps} (means: {losses})")
        for key, value in losses.items():
            self.logger.record(f"train/{key}", value)
        self.logger.record("train/approx_kl", _mean(approx_kl_divs))
        self.logger.record("train/clip_fraction", _mean(clip_fractions))
        self.logger.record("train/loss", loss.item())
        self.logger.record("train/explained_variance", explained_var)
        self.logger.record("train/cost_explained_variance", cost_explained_var)
        self._record_per_constraint("train/lagrange_multiplier", self.lagrange_multiplier.value)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        if self.clip_range_vf is not None:
            self.logger.record("train/clip_range_vf", clip_range_vf)

    def dump_logs(self, iteration: int = 0) -> None:
        if self.ep_cost_buffer:
            self._record_per_constraint("rollout/ep_cost_mean", np.mean(self.ep_cost_buffer, axis=0))
        super().dump_logs(iteration)

    def learn(
        self: SelfPPOLagrangian,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "PPOLagrangian",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfPPOLagrangian:
        check_total_timesteps(total_timesteps)
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )


def check_total_timesteps(total_timesteps: Any) -> None:
    """
    Fail clearly unless ``total_timesteps`` is a finite number >= 0 (SB3 would silently train nothing).

    :param total_timesteps: The argument of ``learn``
    """
    if isinstance(total_timesteps, bool) or not isinstance(total_timesteps, (int, float, np.integer, np.floating)):
        raise TypeError(f"`total_timesteps` must be a number of steps, got {total_timesteps!r}.")
    if not np.isfinite(total_timesteps) or total_timesteps < 0:
        raise ValueError(f"`total_timesteps` must be a finite number >= 0, got {total_timesteps!r}.")


def merge_cost_optimizer(params: dict[str, Any]) -> dict[str, Any]:
    """
    The state dicts of a model saved when its cost critic had an optimizer of its own (``policy.cost_optimizer``),
    rewritten for one optimizer: the cost critic's parameters and their states follow the actor-critic's, in one group
    (the order :class:`~sb3_icrl.common.policies.CostActorCriticPolicy` builds). Other dicts are returned as they are.

    :param params: State dicts by object name, as ``save`` writes them
    :return: The same, with ``policy.optimizer`` covering every parameter and no ``policy.cost_optimizer``
    """
    if "policy.cost_optimizer" not in params:
        return params
    if "policy.optimizer" not in params:
        raise ValueError(
            "The parameters hold the cost critic's optimizer state ('policy.cost_optimizer') without the actor-critic's "
            "('policy.optimizer'), and the two are one optimizer now: pass both, or neither."
        )
    params = dict(params)  # the caller's dict is left as it was
    actor_critic, cost_critic = params["policy.optimizer"], params.pop("policy.cost_optimizer")
    if len(actor_critic["param_groups"]) != 1 or len(cost_critic["param_groups"]) != 1:
        raise ValueError(
            "Cannot merge the saved optimizers of the actor-critic and the cost critic: each should have one parameter "
            f"group, they have {len(actor_critic['param_groups'])} and {len(cost_critic['param_groups'])}. "
            "Load the policy weights alone with `model.policy.load_state_dict(...)`."
        )
    n_actor_critic = len(actor_critic["param_groups"][0]["params"])
    n_cost_critic = len(cost_critic["param_groups"][0]["params"])
    state = {**actor_critic["state"], **{n_actor_critic + index: value for index, value in cost_critic["state"].items()}}
    group = {**actor_critic["param_groups"][0], "params": list(range(n_actor_critic + n_cost_critic))}
    params["policy.optimizer"] = {"state": state, "param_groups": [group]}
    return params


class _DeferredCosts:
    """The raw observations, actions and dones of one rollout, kept for its cost function's one batched call."""

    def __init__(self, n_steps: int):
        self.n_steps = n_steps
        self.obs: np.ndarray | None = None
        self.actions: np.ndarray | None = None
        self.dones: np.ndarray | None = None

    def add_pair(self, step: int, obs: np.ndarray, actions: np.ndarray) -> None:
        obs, actions = np.asarray(obs), np.asarray(actions)
        if self.obs is None or self.actions is None:  # shapes and dtypes as the env and the policy give them
            self.obs = np.empty((self.n_steps, *obs.shape), dtype=obs.dtype)
            self.actions = np.empty((self.n_steps, *actions.shape), dtype=actions.dtype)
            self.dones = np.zeros((self.n_steps, len(obs)), dtype=bool)
        self.obs[step] = obs
        self.actions[step] = actions

    def add_dones(self, step: int, dones: np.ndarray) -> None:
        assert self.dones is not None, "add_pair() first"
        self.dones[step] = dones

    def pairs(self, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """The pairs of the first ``n_steps`` steps, flattened step-major: ``(n_steps * n_envs, ...)``."""
        assert self.obs is not None and self.actions is not None
        obs, actions = self.obs[:n_steps], self.actions[:n_steps]
        return obs.reshape(-1, *obs.shape[2:]), actions.reshape(-1, *actions.shape[2:])


def _batch_costs(costs: Any, n_steps: int, n_envs: int, n_costs: int, signed: bool = False) -> np.ndarray:
    """A cost function's costs of a rollout's pairs, checked, as ``(n_steps, n_envs, n_costs)`` float32."""
    try:
        array = as_cost_array(costs, n_steps * n_envs, n_costs, "cost_fn", signed)
    except CostError as error:
        raise CostError(
            f"{error} (cost_fn judged the {n_steps} steps x {n_envs} env(s) of a rollout in one call: it must return "
            "one cost, or one per constraint, for each pair it is given)"
        ) from error
    return array.reshape(n_steps, n_envs, n_costs)


def _mean(values: list[th.Tensor]) -> float:
    """The mean of a list of scalar tensors as a float (NaN for an empty list, as ``np.mean``)."""
    return float(th.stack(values).double().mean()) if values else float("nan")


def _env_name(env: VecEnv, idx: int) -> str:
    """The env id of sub-env ``idx`` for error messages (falls back to the env's class name)."""
    try:
        spec = env.get_attr("spec", indices=[idx])[0]
        if spec is not None and getattr(spec, "id", None):
            return str(spec.id)
        return type(env.get_attr("unwrapped", indices=[idx])[0]).__name__
    except (AttributeError, IndexError):
        return f"env {idx}"


def _check_termination_cost(termination_cost: str | float, cost_gamma: float) -> str | float:
    """The ``termination_cost`` argument, checked: ``"zero"``, ``"bootstrap"``, ``"budget"`` or a finite float >= 0."""
    if isinstance(termination_cost, str):
        if termination_cost not in TERMINATION_COSTS:
            raise ValueError(
                f"Unknown `termination_cost` {termination_cost!r}: use one of {TERMINATION_COSTS} or a float >= 0 "
                "(the cost per step of the absorbing state a terminated episode enters)."
            )
    elif isinstance(termination_cost, bool) or not isinstance(termination_cost, (int, float)):
        raise TypeError(f"`termination_cost` must be 'zero', 'bootstrap', 'budget' or a float >= 0, got {termination_cost!r}.")
    elif not np.isfinite(termination_cost) or termination_cost < 0:
        raise ValueError(f"`termination_cost` as a float is a cost per step: finite and >= 0, got {termination_cost!r}.")
    if termination_cost in ("zero", "bootstrap"):
        return termination_cost
    if cost_gamma >= 1.0:
        raise ValueError(
            f"termination_cost={termination_cost!r} charges an absorbing state for ever, which needs cost_gamma < 1 "
            f"(got {cost_gamma}): lower cost_gamma or use termination_cost='bootstrap'."
        )
    return termination_cost if isinstance(termination_cost, str) else float(termination_cost)
