"""Rollout buffer with per-step costs, cost values and cost GAE, for Lagrangian on-policy algorithms."""

from collections.abc import Generator
from typing import NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import VecNormalize

#: SB3 RolloutBuffer's arrays that are flattened for sampling
SAMPLED_FIELDS = ("observations", "actions", "values", "log_probs", "advantages", "returns")


class CostRolloutBufferSamples(NamedTuple):
    observations: th.Tensor
    actions: th.Tensor
    old_values: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    returns: th.Tensor
    old_cost_values: th.Tensor  # (batch, n_costs)
    cost_advantages: th.Tensor  # (batch, n_costs)
    cost_returns: th.Tensor  # (batch, n_costs)


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    episode_starts: np.ndarray,
    last_values: np.ndarray,
    dones: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> np.ndarray:
    """
    GAE(lambda) advantages, exactly as SB3's ``RolloutBuffer.compute_returns_and_advantage``, for signals with
    trailing dimensions (e.g. one column per constraint).

    :param rewards: ``(n_steps, n_envs, ...)`` per-step signal (reward or cost)
    :param values: ``(n_steps, n_envs, ...)`` value estimates of the same signal
    :param episode_starts: ``(n_steps, n_envs)``
    :param last_values: ``(n_envs, ...)`` values of the observation after the last step
    :param dones: ``(n_envs,)`` whether the last step ended an episode
    :param gamma: Discount factor
    :param gae_lambda: GAE lambda
    :return: Advantages, same shape as ``rewards``
    """
    trailing = (1,) * (rewards.ndim - 2)
    advantages = np.zeros_like(rewards, dtype=np.float32)
    last_gae_lam = np.zeros_like(last_values, dtype=np.float32)
    n_steps = rewards.shape[0]
    for step in reversed(range(n_steps)):
        if step == n_steps - 1:
            next_non_terminal = 1.0 - dones.astype(np.float32)
            next_values = last_values
        else:
            next_non_terminal = 1.0 - episode_starts[step + 1]
            next_values = values[step + 1]
        next_non_terminal = next_non_terminal.reshape(-1, *trailing)
        delta = rewards[step] + gamma * next_values * next_non_terminal - values[step]
        last_gae_lam = delta + gamma * gae_lambda * next_non_terminal * last_gae_lam
        advantages[step] = last_gae_lam
    return advantages


class CostRolloutBuffer(RolloutBuffer):
    """
    SB3's ``RolloutBuffer`` plus costs, cost-critic values and cost advantages (one column per constraint).

    Cost values need not be known while collecting: the algorithm sets them for the whole rollout at once with
    :meth:`set_cost_values` (one batched forward pass), then calls :meth:`compute_returns_and_advantage`.

    Like SB3's ``rewards``, ``costs`` keeps its ``(n_steps, n_envs, n_costs)`` layout after sampling, while the arrays
    that are sampled (observations, values, advantages, returns and their cost twins) are flattened env by env.
    At time-limit truncations ``costs`` holds the cost plus ``cost_gamma`` times the cost value of the final
    observation, as ``rewards`` does.

    :param buffer_size: Number of steps per env
    :param observation_space: Observation space
    :param action_space: Action space
    :param device: PyTorch device
    :param gae_lambda: GAE lambda of the reward advantages
    :param gamma: Discount factor of the reward
    :param n_envs: Number of parallel environments
    :param n_costs: Number of constraints
    :param cost_gamma: Discount factor of the costs (default: ``gamma``)
    :param cost_gae_lambda: GAE lambda of the cost advantages (default: ``gae_lambda``)
    """

    costs: np.ndarray
    cost_values: np.ndarray
    cost_advantages: np.ndarray
    cost_returns: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        gae_lambda: float = 1,
        gamma: float = 0.99,
        n_envs: int = 1,
        n_costs: int = 1,
        cost_gamma: float | None = None,
        cost_gae_lambda: float | None = None,
    ):
        if isinstance(observation_space, spaces.Dict):
            raise NotImplementedError("CostRolloutBuffer does not support Dict observation spaces yet: flatten them first.")
        self.n_costs = n_costs
        self.cost_gamma = gamma if cost_gamma is None else cost_gamma
        self.cost_gae_lambda = gae_lambda if cost_gae_lambda is None else cost_gae_lambda
        super().__init__(buffer_size, observation_space, action_space, device, gae_lambda, gamma, n_envs)

    def reset(self) -> None:
        cost_shape = (self.buffer_size, self.n_envs, self.n_costs)
        self.costs = np.zeros(cost_shape, dtype=np.float32)
        self.cost_values = np.zeros(cost_shape, dtype=np.float32)
        self.cost_advantages = np.zeros(cost_shape, dtype=np.float32)
        self.cost_returns = np.zeros(cost_shape, dtype=np.float32)
        self._sampling_tensors: tuple[th.Tensor, th.Tensor, list[int]] | None = None
        super().reset()

    def add_costs(self, costs: np.ndarray) -> None:
        """
        Store the costs of the step just added with ``add`` (call it right after ``add``).

        :param costs: ``(n_envs, n_costs)``
        """
        self.costs[self.pos - 1] = costs

    def set_cost_values(self, cost_values: np.ndarray) -> None:
        """
        :param cost_values: Cost-critic values of every stored observation, ``(buffer_size, n_envs, n_costs)``
        """
        self.cost_values[:] = cost_values.reshape(self.cost_values.shape)

    def compute_returns_and_advantage(
        self, last_values: th.Tensor, dones: np.ndarray, last_cost_values: th.Tensor | np.ndarray | None = None
    ) -> None:
        """
        Reward and cost GAE(lambda) advantages and TD(lambda) returns.

        :param last_values: Reward values of the observation after the last step, ``(n_envs,)``
        :param dones: Whether the last step ended an episode, ``(n_envs,)``
        :param last_cost_values: Cost values of the observation after the last step, ``(n_envs, n_costs)``
        """
        super().compute_returns_and_advantage(last_values, dones)
        if last_cost_values is None:
            raise ValueError("CostRolloutBuffer needs `last_cost_values` to compute cost advantages.")
        if isinstance(last_cost_values, th.Tensor):
            last_cost_values = last_cost_values.detach().cpu().numpy()
        self.cost_advantages = compute_gae(
            self.costs,
            self.cost_values,
            self.episode_starts,
            np.asarray(last_cost_values, dtype=np.float32).reshape(self.n_envs, self.n_costs),
            dones,
            self.cost_gamma,
            self.cost_gae_lambda,
        )
        self.cost_returns = self.cost_advantages + self.cost_values

    def get(self, batch_size: int | None = None) -> Generator[CostRolloutBufferSamples, None, None]:  # type: ignore[override]
        assert self.full, "The buffer must be full before sampling from it"
        # Same single permutation as SB3's RolloutBuffer, so runs are reproducible against PPO
        indices = np.random.permutation(self.buffer_size * self.n_envs)
        if not self.generator_ready:
            for tensor in (*SAMPLED_FIELDS, "cost_values", "cost_advantages", "cost_returns"):
                self.__dict__[tensor] = self.swap_and_flatten(self.__dict__[tensor])
            self.generator_ready = True

        if batch_size is None:
            batch_size = self.buffer_size * self.n_envs

        observations, packed, widths = self._tensors_for_sampling()
        all_indices = th.as_tensor(indices, device=packed.device)
        start_idx = 0
        while start_idx < self.buffer_size * self.n_envs:
            batch_indices = all_indices[start_idx : start_idx + batch_size]
            # One gather for the eight float fields instead of eight numpy copies turned into tensors; a field's rows
            # come out contiguous (strided fields would change the rounding of the losses' reductions)
            fields = [field.T.contiguous() for field in packed.index_select(1, batch_indices).split(widths, dim=0)]
            yield CostRolloutBufferSamples(
                observations[batch_indices],
                fields[0],
                *(field.flatten() for field in fields[1:5]),
                *fields[5:],
            )
            start_idx += batch_size

    def _tensors_for_sampling(self) -> tuple[th.Tensor, th.Tensor, list[int]]:
        """
        The flattened fields as tensors on the device, made once per rollout (every epoch samples from them):
        observations as stored, and the other fields stacked in one float32 tensor, one row per feature (``(width,
        n_samples)``), with each field's width.
        """
        if self._sampling_tensors is None:
            n_samples = self.buffer_size * self.n_envs
            columns = [
                self.actions,
                self.values,
                self.log_probs,
                self.advantages,
                self.returns,
                self.cost_values,
                self.cost_advantages,
                self.cost_returns,
            ]
            columns = [np.asarray(column, dtype=np.float32).reshape(n_samples, -1) for column in columns]
            packed = th.as_tensor(np.ascontiguousarray(np.concatenate(columns, axis=1).T), device=self.device)
            observations = th.as_tensor(self.observations, device=self.device)
            self._sampling_tensors = (observations, packed, [column.shape[1] for column in columns])
        return self._sampling_tensors

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> CostRolloutBufferSamples:
        data = (
            self.observations[batch_inds],
            self.actions[batch_inds].astype(np.float32, copy=False),
            self.values[batch_inds].flatten(),
            self.log_probs[batch_inds].flatten(),
            self.advantages[batch_inds].flatten(),
            self.returns[batch_inds].flatten(),
            self.cost_values[batch_inds],
            self.cost_advantages[batch_inds],
            self.cost_returns[batch_inds],
        )
        return CostRolloutBufferSamples(*tuple(map(self.to_torch, data)))
