"""A replay buffer that also keeps each step's cost, and the raw pairs a learned cost is computed from."""

from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

from sb3_icrl.common.costs import costs_from_infos


class CostReplayBufferSamples(NamedTuple):
    """
    SB3's ``ReplayBufferSamples`` fields, then the stored costs and the raw pairs of the same transitions.

    :param raw_observations: Observations as the env returned them (before ``VecNormalize``), numpy
    :param raw_actions: The actions as stored (scaled to ``[-1, 1]`` for a Box space), numpy
    """

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    costs: th.Tensor  # (batch, 1)
    raw_observations: np.ndarray
    raw_actions: np.ndarray
    discounts: th.Tensor | None = None


class CostReplayBuffer(ReplayBuffer):
    """
    SB3's ``ReplayBuffer``, storing ``info[cost_info_key]`` of each step too (0 when ``cost_info_key`` is ``None``:
    the learner computes the cost itself, on sampled batches). Samples also carry the raw observations and actions,
    which a learned cost (e.g. ICRL's, which changes during training) is computed from at update time.

    :param cost_info_key: The info key of the per-step cost (``None``: store no cost)
    :param args: The arguments of SB3's ``ReplayBuffer``
    :param kwargs: The keyword arguments of SB3's ``ReplayBuffer``
    """

    def __init__(self, *args: Any, cost_info_key: str | None = "cost", **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.cost_info_key = cost_info_key
        self.costs = np.zeros((self.buffer_size, self.n_envs), dtype=np.float32)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        if self.cost_info_key is None:
            self.costs[self.pos] = 0.0
        else:
            names = [f"index {env_idx}" for env_idx in range(len(infos))]
            self.costs[self.pos] = costs_from_infos(infos, self.cost_info_key, 1, names)[:, 0]
        super().add(obs, next_obs, action, reward, done, infos)

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> CostReplayBufferSamples:  # type: ignore[override]
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        if self.optimize_memory_usage:
            next_obs = self.observations[(batch_inds + 1) % self.buffer_size, env_indices, :]
        else:
            next_obs = self.next_observations[batch_inds, env_indices, :]
        raw_obs = self.observations[batch_inds, env_indices, :]
        actions = self.actions[batch_inds, env_indices, :]
        to_torch = self.to_torch
        return CostReplayBufferSamples(
            observations=to_torch(self._normalize_obs(raw_obs, env)),  # type: ignore[arg-type]
            actions=to_torch(actions),
            next_observations=to_torch(self._normalize_obs(next_obs, env)),  # type: ignore[arg-type]
            # Only dones that are not due to timeouts
            dones=to_torch(
                (self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])).reshape(-1, 1)
            ),
            rewards=to_torch(self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env)),
            costs=to_torch(self.costs[batch_inds, env_indices].reshape(-1, 1)),
            raw_observations=raw_obs,
            raw_actions=actions,
        )
