"""
Binding variants of the benchmark's MuJoCo envs: the same robot, observation and true constraint, with a reward that
grows toward the forbidden side, so that the constraint decides what the best policy does.

On the paper's rewards, unconstrained PPO rarely crosses the line of Ant, Walker and Pendulum (nothing pulls it
there), and the HalfCheetah and Ant experts never come near their line (they run the other way): such envs can show
neither that a learned constraint binds nor where it lies. Here the reward pays the position itself, so that:

- unconstrained PPO runs across the line and keeps going (the constraint binds), and
- the constrained expert walks up to the line and stays there, so that its demonstrations show where the line is
  (the constraint can be identified, threshold included).

Feasible reward then separates the two reference rows widely: PPO's stops at its first crossing, early in the
episode; the oracle's is the position held near the line for the rest of it.

==============================  =======================  =====================================================
id (``sb3_icrl/...``)           constraint of            reward
==============================  =======================  =====================================================
``BlockedHalfCheetahReach-v0``  BlockedHalfCheetah-v0    ``-x - ctrl``: the distance covered toward x <= -3
``BlockedAntReach-v0``          BlockedAnt-v0            ``-max(x, -3.5) + healthy - ctrl - contact``
``BlockedWalkerReach-v0``       BlockedWalker-v0         ``-x + healthy - ctrl``
``BiasedPendulumReach-v0``      BiasedPendulum-v0        the biased reward, full only at x <= -0.05
==============================  =======================  =====================================================

``x`` is the root's position after the step, in metres (0 at the start, up to the reset noise). The ant's pay stops
half a metre past its line: an ant runs several metres past the line within an episode, and with a pull that keeps
growing there the multiplier a constrained learner needs grows with it, high enough that its experts learnt to walk
away from the line instead; half a metre still pulls unconstrained PPO across. BlockedSwimmer needs no
variant: its expert swims to the line and PPO crosses it. ``info["cost"]`` is the true cost, as in the source env
(experts and evaluation only).
"""

from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from sb3_icrl.envs.blocked_mujoco import BlockedAntEnv, BlockedHalfCheetahEnv, BlockedWalkerEnv, StepReturn

#: ``name -> (entry point, max_episode_steps, kwargs)`` of the binding variants (registered by :mod:`sb3_icrl.envs`)
BINDING_ENV_SPECS: dict[str, tuple[str, int, dict]] = {
    "BlockedHalfCheetahReach-v0": ("sb3_icrl.envs.binding_envs:BlockedHalfCheetahReachEnv", 1000, {}),
    "BlockedAntReach-v0": ("sb3_icrl.envs.binding_envs:BlockedAntReachEnv", 500, {}),
    "BlockedWalkerReach-v0": ("sb3_icrl.envs.binding_envs:BlockedWalkerReachEnv", 500, {}),
    "BiasedPendulumReach-v0": ("sb3_icrl.envs.blocked_mujoco:BiasedPendulumEnv", 100, {"high_reward_x": -0.05}),
}

#: The binding variant of each paper env that needs one
BINDING_VARIANTS: dict[str, str] = {
    "BlockedHalfCheetah-v0": "BlockedHalfCheetahReach-v0",
    "BlockedAnt-v0": "BlockedAntReach-v0",
    "BlockedWalker-v0": "BlockedWalkerReach-v0",
    "BiasedPendulum-v0": "BiasedPendulumReach-v0",
}


def _reach_reward(
    env: Any, action: np.ndarray, extra: dict[str, float], paid_down_to: float = -np.inf
) -> tuple[float, dict[str, float]]:
    # The position itself pays: each step spent nearer the forbidden side (x <= threshold < 0) earns more, down to
    # `paid_down_to`
    reach = -max(float(env.data.qpos[0]), paid_down_to)
    ctrl_cost = float(env.control_cost(action))
    reward_info = {"reward_reach": reach, "reward_ctrl": -ctrl_cost, **extra}
    return reach - ctrl_cost + sum(extra.values()), reward_info


class BlockedHalfCheetahReachEnv(BlockedHalfCheetahEnv):
    """
    :class:`~sb3_icrl.envs.BlockedHalfCheetahEnv` paid its distance toward the forbidden side
    (id ``sb3_icrl/BlockedHalfCheetahReach-v0``): reward ``-x - ctrl_cost``. Same arguments as the source env
    (``forward_reward_weight`` is unused).
    """

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _reach_reward(self, action, {})


class BlockedAntReachEnv(BlockedAntEnv):
    """
    :class:`~sb3_icrl.envs.BlockedAntEnv` paid its distance toward the forbidden side, up to a little past its line
    (id ``sb3_icrl/BlockedAntReach-v0``): reward ``-max(x, cost_threshold - paid_beyond_line) + healthy_reward
    - ctrl_cost - contact_cost``. Other arguments as the source env.

    :param paid_beyond_line: How far past the line (metres) the position still pays; beyond, the pull stops, so that
        crossing gains at most this much per step
    :param end_at_line: End the episode (``terminated``) at the first step that breaks the constraint: a way to train
        an expert that holds its position near the line, since a crossing then forfeits the rest of the episode's pay.
        The benchmark's env keeps it off (demonstrations and evaluation run whole episodes)
    :param kwargs: Arguments of :class:`~sb3_icrl.envs.BlockedAntEnv`
    """

    def __init__(self, paid_beyond_line: float = 0.5, end_at_line: bool = False, **kwargs: Any):
        if isinstance(paid_beyond_line, bool) or not isinstance(paid_beyond_line, (int, float)) or not paid_beyond_line > 0:
            raise ValueError(f"`paid_beyond_line` must be a positive number of metres, got {paid_beyond_line!r}.")
        if not isinstance(end_at_line, (bool, np.bool_)):
            raise TypeError(f"`end_at_line` must be True or False, got {type(end_at_line).__name__} {end_at_line!r}.")
        super().__init__(**kwargs)
        self.paid_beyond_line = float(paid_beyond_line)
        self.end_at_line = bool(end_at_line)
        utils.EzPickle.__init__(self, paid_beyond_line, end_at_line, **kwargs)

    def step(self, action: NDArray[np.float32]) -> StepReturn:
        observation, reward, terminated, truncated, info = super().step(action)
        return observation, reward, terminated or (self.end_at_line and bool(info["cost"])), truncated, info

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        paid_down_to = self.cost_threshold - self.paid_beyond_line
        reward, info = _reach_reward(self, action, {"reward_survive": self.healthy_reward}, paid_down_to)
        contact_cost = float(self.contact_cost)
        info["reward_contact"] = -contact_cost
        return reward - contact_cost, info


class BlockedWalkerReachEnv(BlockedWalkerEnv):
    """
    :class:`~sb3_icrl.envs.BlockedWalkerEnv` paid its distance toward the forbidden side
    (id ``sb3_icrl/BlockedWalkerReach-v0``): reward ``-x + healthy_reward - ctrl_cost``; episodes still end when the
    walker falls. Same arguments as the source env (``forward_reward_weight`` is unused).
    """

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _reach_reward(self, action, {"reward_survive": self._healthy_reward})
