"""
Transfer tasks of the benchmark envs: the same robot, observation and true constraint, with a reward that pulls
toward the constrained side. A constraint that was identified, not just fitted to one reward, should keep a fresh
learner feasible here too (``sb3-icrl transfer RUN --task reward``).

============================================  =======================  =============================================
id (``sb3_icrl/...``)                         constraint of            reward
============================================  =======================  =============================================
``BlockedHalfCheetahBackward-v0``             BlockedHalfCheetah-v0    ``-dx/dt - ctrl``: running backward, to x <= -3
``BlockedAntBackward-v0``                     BlockedAnt-v0            ``-dx/dt + healthy - ctrl - contact``
``BlockedWalkerBackward-v0``                  BlockedWalker-v0         ``-dx/dt + healthy - ctrl``
``BlockedSwimmerForward-v0``                  BlockedSwimmer-v0        ``+dx/dt - ctrl``: swimming to x >= 0.5
``BiasedPendulumFarLeft-v0``                  BiasedPendulum-v0        the biased reward, full only at x <= -0.05
============================================  =======================  =============================================

``info["cost"]`` is the true cost, as in the source env (evaluation and oracle only).
"""

from typing import Any

import numpy as np

from sb3_icrl.envs.blocked_mujoco import BlockedAntEnv, BlockedHalfCheetahEnv, BlockedSwimmerEnv, BlockedWalkerEnv

#: ``name -> (entry point, max_episode_steps, kwargs)`` of the transfer tasks (registered by :mod:`sb3_icrl.envs`)
TRANSFER_ENV_SPECS: dict[str, tuple[str, int, dict]] = {
    "BlockedHalfCheetahBackward-v0": ("sb3_icrl.envs.transfer_envs:BlockedHalfCheetahBackwardEnv", 1000, {}),
    "BlockedAntBackward-v0": ("sb3_icrl.envs.transfer_envs:BlockedAntBackwardEnv", 500, {}),
    "BlockedWalkerBackward-v0": ("sb3_icrl.envs.transfer_envs:BlockedWalkerBackwardEnv", 500, {}),
    "BlockedSwimmerForward-v0": ("sb3_icrl.envs.transfer_envs:BlockedSwimmerForwardEnv", 500, {}),
    "BiasedPendulumFarLeft-v0": ("sb3_icrl.envs.blocked_mujoco:BiasedPendulumEnv", 100, {"high_reward_x": -0.05}),
}

#: The reward-transfer task of each source env (same observation space and true constraint)
REWARD_TRANSFER_TASKS: dict[str, str] = {
    "BlockedHalfCheetah-v0": "BlockedHalfCheetahBackward-v0",
    "BlockedAnt-v0": "BlockedAntBackward-v0",
    "BlockedWalker-v0": "BlockedWalkerBackward-v0",
    "BlockedSwimmer-v0": "BlockedSwimmerForward-v0",
    "BiasedPendulum-v0": "BiasedPendulumFarLeft-v0",
    # The binding variants (sb3_icrl.envs.binding_envs): a reward of speed toward the line, or the paper's own pendulum
    "BlockedHalfCheetahReach-v0": "BlockedHalfCheetahBackward-v0",
    "BlockedAntReach-v0": "BlockedAntBackward-v0",
    "BlockedWalkerReach-v0": "BlockedWalkerBackward-v0",
    "BiasedPendulumReach-v0": "BiasedPendulum-v0",
}


def _directed_reward(env: Any, x_velocity: float, action: np.ndarray, direction: float, extra: dict[str, float]) -> tuple:
    # Signed speed: moving toward the constrained side pays, moving away costs
    directed = direction * env._forward_reward_weight * x_velocity
    ctrl_cost = env.control_cost(action)
    reward_info = {"reward_forward": directed, "reward_ctrl": -ctrl_cost, **extra}
    return directed - ctrl_cost + sum(extra.values()), reward_info


class BlockedHalfCheetahBackwardEnv(BlockedHalfCheetahEnv):
    """
    :class:`~sb3_icrl.envs.BlockedHalfCheetahEnv` rewarded for running backward, into ``x <= -3``
    (id ``sb3_icrl/BlockedHalfCheetahBackward-v0``): reward ``-forward_reward_weight * dx/dt - ctrl_cost``.
    Same arguments as the source env.
    """

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _directed_reward(self, x_velocity, action, -1.0, {})


class BlockedAntBackwardEnv(BlockedAntEnv):
    """
    :class:`~sb3_icrl.envs.BlockedAntEnv` rewarded for walking toward negative x, into ``x <= -3``
    (id ``sb3_icrl/BlockedAntBackward-v0``): reward ``-dx/dt + healthy_reward - ctrl_cost - contact_cost``.
    Same arguments as the source env.
    """

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        reward, info = _directed_reward(self, x_velocity, action, -1.0, {"reward_survive": self.healthy_reward})
        contact_cost = self.contact_cost
        info["reward_contact"] = -contact_cost
        return reward - contact_cost, info


class BlockedWalkerBackwardEnv(BlockedWalkerEnv):
    """
    :class:`~sb3_icrl.envs.BlockedWalkerEnv` rewarded for walking backward, into ``x <= -3``
    (id ``sb3_icrl/BlockedWalkerBackward-v0``): reward ``-dx/dt + healthy_reward - ctrl_cost``.
    Same arguments as the source env.
    """

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _directed_reward(self, x_velocity, action, -1.0, {"reward_survive": self._healthy_reward})


class BlockedSwimmerForwardEnv(BlockedSwimmerEnv):
    """
    :class:`~sb3_icrl.envs.BlockedSwimmerEnv` rewarded for swimming forward, into ``x >= 0.5``
    (id ``sb3_icrl/BlockedSwimmerForward-v0``): reward ``dx/dt - ctrl_cost``. Same arguments as the source env.
    """

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _directed_reward(self, x_velocity, action, 1.0, {})
