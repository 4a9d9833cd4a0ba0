"""SAC-Lagrangian: SAC with a cost critic and a Lagrange multiplier, the off-policy forward solver."""

import io
import pathlib
from collections import deque
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy, ContinuousCritic
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F

from sb3_icrl.common.costs import CostFn, costs_from_infos
from sb3_icrl.common.lagrange import LagrangeMultiplier, make_lagrange_multiplier
from sb3_icrl.common.saved import CheckedLoadMixin, library_algorithm
from sb3_icrl.sac_lagrangian.buffers import CostReplayBuffer, CostReplayBufferSamples
from sb3_icrl.sac_lagrangian.policies import CostSACPolicy, MlpPolicy

#: What the multiplier is updated on (see :class:`SACLagrangian`)
SAC_BUDGET_STATISTICS = ("episode", "critic")


class SACLagrangian(CheckedLoadMixin, SAC):
    """
    SAC-Lagrangian: SAC whose actor maximises ``Q_r(s, a) - lambda * Q_c(s, a)`` (plus the entropy term), with a cost
    critic ``Q_c`` trained by TD on the per-step cost (no entropy term in its target) and a multiplier
    ``lambda >= 0`` updated on ``J_c - budget``. With ``lambda`` held at 0 every update is exactly SAC's.

    The per-step cost is read from ``info[cost_info_key]`` and stored in the replay buffer
    (:class:`~sb3_icrl.sac_lagrangian.CostReplayBuffer`), or computed by ``cost_fn(observations, actions)`` on each
    sampled batch at update time (e.g. a learned cost that changes during training: old transitions are judged by
    the current model). ``cost_fn`` sees the observations the env returned (before ``VecNormalize``) and the actions
    as sent to the env.

    :param policy: The policy model (``"MlpPolicy"``: :class:`~sb3_icrl.sac_lagrangian.CostSACPolicy`)
    :param env: The environment (a gymnasium env, a VecEnv or a registered id); Box actions
    :param cost_budget: The budget ``d`` on ``J_c``, in the units of ``budget_statistic``
    :param budget_statistic: ``"episode"``: ``J_c`` is the mean undiscounted cost of the episodes that ended since the
        last multiplier update (no update while none ended; needs the env's costs, not ``cost_fn``); ``"critic"``: the
        mean of ``Q_c(s, pi(s))`` on the batch of the last gradient step, a discounted cost-to-go (without a cost
        critic, ``separate_cost_critic=False``, the multiplier then keeps its value)
    :param cost_gamma: Discount factor of the cost critic (default: ``gamma``)
    :param lagrange_update: ``"gradient"`` or ``"pid"`` (see :mod:`sb3_icrl.common.lagrange`)
    :param lagrange_kwargs: Arguments of the multiplier (``init``, ``lr``, ``optimizer``, ``upper_bound`` for gradient
        ascent; ``kp``, ``ki``, ``kd``... for PID). ``{"init": x, "lr": 0.0}`` holds it at ``x``
    :param lagrange_update_interval: Calls of ``train`` (one per ``train_freq``) between multiplier updates
    :param separate_cost_critic: ``True``: the cost has its own critic, weighted by ``lambda`` in the actor loss.
        ``False``: no cost critic; the reward critics learn ``r - lambda * c`` (a penalty folded into the reward)
    :param cost_fn: Optional ``cost_fn(observations, actions) -> costs`` replacing ``info[cost_info_key]``, called on
        each sampled batch; not saved with the model (set it again after ``load`` with :meth:`set_cost_fn`)
    :param cost_info_key: The info key holding the per-step cost
    :param kwargs: The other arguments of SB3's ``SAC`` (``learning_rate``, ``buffer_size``, ``batch_size``,
        ``learning_starts``, ``ent_coef``, ``policy_kwargs``, ``seed``...), except ``n_steps`` > 1 and
        ``optimize_memory_usage``
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": MlpPolicy}
    policy: CostSACPolicy  # type: ignore[assignment]
    replay_buffer: CostReplayBuffer  # type: ignore[assignment]

    def __init__(
        self,
        policy: str | type[CostSACPolicy],
        env: GymEnv | str,
        cost_budget: float = 0.0,
        budget_statistic: str = "episode",
        cost_gamma: float | None = None,
        lagrange_update: str = "gradient",
        lagrange_kwargs: dict[str, Any] | None = None,
        lagrange_update_interval: int = 1,
        separate_cost_critic: bool = True,
        cost_fn: CostFn | None = None,
        cost_info_key: str = "cost",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        if kwargs.get("n_steps", 1) != 1:
            raise ValueError(
                f"{type(self).__name__} learns from one-step transitions: `n_steps` must be 1, got {kwargs['n_steps']}."
            )
        if kwargs.get("optimize_memory_usage", False):
            raise ValueError(f"{type(self).__name__} does not support `optimize_memory_usage=True`: leave it False.")
        replay_buffer_class = kwargs.get("replay_buffer_class")
        if replay_buffer_class is not None and not (
            isinstance(replay_buffer_class, type) and issubclass(replay_buffer_class, CostReplayBuffer)
        ):
            raise TypeError(
                "`replay_buffer_class` must be a CostReplayBuffer (sub)class, which stores the costs; got "
                f"{replay_buffer_class!r}."
            )
        kwargs["replay_buffer_class"] = replay_buffer_class or CostReplayBuffer
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        try:
            budget = float(cost_budget)
        except (TypeError, ValueError):
            budget = float("nan")
        if not (np.isfinite(budget) and budget >= 0):
            raise ValueError(f"`cost_budget` must be a finite float >= 0, got {cost_budget!r}.")
        if budget_statistic not in SAC_BUDGET_STATISTICS:
            raise ValueError(f"Unknown `budget_statistic` {budget_statistic!r}: use one of {SAC_BUDGET_STATISTICS}.")
        if cost_gamma is not None and not 0.0 <= cost_gamma <= 1.0:
            raise ValueError(f"`cost_gamma` must be in [0, 1], got {cost_gamma!r}.")
        if lagrange_update_interval < 1:
            raise ValueError(f"`lagrange_update_interval` must be >= 1, got {lagrange_update_interval}.")
        self.cost_budget = budget
        self.budget_statistic = budget_statistic
        self.cost_gamma = self.gamma if cost_gamma is None else float(cost_gamma)
        self.lagrange_update = lagrange_update
        self.lagrange_kwargs = dict(lagrange_kwargs or {})
        self.lagrange_update_interval = int(lagrange_update_interval)
        self.separate_cost_critic = bool(separate_cost_critic)
        self.cost_info_key = cost_info_key
        self.cost_fn: CostFn | None = None
        self.set_cost_fn(cost_fn)
        self.lagrange_multiplier: LagrangeMultiplier | None = None
        self.ep_cost_buffer: deque[float] | None = None
        self._current_episode_costs: np.ndarray | None = None
        self._episode_costs_since_update: list[float] = []
        self._n_train_calls = 0
        # Saved in the zip: ``load`` of another algorithm's model fails clearly
        self.sb3_icrl_algorithm = library_algorithm(type(self))
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up

    def _setup_model(self) -> None:
        if not (isinstance(self.policy_class, type) and issubclass(self.policy_class, CostSACPolicy)):
            raise TypeError(
                f"{type(self).__name__} needs a CostSACPolicy (it has the cost critic), got {self.policy_class!r}: use "
                "'MlpPolicy' or a CostSACPolicy subclass."
            )
        if self.budget_statistic == "episode" and self.cost_fn is not None:
            raise ValueError(
                "budget_statistic='episode' counts the env's costs as episodes end; a `cost_fn` is computed on sampled "
                "batches only: use budget_statistic='critic'."
            )
        self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, "cost_info_key": self._stored_cost_key()}
        super()._setup_model()
        if self.lagrange_multiplier is None:  # ``load`` restores it before calling _setup_model: keep it
            self.lagrange_multiplier = make_lagrange_multiplier(
                self.lagrange_update, self.cost_budget, 1, **self.lagrange_kwargs
            )

    def _stored_cost_key(self) -> str | None:
        """The info key whose cost the replay buffer stores (``None``: the cost is computed on sampled batches)."""
        return None if self.cost_fn is not None else self.cost_info_key

    def _create_aliases(self) -> None:
        super()._create_aliases()
        self.cost_critic = self.policy.cost_critic
        self.cost_critic_target = self.policy.cost_critic_target

    def set_cost_fn(self, cost_fn: CostFn | None) -> None:
        """
        Compute the costs with ``cost_fn(observations, actions) -> costs`` on each sampled batch from now on
        (``None``: the costs stored from ``info[cost_info_key]``; the buffer then stores the costs of new steps only).

        :param cost_fn: The cost function
        """
        if cost_fn is not None and not callable(cost_fn):
            raise TypeError(f"`cost_fn` must be callable as cost_fn(observations, actions) -> costs, got {cost_fn!r}.")
        self.cost_fn = cost_fn
        if getattr(self, "replay_buffer", None) is not None:
            self.replay_buffer.cost_info_key = self._stored_cost_key()

    def load_replay_buffer(self, path: str | pathlib.Path | io.BufferedIOBase, truncate_last_traj: bool = True) -> None:
        """
        SB3's ``load_replay_buffer`` (e.g. the buffer of a checkpoint, to go on learning from its transitions), for a
        :class:`~sb3_icrl.sac_lagrangian.CostReplayBuffer`. The buffer stores the costs of new steps as this model's
        cost function asks (:meth:`set_cost_fn`: the function is not saved), whatever it stored when saved.

        :param path: The pickled buffer (``save_replay_buffer``)
        :param truncate_last_traj: See SB3's ``load_replay_buffer`` (``HerReplayBuffer`` only)
        :raises TypeError: When the file holds another kind of buffer (the model keeps its own)
        """
        previous = self.replay_buffer
        try:
            super().load_replay_buffer(path, truncate_last_traj)
            if not isinstance(self.replay_buffer, CostReplayBuffer):
                loaded = type(self.replay_buffer).__name__
                raise TypeError(f"{type(self).__name__} needs a CostReplayBuffer (with costs); {path} holds a {loaded}.")
        except BaseException:
            self.replay_buffer = previous  # a failed load leaves the model as it was
            raise
        self.replay_buffer.cost_info_key = self._stored_cost_key()

    def set_cost_budget(self, cost_budget: float) -> None:
        """
        Use a new budget from the next multiplier update on; the multiplier keeps its value.

        :param cost_budget: The budget, in the units of ``budget_statistic``
        """
        self.cost_budget = float(cost_budget)
        if self.lagrange_multiplier is not None:
            self.lagrange_multiplier.cost_budget = np.array([self.cost_budget])

    # ------------------------------------------------------------------ collection

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
            self._current_episode_costs = np.zeros(self.n_envs, dtype=np.float64)
            self._episode_costs_since_update = []
        return result

    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        super()._update_info_buffer(infos, dones)
        if self._stored_cost_key() is None or dones is None or self._current_episode_costs is None:
            return
        assert self.ep_cost_buffer is not None
        names = [f"index {env_idx}" for env_idx in range(len(infos))]
        self._current_episode_costs += costs_from_infos(infos, self.cost_info_key, 1, names)[:, 0]
        keep = self.budget_statistic == "episode"  # what the multiplier reads, and empties; "critic" reads none
        for env_idx in np.flatnonzero(dones):
            self.ep_cost_buffer.append(float(self._current_episode_costs[env_idx]))
            if keep:
                self._episode_costs_since_update.append(float(self._current_episode_costs[env_idx]))
            self._current_episode_costs[env_idx] = 0.0

    def _dump_logs(self) -> None:
        if self.ep_cost_buffer:
            self.logger.record("rollout/ep_cost_mean", float(np.mean(self.ep_cost_buffer)))
        super()._dump_logs()

    # ------------------------------------------------------------------ training

    def batch_costs(self, replay_data: CostReplayBufferSamples) -> th.Tensor:
        """
        The per-step costs of a sampled batch: ``cost_fn`` on its raw pairs, or the stored ones.

        :param replay_data: A batch of the replay buffer
        :return: Costs, ``(batch, 1)`` on the model's device
        """
        if self.cost_fn is None:
            return replay_data.costs
        actions = self.policy.unscale_action(replay_data.raw_actions)  # as sent to the env
        costs = np.asarray(self.cost_fn(replay_data.raw_observations, actions), dtype=np.float32).reshape(-1, 1)
        if costs.shape[0] != len(replay_data.raw_actions) or not np.all(np.isfinite(costs)):
            raise ValueError(
                f"`cost_fn` must return one finite cost per pair ({len(replay_data.raw_actions)}), got shape "
                f"{costs.shape}{' with non-finite values' if costs.shape[0] == len(replay_data.raw_actions) else ''}."
            )
        return th.as_tensor(costs, device=self.device)

    def _constraint_value(self, cost_values_pi: th.Tensor | None) -> float | None:
        """``J_c`` for the multiplier, or None when there is nothing to judge yet."""
        if self.budget_statistic == "critic":
            return None if cost_values_pi is None else float(cost_values_pi.mean().item())
        if not self._episode_costs_since_update:
            return None
        value = float(np.mean(self._episode_costs_since_update))
        self._episode_costs_since_update = []
        return value

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """
        SAC's update with a cost critic: per gradient step, the entropy coefficient, the reward critics, the cost
        critic and the actor (on ``Q_r - lambda Q_c``), then the targets; the multiplier every
        ``lagrange_update_interval`` calls, on ``budget_statistic``.
        """
        assert self.lagrange_multiplier is not None
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer, self.cost_critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)
        multiplier = float(self.lagrange_multiplier.value[0])

        logs: dict[str, list[float]] = {
            key: [] for key in ("ent_coef_loss", "ent_coef", "actor_loss", "critic_loss", "cost_critic_loss", "batch_cost")
        }
        cost_values_pi: th.Tensor | None = None
        for gradient_step in range(gradient_steps):
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            assert isinstance(replay_data, CostReplayBufferSamples)
            costs = self.batch_costs(replay_data)
            logs["batch_cost"].append(float(costs.mean().item()))
            rewards = replay_data.rewards if self.separate_cost_critic else replay_data.rewards - multiplier * costs

            if self.use_sde:
                self.actor.reset_noise()
            actions_pi, log_prob = self.actor.action_log_prob(replay_data.observations)
            log_prob = log_prob.reshape(-1, 1)

            ent_coef_loss = None
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                ent_coef = th.exp(self.log_ent_coef.detach())
                assert isinstance(self.target_entropy, float)
                ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                logs["ent_coef_loss"].append(ent_coef_loss.item())
            else:
                ent_coef = self.ent_coef_tensor
            logs["ent_coef"].append(ent_coef.item())
            if ent_coef_loss is not None and self.ent_coef_optimizer is not None:
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()

            with th.no_grad():
                next_actions, next_log_prob = self.actor.action_log_prob(replay_data.next_observations)
                next_q_values = th.cat(self.critic_target(replay_data.next_observations, next_actions), dim=1)
                next_q_values, _ = th.min(next_q_values, dim=1, keepdim=True)
                next_q_values = next_q_values - ent_coef * next_log_prob.reshape(-1, 1)
                target_q_values = rewards + (1 - replay_data.dones) * self.gamma * next_q_values

            logs["critic_loss"].append(self._fit_critic(self.critic, replay_data, target_q_values))

            if self.separate_cost_critic:
                with th.no_grad():
                    # The pessimistic cost-to-go: the largest of the target cost critics (no entropy term)
                    next_cost_values = th.cat(self.cost_critic_target(replay_data.next_observations, next_actions), dim=1)
                    next_cost_values, _ = th.max(next_cost_values, dim=1, keepdim=True)
                    target_cost_values = costs + (1 - replay_data.dones) * self.cost_gamma * next_cost_values
                logs["cost_critic_loss"].append(self._fit_critic(self.cost_critic, replay_data, target_cost_values))

            q_values_pi = th.cat(self.critic(replay_data.observations, actions_pi), dim=1)
            min_qf_pi, _ = th.min(q_values_pi, dim=1, keepdim=True)
            actor_loss_terms = ent_coef * log_prob - min_qf_pi
            if self.separate_cost_critic:
                cost_values_pi, _ = th.max(th.cat(self.cost_critic(replay_data.observations, actions_pi), dim=1), dim=1)
                actor_loss_terms = actor_loss_terms + multiplier * cost_values_pi.reshape(-1, 1)
                cost_values_pi = cost_values_pi.detach()
            actor_loss = actor_loss_terms.mean()
            logs["actor_loss"].append(actor_loss.item())
            self.actor.optimizer.zero_grad()
            actor_loss.backward()
            self.actor.optimizer.step()

            if gradient_step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)
                if self.separate_cost_critic:
                    polyak_update(self.cost_critic.parameters(), self.cost_critic_target.parameters(), self.tau)

        self._n_updates += gradient_steps
        self._n_train_calls += 1
        if self._n_train_calls % self.lagrange_update_interval == 0:
            constraint_value = self._constraint_value(cost_values_pi)
            if constraint_value is not None:
                self.lagrange_multiplier.update(np.array([constraint_value]))
                self.logger.record("train/constraint_value", constraint_value)

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", np.mean(logs["ent_coef"]))
        self.logger.record("train/actor_loss", np.mean(logs["actor_loss"]))
        self.logger.record("train/critic_loss", np.mean(logs["critic_loss"]))
        self.logger.record("train/batch_cost", np.mean(logs["batch_cost"]))
        self.logger.record("train/lagrange_multiplier", float(self.lagrange_multiplier.value[0]))
        if logs["cost_critic_loss"]:
            self.logger.record("train/cost_critic_loss", np.mean(logs["cost_critic_loss"]))
        if logs["ent_coef_loss"]:
            self.logger.record("train/ent_coef_loss", np.mean(logs["ent_coef_loss"]))

    @staticmethod
    def _fit_critic(critic: ContinuousCritic, replay_data: CostReplayBufferSamples, target_values: th.Tensor) -> float:
        """One gradient step of every head of ``critic`` towards ``target_values``; returns the loss."""
        current_values = critic(replay_data.observations, replay_data.actions)
        loss = 0.5 * sum(F.mse_loss(current, target_values) for current in current_values)
        assert isinstance(loss, th.Tensor) and critic.optimizer is not None
        critic.optimizer.zero_grad()
        loss.backward()
        critic.optimizer.step()
        return float(loss.item())

    # ------------------------------------------------------------------ saving

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "cost_critic.optimizer"], variables

    def _excluded_save_params(self) -> list[str]:
        # The cost function may be an arbitrary closure (e.g. over a learned constraint net saved elsewhere)
        return [*super()._excluded_save_params(), "cost_critic", "cost_critic_target", "cost_fn"]
