"""
Environments of the ICRL benchmark, registered with gymnasium in the ``sb3_icrl`` namespace::

    import gymnasium
    import sb3_icrl.envs  # noqa: F401  (registers the ids)

    env = gymnasium.make("sb3_icrl/BlockedHalfCheetah-v0")

Every step's ``info["cost"]`` is the true cost (1.0 when the constraint is broken, else 0.0). Each env declares its
constraint as ``constraint_spec`` (:mod:`sb3_icrl.common.constraint_spec`), read by :func:`get_constraint_spec`.
"""

from typing import Any

import gymnasium
from gymnasium.envs.registration import load_env_creator

from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint, declare_constraint, get_constraint_spec
from sb3_icrl.common.env_ids import NAMESPACE
from sb3_icrl.envs.binding_envs import BINDING_ENV_SPECS, BINDING_VARIANTS
from sb3_icrl.envs.blocked_mujoco import (
    CONSTRAINED_FEATURE,
    BiasedPendulumEnv,
    BlockedAntEnv,
    BlockedHalfCheetahEnv,
    BlockedSwimmerEnv,
    BlockedWalkerEnv,
    ConstrainedFeature,
)
from sb3_icrl.envs.grid_world import MAPS, GridWorldEnv
from sb3_icrl.envs.transfer_envs import REWARD_TRANSFER_TASKS, TRANSFER_ENV_SPECS
from sb3_icrl.envs.wrappers import TransitionNoiseWrapper

#: ``name -> (entry point, max_episode_steps, kwargs)`` of every registered environment
ENV_SPECS: dict[str, tuple[str, int, dict]] = {
    "BlockedHalfCheetah-v0": ("sb3_icrl.envs.blocked_mujoco:BlockedHalfCheetahEnv", 1000, {}),
    "BlockedAnt-v0": ("sb3_icrl.envs.blocked_mujoco:BlockedAntEnv", 500, {}),
    "BiasedPendulum-v0": ("sb3_icrl.envs.blocked_mujoco:BiasedPendulumEnv", 100, {}),
    "BlockedWalker-v0": ("sb3_icrl.envs.blocked_mujoco:BlockedWalkerEnv", 500, {}),
    "BlockedSwimmer-v0": ("sb3_icrl.envs.blocked_mujoco:BlockedSwimmerEnv", 500, {}),
    "GridWorld-v0": ("sb3_icrl.envs.grid_world:GridWorldEnv", 50, {}),
    "GridWorldWall-v0": ("sb3_icrl.envs.grid_world:GridWorldEnv", 50, {"map_name": "wall"}),
    "GridWorldSquare-v0": ("sb3_icrl.envs.grid_world:GridWorldEnv", 50, {"map_name": "square"}),
    "GridWorldBigSquare-v0": ("sb3_icrl.envs.grid_world:GridWorldEnv", 50, {"map_name": "big-square"}),
    "GridWorldZigzag-v0": ("sb3_icrl.envs.grid_world:GridWorldEnv", 50, {"map_name": "zigzag"}),
    # Driving: 40 s at 5 Hz; the env ends its episodes itself (time-out included), the limit only backs it up
    "HighwayVelocity-v0": (
        "sb3_icrl.envs.highway.env:HighwayConstraintEnv",
        200,
        {"constraints": ("velocity",), "traffic": "sparse"},
    ),
    "HighwayDistance-v0": (
        "sb3_icrl.envs.highway.env:HighwayConstraintEnv",
        200,
        {"constraints": ("distance",), "traffic": "dense"},
    ),
    "HighwayVelocityDistance-v0": (
        "sb3_icrl.envs.highway.env:HighwayConstraintEnv",
        200,
        {"constraints": ("velocity", "distance"), "traffic": "mixed"},
    ),
}


def heldout_env_kwargs(env_id: str) -> dict[str, Any]:
    """
    The env keyword arguments of a held-out evaluation: what the env's class declares in ``heldout_env_kwargs`` (the
    driving envs: their test recordings, ``split="test"``), nothing for envs without held-out data of their own (their
    held-out episodes differ by seed only).

    :param env_id: A registered env id
    :return: Keyword arguments (empty for most envs)
    """
    entry_point = gymnasium.spec(env_id).entry_point
    creator = load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point
    return dict(getattr(creator, "heldout_env_kwargs", None) or {})


def register_envs() -> None:
    """Register every environment of :data:`ENV_SPECS` with gymnasium; ids already registered are left alone."""
    # The transfer tasks (sb3_icrl.envs.transfer_envs) and the binding variants (sb3_icrl.envs.binding_envs) register
    # with the benchmark envs
    for name, (entry_point, max_episode_steps, kwargs) in {**ENV_SPECS, **TRANSFER_ENV_SPECS, **BINDING_ENV_SPECS}.items():
        env_id = f"{NAMESPACE}/{name}"
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, max_episode_steps=max_episode_steps, kwargs=kwargs)


register_envs()

__all__ = [
    "BINDING_ENV_SPECS",
    "BINDING_VARIANTS",
    "CONSTRAINED_FEATURE",
    "ENV_SPECS",
    "MAPS",
    "NAMESPACE",
    "REWARD_TRANSFER_TASKS",
    "TRANSFER_ENV_SPECS",
    "BiasedPendulumEnv",
    "BlockedAntEnv",
    "BlockedHalfCheetahEnv",
    "BlockedSwimmerEnv",
    "BlockedWalkerEnv",
    "ConstrainedFeature",
    "ConstraintSpec",
    "FeatureConstraint",
    "GridWorldEnv",
    "TransitionNoiseWrapper",
    "declare_constraint",
    "get_constraint_spec",
    "heldout_env_kwargs",
    "register_envs",
]
