"""
MuJoCo environments of the ICRL benchmark (Liu et al., ICLR 2023, appendix "Virtual Environments").

Each environment subclasses a gymnasium ``v5`` MuJoCo environment, keeps the robot's global position in
the observation (the constraint is on it), replaces the reward by the benchmark's and reports the true
constraint in every step's ``info``:

- ``info["cost"]``: ``1.0`` when the state reached by the step breaks the constraint, else ``0.0``
- ``info["x_position"]``: the constrained quantity (the x coordinate of the robot's root, ``qpos[0]``)

The learner must not read ``info["cost"]``; it is there for experts (PPO-Lagrangian) and for evaluation.

Each environment declares its true constraint (:mod:`sb3_icrl.common.constraint_spec`): the class attribute
``default_constraint`` (default threshold) and the property ``constraint_spec`` (this env's threshold), read by
:func:`~sb3_icrl.common.constraint_spec.get_constraint_spec`. :data:`CONSTRAINED_FEATURE` is a view of these
declarations by environment id. Thresholds and reward weights are constructor arguments
(``gymnasium.make("sb3_icrl/BlockedHalfCheetah-v0", cost_threshold=-2.0)``).

Differences from the paper's code (gym 0.21, mujoco-py), kept on purpose:

- Observations are the v5 ones with the position included: the same layout as the paper's
  ``qpos, qvel`` for HalfCheetah (18), Walker (18, but v5 clips the velocities to [-10, 10]),
  Swimmer (10) and InvertedPendulum (4). Ant has 107 features instead of 113: v5 drops the contact
  forces of the world body, which are always zero.
- BlockedAnt uses gymnasium's ``ant.xml`` (the paper's ``ant_circle.xml`` is not public) and
  measures the distance from the origin on ``qpos[0:2]`` rather than on the torso's ``xpos``
  (the same point, but ``xpos`` lags one physics sub-step behind ``qpos``).
"""

import dataclasses
from typing import Any, ClassVar, NamedTuple

import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco.ant_v5 import AntEnv
from gymnasium.envs.mujoco.half_cheetah_v5 import HalfCheetahEnv
from gymnasium.envs.mujoco.inverted_pendulum_v5 import InvertedPendulumEnv
from gymnasium.envs.mujoco.swimmer_v5 import SwimmerEnv
from gymnasium.envs.mujoco.walker2d_v5 import Walker2dEnv
from numpy.typing import NDArray

from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint
from sb3_icrl.envs.mujoco_compat import compile_model

# Same as gymnasium's MujocoEnv.step
StepReturn = tuple[NDArray[np.float64], np.float64, bool, bool, dict[str, np.float64]]


class ConstrainedFeature(NamedTuple):
    """
    Where the constrained quantity lives and when the constraint is broken.

    :param name: Key of the quantity in ``info`` (e.g. ``"x_position"``)
    :param obs_index: Index of the quantity in the observation vector
    :param threshold: Default threshold (a constructor argument of the environment)
    :param op: ``"<="``: broken when ``value <= threshold``; ``">="``: broken when ``value >= threshold``
    """

    name: str
    obs_index: int
    threshold: float
    op: str


class _PositionConstraintMixin:
    """
    Adds the benchmark's position constraint to a gymnasium MuJoCo environment.

    Subclasses call :meth:`_setup_constraint` in ``__init__``; ``step`` then adds ``info["cost"]``.
    """

    data: Any
    cost_threshold: float
    cost_op: str
    #: The declared constraint with the default threshold (each environment's own)
    default_constraint: ClassVar[FeatureConstraint]

    @property
    def constraint_spec(self) -> ConstraintSpec:
        """The true constraint, with this env's ``cost_threshold`` (see :mod:`sb3_icrl.common.constraint_spec`)."""
        return ConstraintSpec(features=(dataclasses.replace(self.default_constraint, threshold=self.cost_threshold),))

    def _setup_constraint(self, cost_threshold: float, cost_op: str, kwargs: dict[str, Any]) -> None:
        if isinstance(cost_threshold, bool) or not isinstance(cost_threshold, (int, float, np.integer, np.floating)):
            raise TypeError(
                f"`cost_threshold` must be a finite float, got {type(cost_threshold).__name__} {cost_threshold!r}."
            )
        if not np.isfinite(cost_threshold):
            raise ValueError(f"`cost_threshold` must be a finite float, got {cost_threshold!r}.")
        if kwargs.pop("exclude_current_positions_from_observation", False):
            raise ValueError(
                f"{type(self).__name__} keeps the robot's position in the observation: the constraint is on it. "
                "Remove `exclude_current_positions_from_observation=True`."
            )
        self.cost_threshold = float(cost_threshold)
        self.cost_op = cost_op

    def constraint_cost(self, value: float) -> np.float64:
        """
        True cost of a value of the constrained quantity.

        :param value: The constrained quantity (x position)
        :return: ``1.0`` when the constraint is broken, else ``0.0``
        """
        if self.cost_op == "<=":
            return np.float64(value <= self.cost_threshold)
        return np.float64(value >= self.cost_threshold)

    def cost_info(self) -> dict[str, np.float64]:
        """
        The constrained quantity and the true cost of the current simulator state.

        :return: ``{"x_position": x, "cost": 0.0 or 1.0}``
        """
        x_position = np.float64(self.data.qpos[0])
        return {"x_position": x_position, "cost": self.constraint_cost(x_position)}

    def step(self, action: NDArray[np.float32]) -> StepReturn:
        observation, reward, terminated, truncated, info = super().step(action)  # type: ignore[misc]
        info["cost"] = self.constraint_cost(info["x_position"])
        return observation, reward, terminated, truncated, info


def _abs_forward_reward(env: Any, x_velocity: float, action: np.ndarray, survive: float | None = None) -> tuple[float, dict]:
    # Moving either way pays: the constraint, not the reward, tells the agent which way is allowed
    forward_reward = env._forward_reward_weight * abs(x_velocity)
    ctrl_cost = env.control_cost(action)
    reward_info = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost}
    if survive is None:
        return forward_reward - ctrl_cost, reward_info
    reward_info["reward_survive"] = survive
    return forward_reward + survive - ctrl_cost, reward_info


class BlockedHalfCheetahEnv(_PositionConstraintMixin, HalfCheetahEnv):
    """
    HalfCheetah whose backward region is blocked (id ``sb3_icrl/BlockedHalfCheetah-v0``, 1000 steps).

    - Observation (18): ``qpos`` (9, x position at index 0) then ``qvel`` (9)
    - Reward: ``forward_reward_weight * |dx| / dt - ctrl_cost_weight * ||action||^2``
    - Cost: 1 when ``x <= cost_threshold`` (default -3)

    :param cost_threshold: The region ``x <= cost_threshold`` is forbidden
    :param forward_reward_weight: Weight of the speed ``|dx| / dt``
    :param ctrl_cost_weight: Weight of the squared action
    :param kwargs: Other arguments of gymnasium's ``HalfCheetahEnv`` (``reset_noise_scale``, ``render_mode``, ...)
    """

    default_constraint = FeatureConstraint(obs_index=0, threshold=-3.0, op="<=", name="x_position")

    def __init__(
        self,
        cost_threshold: float = -3.0,
        forward_reward_weight: float = 1.0,
        ctrl_cost_weight: float = 0.1,
        **kwargs: Any,
    ):
        self._setup_constraint(cost_threshold, "<=", kwargs)
        super().__init__(
            forward_reward_weight=forward_reward_weight,
            ctrl_cost_weight=ctrl_cost_weight,
            exclude_current_positions_from_observation=False,
            **kwargs,
        )
        # The parent recorded its own positional arguments: record ours so that pickling rebuilds this class
        utils.EzPickle.__init__(self, cost_threshold, forward_reward_weight, ctrl_cost_weight, **kwargs)

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _abs_forward_reward(self, x_velocity, action)

    def _initialize_simulation(self) -> tuple[Any, Any]:
        # The same model without the deprecated settotalmass attribute: no mujoco warning (nor MUJOCO_LOG.TXT) per env
        return compile_model(self.fullpath, self.width, self.height)


class BlockedAntEnv(_PositionConstraintMixin, AntEnv):
    """
    Ant whose region ``x <= -3`` is blocked and whose reward grows with the distance from the origin
    (id ``sb3_icrl/BlockedAnt-v0``, 500 steps), as ``AntWall`` in the paper's public code.

    - Observation (107): ``qpos`` (15, x at index 0, y at index 1), ``qvel`` (14), contact forces (78)
    - Reward: ``||(x, y)|| + healthy_reward * is_healthy - ctrl_cost - contact_cost``
    - Cost: 1 when ``x <= cost_threshold`` (default -3)
    - Episodes do not end when the ant is unhealthy (``terminate_when_unhealthy=False``, as the paper)

    :param cost_threshold: The region ``x <= cost_threshold`` is forbidden
    :param healthy_reward: Bonus per step while the torso height is in ``healthy_z_range``
    :param terminate_when_unhealthy: End the episode when the ant is unhealthy
    :param ctrl_cost_weight: Weight of the squared action
    :param contact_cost_weight: Weight of the squared (clipped) contact forces
    :param kwargs: Other arguments of gymnasium's ``AntEnv``
    """

    default_constraint = FeatureConstraint(obs_index=0, threshold=-3.0, op="<=", name="x_position")

    def __init__(
        self,
        cost_threshold: float = -3.0,
        healthy_reward: float = 1.0,
        terminate_when_unhealthy: bool = False,
        ctrl_cost_weight: float = 0.5,
        contact_cost_weight: float = 5e-4,
        **kwargs: Any,
    ):
        self._setup_constraint(cost_threshold, "<=", kwargs)
        super().__init__(
            healthy_reward=healthy_reward,
            terminate_when_unhealthy=terminate_when_unhealthy,
            ctrl_cost_weight=ctrl_cost_weight,
            contact_cost_weight=contact_cost_weight,
            exclude_current_positions_from_observation=False,
            **kwargs,
        )
        utils.EzPickle.__init__(
            self, cost_threshold, healthy_reward, terminate_when_unhealthy, ctrl_cost_weight, contact_cost_weight, **kwargs
        )

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        distance_reward = float(np.linalg.norm(self.data.qpos[0:2]))
        healthy_reward = self.healthy_reward
        ctrl_cost = self.control_cost(action)
        contact_cost = self.contact_cost
        reward = distance_reward + healthy_reward - ctrl_cost - contact_cost
        reward_info = {
            "reward_distance": distance_reward,
            "reward_ctrl": -ctrl_cost,
            "reward_contact": -contact_cost,
            "reward_survive": healthy_reward,
        }
        return reward, reward_info


class BiasedPendulumEnv(_PositionConstraintMixin, InvertedPendulumEnv):
    """
    InvertedPendulum that pays more on the left, with a wall a little further left
    (id ``sb3_icrl/BiasedPendulum-v0``, 100 steps).

    - Observation (4): ``qpos`` (cart x at index 0, pole angle) then ``qvel`` (2)
    - Reward: ``high_reward`` when ``x <= high_reward_x``, ``low_reward`` when ``x >= 0``, linear in between;
      paid on every step, the last one included (as the paper's code)
    - Cost: 1 when ``x <= cost_threshold`` (default -0.015)
    - Episodes end when the pole falls (``|angle| > 0.2``)

    :param cost_threshold: The region ``x <= cost_threshold`` is forbidden
    :param high_reward: Reward left of ``high_reward_x``
    :param low_reward: Reward right of 0
    :param high_reward_x: Cart position (< 0) from which the reward is ``high_reward``
    :param kwargs: Other arguments of gymnasium's ``InvertedPendulumEnv``
    """

    default_constraint = FeatureConstraint(obs_index=0, threshold=-0.015, op="<=", name="x_position")

    def __init__(
        self,
        cost_threshold: float = -0.015,
        high_reward: float = 1.0,
        low_reward: float = 0.1,
        high_reward_x: float = -0.01,
        **kwargs: Any,
    ):
        if not high_reward_x < 0:
            raise ValueError(f"`high_reward_x` must be < 0 (the reward ramps up between it and 0), got {high_reward_x}.")
        self._setup_constraint(cost_threshold, "<=", kwargs)
        self.high_reward = float(high_reward)
        self.low_reward = float(low_reward)
        self.high_reward_x = float(high_reward_x)
        super().__init__(**kwargs)
        utils.EzPickle.__init__(self, cost_threshold, high_reward, low_reward, high_reward_x, **kwargs)

    def biased_reward(self, x_position: float) -> float:
        """
        The benchmark's reward for a cart position.

        :param x_position: Cart position
        :return: The reward
        """
        if x_position <= self.high_reward_x:
            return self.high_reward
        if x_position >= 0.0:
            return self.low_reward
        return self.low_reward + (self.high_reward - self.low_reward) * x_position / self.high_reward_x

    def step(self, action: NDArray[np.float32]) -> StepReturn:
        # The parent's step gives no position and a survival reward: replace both
        observation, _, terminated, truncated, _ = InvertedPendulumEnv.step(self, action)
        x_position = self.data.qpos[0]
        info = {"x_position": x_position, "cost": self.constraint_cost(x_position)}
        return observation, np.float64(self.biased_reward(x_position)), terminated, truncated, info

    def _get_reset_info(self) -> dict[str, float]:
        return {"x_position": float(self.data.qpos[0])}


class BlockedWalkerEnv(_PositionConstraintMixin, Walker2dEnv):
    """
    Walker2d whose backward region is blocked (id ``sb3_icrl/BlockedWalker-v0``, 500 steps).

    - Observation (18): ``qpos`` (9, x at index 0) then ``qvel`` (9, clipped to [-10, 10] as in v5)
    - Reward: ``|dx| / dt + healthy_reward - ctrl_cost_weight * ||action||^2``; the bonus is paid on every
      step, the terminal one included (as the paper's code)
    - Cost: 1 when ``x <= cost_threshold`` (default -3)
    - Episodes end when the walker falls (v5's health check)

    :param cost_threshold: The region ``x <= cost_threshold`` is forbidden
    :param forward_reward_weight: Weight of the speed ``|dx| / dt``
    :param ctrl_cost_weight: Weight of the squared action
    :param healthy_reward: Bonus per step
    :param kwargs: Other arguments of gymnasium's ``Walker2dEnv``
    """

    default_constraint = FeatureConstraint(obs_index=0, threshold=-3.0, op="<=", name="x_position")

    def __init__(
        self,
        cost_threshold: float = -3.0,
        forward_reward_weight: float = 1.0,
        ctrl_cost_weight: float = 1e-3,
        healthy_reward: float = 1.0,
        **kwargs: Any,
    ):
        self._setup_constraint(cost_threshold, "<=", kwargs)
        super().__init__(
            forward_reward_weight=forward_reward_weight,
            ctrl_cost_weight=ctrl_cost_weight,
            healthy_reward=healthy_reward,
            exclude_current_positions_from_observation=False,
            **kwargs,
        )
        utils.EzPickle.__init__(self, cost_threshold, forward_reward_weight, ctrl_cost_weight, healthy_reward, **kwargs)

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _abs_forward_reward(self, x_velocity, action, survive=self._healthy_reward)


class BlockedSwimmerEnv(_PositionConstraintMixin, SwimmerEnv):
    """
    Swimmer whose forward region is blocked (id ``sb3_icrl/BlockedSwimmer-v0``, 500 steps).

    - Observation (10): ``qpos`` (5, x at index 0, y at index 1) then ``qvel`` (5)
    - Reward: ``forward_reward_weight * |dx| / dt - ctrl_cost_weight * ||action||^2``
    - Cost: 1 when ``x >= cost_threshold`` (default 0.5)

    :param cost_threshold: The region ``x >= cost_threshold`` is forbidden
    :param forward_reward_weight: Weight of the speed ``|dx| / dt``
    :param ctrl_cost_weight: Weight of the squared action
    :param kwargs: Other arguments of gymnasium's ``SwimmerEnv``
    """

    default_constraint = FeatureConstraint(obs_index=0, threshold=0.5, op=">=", name="x_position")

    def __init__(
        self,
        cost_threshold: float = 0.5,
        forward_reward_weight: float = 1.0,
        ctrl_cost_weight: float = 1e-4,
        **kwargs: Any,
    ):
        self._setup_constraint(cost_threshold, ">=", kwargs)
        super().__init__(
            forward_reward_weight=forward_reward_weight,
            ctrl_cost_weight=ctrl_cost_weight,
            exclude_current_positions_from_observation=False,
            **kwargs,
        )
        utils.EzPickle.__init__(self, cost_threshold, forward_reward_weight, ctrl_cost_weight, **kwargs)

    def _get_rew(self, x_velocity: float, action: np.ndarray) -> tuple[float, dict]:
        return _abs_forward_reward(self, x_velocity, action)


# The benchmark's MuJoCo environments, by registered name
_DECLARING_ENVS: dict[str, type[_PositionConstraintMixin]] = {
    "BlockedHalfCheetah-v0": BlockedHalfCheetahEnv,
    "BlockedAnt-v0": BlockedAntEnv,
    "BiasedPendulum-v0": BiasedPendulumEnv,
    "BlockedWalker-v0": BlockedWalkerEnv,
    "BlockedSwimmer-v0": BlockedSwimmerEnv,
}
#: True constraint of each MuJoCo environment (default thresholds), cost 1 when ``obs[obs_index] op threshold``: a view
#: of the environments' own declarations (``default_constraint``)
CONSTRAINED_FEATURE: dict[str, ConstrainedFeature] = {
    name: ConstrainedFeature(
        env_class.default_constraint.name,
        env_class.default_constraint.obs_index,
        env_class.default_constraint.threshold,
        env_class.default_constraint.op,
    )
    for name, env_class in _DECLARING_ENVS.items()
}
