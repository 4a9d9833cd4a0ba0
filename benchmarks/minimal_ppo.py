"""
A minimal PPO in plain torch: the speed ceiling the library's learners are measured against.

The same algorithm as SB3's PPO at the same settings (clipped surrogate, GAE, value loss, advantage normalisation per
minibatch, gradient clipping, a diagonal Gaussian policy with a state-independent log-std, separate [64, 64] tanh
actor and critic), written as one flat loop with no callbacks, no rollout buffer object and no distribution objects.
It steps the same VecEnv stack as ``train.py`` (``create_env``), so that the gap to it is what the learner's own
machinery costs. Not a library class: only ``benchmarks/icrl_speed.py --algos minimal`` uses it.
"""

from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecEnv
from torch import nn


def _mlp(in_dim: int, out_dim: int, out_gain: float) -> nn.Sequential:
    layers = [nn.Linear(in_dim, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, out_dim)]
    for layer, gain in zip(layers[::2], (np.sqrt(2), np.sqrt(2), out_gain), strict=True):
        nn.init.orthogonal_(layer.weight, gain)  # type: ignore[arg-type]
        nn.init.zeros_(layer.bias)  # type: ignore[arg-type]
    return nn.Sequential(*layers)


class MinimalPPO:
    """
    PPO for a Box action space on a VecEnv, with ``learn(total_timesteps)`` and ``num_timesteps`` as in SB3.

    :param env: The VecEnv (as ``train.py`` builds it)
    :param n_steps: Steps per env per rollout
    :param batch_size: Minibatch size
    :param n_epochs: Passes over each rollout
    :param learning_rate: Adam learning rate
    :param gamma: Discount
    :param gae_lambda: GAE lambda
    :param clip_range: PPO's clipping
    :param ent_coef: Entropy weight
    :param vf_coef: Value loss weight
    :param max_grad_norm: Gradient norm clip
    :param seed: Torch seed
    """

    def __init__(
        self,
        env: VecEnv,
        n_steps: int = 2048,
        batch_size: int = 64,
        n_epochs: int = 10,
        learning_rate: float = 3e-4,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float = 0.2,
        ent_coef: float = 0.0,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        seed: int = 0,
        **_ignored: Any,
    ):
        th.manual_seed(seed)
        self.env, self.n_envs = env, env.num_envs
        self.n_steps, self.batch_size, self.n_epochs = n_steps, batch_size, n_epochs
        self.gamma, self.gae_lambda, self.clip_range = gamma, gae_lambda, clip_range
        self.ent_coef, self.vf_coef, self.max_grad_norm = ent_coef, vf_coef, max_grad_norm
        obs_dim = int(np.prod(env.observation_space.shape))  # type: ignore[arg-type]
        act_dim = int(np.prod(env.action_space.shape))  # type: ignore[arg-type]
        self.actor, self.critic = _mlp(obs_dim, act_dim, 0.01), _mlp(obs_dim, 1, 1.0)
        self.log_std = nn.Parameter(th.zeros(act_dim))
        self.parameters = [*self.actor.parameters(), *self.critic.parameters(), self.log_std]
        self.optimizer = th.optim.Adam(self.parameters, lr=learning_rate, eps=1e-5, fused=True)
        self.low, self.high = env.action_space.low, env.action_space.high  # type: ignore[attr-defined]
        self.num_timesteps = 0
        self.last_obs = th.as_tensor(env.reset(), dtype=th.float32)
        self.last_done = th.zeros(self.n_envs)

    def collect_rollouts(self) -> tuple[th.Tensor, ...]:
        """One rollout of ``n_steps`` per env: observations, actions, log-probabilities, returns and advantages."""
        shape = (self.n_steps, self.n_envs)
        obs = th.zeros((*shape, self.last_obs.shape[1]))
        actions = th.zeros((*shape, self.log_std.shape[0]))
        log_probs, rewards, dones = th.zeros(shape), th.zeros(shape), th.zeros(shape)
        with th.no_grad():
            for step in range(self.n_steps):
                obs[step], dones[step] = self.last_obs, self.last_done
                mean = self.actor(self.last_obs)
                action = mean + self.log_std.exp() * th.randn_like(mean)
                log_probs[step] = (-0.5 * ((action - mean) / self.log_std.exp()) ** 2 - self.log_std).sum(1)
                actions[step] = action
                next_obs, reward, done, infos = self.env.step(np.clip(action.numpy(), self.low, self.high))
                for env_index, info in enumerate(infos):  # bootstrap time-outs, as SB3 does
                    if done[env_index] and info.get("TimeLimit.truncated", False):
                        terminal = th.as_tensor(info["terminal_observation"], dtype=th.float32)
                        reward[env_index] += self.gamma * float(self.critic(terminal[None])[0, 0])
                rewards[step] = th.as_tensor(reward, dtype=th.float32)
                self.last_obs = th.as_tensor(next_obs, dtype=th.float32)
                self.last_done = th.as_tensor(done, dtype=th.float32)
            values = self.critic(obs.reshape(-1, obs.shape[-1])).reshape(shape)
            next_value = self.critic(self.last_obs)[:, 0]
            advantages, last_gae = th.zeros(shape), th.zeros(self.n_envs)
            for step in reversed(range(self.n_steps)):
                next_non_terminal = 1.0 - (self.last_done if step == self.n_steps - 1 else dones[step + 1])
                following = next_value if step == self.n_steps - 1 else values[step + 1]
                delta = rewards[step] + self.gamma * following * next_non_terminal - values[step]
                last_gae = delta + self.gamma * self.gae_lambda * next_non_terminal * last_gae
                advantages[step] = last_gae
        self.num_timesteps += self.n_steps * self.n_envs
        flat = (obs, actions, log_probs, advantages + values, advantages)
        return tuple(tensor.reshape(self.n_steps * self.n_envs, *tensor.shape[2:]) for tensor in flat)

    def train(self, rollout: tuple[th.Tensor, ...]) -> None:
        """``n_epochs`` passes of minibatch updates over one rollout."""
        obs, actions, old_log_probs, returns, advantages = rollout
        size = obs.shape[0]
        for _ in range(self.n_epochs):
            permutation = th.randperm(size)
            for start in range(0, size, self.batch_size):
                index = permutation[start : start + self.batch_size]
                mean, std = self.actor(obs[index]), self.log_std.exp()
                log_prob = (-0.5 * ((actions[index] - mean) / std) ** 2 - self.log_std).sum(1)
                advantage = advantages[index]
                advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
                ratio = th.exp(log_prob - old_log_probs[index])
                clipped = th.clamp(ratio, 1 - self.clip_range, 1 + self.clip_range)
                policy_loss = -th.min(advantage * ratio, advantage * clipped).mean()
                value_loss = ((returns[index] - self.critic(obs[index])[:, 0]) ** 2).mean()
                entropy = (0.5 + 0.5 * np.log(2 * np.pi) + self.log_std).sum()
                loss = policy_loss + self.vf_coef * value_loss - self.ent_coef * entropy
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(self.parameters, self.max_grad_norm)
                self.optimizer.step()

    def learn(self, total_timesteps: int) -> "MinimalPPO":
        """Alternate rollouts and updates until ``total_timesteps`` more env steps are taken."""
        target = self.num_timesteps + total_timesteps
        while self.num_timesteps < target:
            self.train(self.collect_rollouts())
        return self
