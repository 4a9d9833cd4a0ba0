"""Wrappers that turn the benchmark's environments into its variants."""

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv


class TransitionNoiseWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """
    Stochastic transitions: add ``N(0, sigma^2)`` noise to every component of the next state
    (the paper's "noisy environments", sigma in {1e-3, 1e-2, 1e-1}).

    On MuJoCo environments the noise perturbs the simulator state itself: after each step every
    component of ``qpos`` and ``qvel`` gets independent noise (quaternions are re-normalised), the
    simulator continues from the perturbed state, and the returned observation, ``info["x_position"]``
    and ``info["cost"]`` are recomputed from it, so the true cost stays consistent with what the agent
    sees. The reward and ``terminated`` are those of the noiseless step (as in the paper's code: noise in
    ``|dx| / dt`` would otherwise pay for jitter); an environment whose perturbed state is unhealthy ends
    at its next step. Wrap the environment before any observation wrapper (normalisation, ...).

    On other environments with a ``Box`` observation space only the observation is perturbed (and
    clipped to the space's bounds); the simulator's state is untouched.

    The noise generator is re-seeded by ``reset(seed=...)`` (from a child of that seed, so it does not
    repeat the environment's own random stream): the same seed gives the same noise.

    :param env: Environment to wrap, e.g. ``gymnasium.make("sb3_icrl/BlockedHalfCheetah-v0")``
    :param sigma: Standard deviation of the noise (0 disables it)
    """

    def __init__(self, env: gym.Env, sigma: float):
        # Recorded so that gymnasium can rebuild the wrapped env from its spec
        gym.utils.RecordConstructorArgs.__init__(self, sigma=sigma)
        gym.Wrapper.__init__(self, env)
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"`sigma` is a standard deviation: a finite float >= 0, got {sigma!r} (paper: 1e-3, 1e-2, 1e-1).")
        self.sigma = float(sigma)
        self._mujoco_env: MujocoEnv | None = env.unwrapped if isinstance(env.unwrapped, MujocoEnv) else None
        if self._mujoco_env is None and not isinstance(env.observation_space, spaces.Box):
            raise TypeError(
                "TransitionNoiseWrapper adds Gaussian noise to continuous states: it needs a MuJoCo environment or a Box "
                f"observation space, got {env.observation_space}."
            )
        inner: gym.Env = env
        while self._mujoco_env is not None and isinstance(inner, gym.Wrapper):
            if isinstance(inner, gym.ObservationWrapper):
                raise ValueError(
                    f"{type(inner).__name__} transforms the observations: apply TransitionNoiseWrapper first, then it."
                )
            inner = inner.env
        # Free and ball joints hold quaternions, which must stay unit-norm
        quaternion_joints = (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL)
        self._has_quaternions = self._mujoco_env is not None and bool(
            np.isin(self._mujoco_env.model.jnt_type, quaternion_joints).any()
        )
        self._noise_rng: np.random.Generator | None = None
        #: The noise added by the last step (``qpos`` then ``qvel`` noise for MuJoCo, else observation noise)
        self.last_noise: np.ndarray | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._noise_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        elif self._noise_rng is None:
            self._noise_rng = np.random.default_rng()
        self.last_noise = None
        return self.env.reset(seed=seed, options=options)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        if self.sigma == 0.0:
            return observation, reward, terminated, truncated, info
        if self._noise_rng is None:
            raise gym.error.ResetNeeded("Call reset() before step().")
        if self._mujoco_env is None:
            noise = self._noise_rng.normal(0.0, self.sigma, size=np.shape(observation))
            space = self.observation_space
            assert isinstance(space, spaces.Box)
            observation = np.clip(observation + noise, space.low, space.high).astype(space.dtype)
        else:
            observation, noise = self._perturb_simulator(info)
        self.last_noise = noise
        return observation, reward, terminated, truncated, info

    def _perturb_simulator(self, info: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        env = self._mujoco_env
        assert env is not None and self._noise_rng is not None
        model, data = env.model, env.data
        noise = self._noise_rng.normal(0.0, self.sigma, size=model.nq + model.nv)
        # In place rather than through set_state(), which copies both arrays: this runs every step
        data.qpos += noise[: model.nq]
        data.qvel += noise[model.nq :]
        if self._has_quaternions:
            mujoco.mj_normalizeQuat(model, data.qpos)
        # Recompute the quantities derived from the state (positions of bodies, contact forces in Ant's observation)
        mujoco.mj_forward(model, data)
        mujoco.mj_rnePostConstraint(model, data)
        # Positions reported by the step describe the state before the noise: refresh them
        qpos = data.qpos
        if "x_position" in info:
            info["x_position"] = np.float64(qpos[0])
        if "y_position" in info:
            info["y_position"] = np.float64(qpos[1])
            info["distance_from_origin"] = np.float64(np.hypot(qpos[0], qpos[1]))
        cost_info = getattr(env, "cost_info", None)
        if cost_info is not None:
            info.update(cost_info())
        return env._get_obs(), noise  # type: ignore[attr-defined]
