"""Wrappers that turn the benchmark's environments into its variants, and that add the true cost of a declared constraint."""

from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

from sb3_icrl.common.constraint_spec import ConstraintSpec, FeatureConstraint, as_constraint_spec, get_constraint_spec

#: Noise model of :class:`TransitionNoiseWrapper`: an independent draw for each component of the state
COMPONENT_NOISE = "component"
#: Noise model of :class:`TransitionNoiseWrapper`: one draw per step, added to every component alike (the paper's code)
SHARED_NOISE = "shared"
#: The noise models :class:`TransitionNoiseWrapper` takes
TRANSITION_NOISE_MODELS = (COMPONENT_NOISE, SHARED_NOISE)


def check_noise_model(model: Any, where: str = "model") -> str:
    """
    :param model: A transition noise model's name
    :param where: What the name was given as, for the error message (an argument, a flag, a suite key)
    :return: The name, when it is one of :data:`TRANSITION_NOISE_MODELS`
    :raises ValueError: When it is not
    """
    if model not in TRANSITION_NOISE_MODELS:
        raise ValueError(
            f"`{where}` names a transition noise model: {COMPONENT_NOISE!r} (an independent draw per state component) or "
            f"{SHARED_NOISE!r} (one draw per step added to every component, as the paper's code does), got {model!r}."
        )
    return str(model)


def recorded_transition_noise(run_args: Mapping[str, Any]) -> tuple[float, str]:
    """
    The transition noise a run trained with, to rebuild its env (evaluation, identification, plots, transfer).

    :param run_args: The run's ``args.yml``
    :return: ``(sigma, model)``; a run recorded before the noise had a model used the per-component one
    """
    sigma = float(run_args.get("transition_noise") or 0.0)
    return sigma, check_noise_model(run_args.get("transition_noise_model") or COMPONENT_NOISE, "transition_noise_model")


def transition_noise_wrapper(sigma: float, model: str = COMPONENT_NOISE) -> Callable[[gym.Env], gym.Env] | None:
    """
    :param sigma: Standard deviation of the noise
    :param model: One of :data:`TRANSITION_NOISE_MODELS`
    :return: A ``wrapper_class`` for SB3's ``make_vec_env`` that adds the noise, or ``None`` when ``sigma`` is 0
    """
    check_noise_model(model)
    if sigma <= 0:
        return None
    return lambda env: TransitionNoiseWrapper(env, sigma=sigma, model=model)


class TransitionNoiseWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """
    Stochastic transitions: add ``N(0, sigma^2)`` noise to every component of the next state
    (the paper's "noisy environments", sigma in {1e-3, 1e-2, 1e-1}).

    Two noise models: ``"component"`` draws independent noise for each component of the state; ``"shared"`` draws one
    value per step and adds it to every component alike, as the paper's code does. Independent noise is the usual
    reading of "``N(0, sigma)`` on the next state"; the shared draw moves the whole state along one diagonal direction,
    which is what the paper's results measured.

    On MuJoCo environments the noise perturbs the simulator state itself: after each step the components
    of ``qpos`` and ``qvel`` get the noise (quaternions are re-normalised), the
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
    :param model: ``"component"`` (an independent draw per state component) or ``"shared"`` (one draw per step added to
        every component)
    """

    def __init__(self, env: gym.Env, sigma: float, model: str = COMPONENT_NOISE):
        # Recorded so that gymnasium can rebuild the wrapped env from its spec
        gym.utils.RecordConstructorArgs.__init__(self, sigma=sigma, model=model)
        gym.Wrapper.__init__(self, env)
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"`sigma` is a standard deviation: a finite float >= 0, got {sigma!r} (paper: 1e-3, 1e-2, 1e-1).")
        self.sigma = float(sigma)
        self.model = check_noise_model(model)
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
            noise = self._draw_noise(np.shape(observation))
            space = self.observation_space
            assert isinstance(space, spaces.Box)
            observation = np.clip(observation + noise, space.low, space.high).astype(space.dtype)
        else:
            observation, noise = self._perturb_simulator(info)
        self.last_noise = noise
        return observation, reward, terminated, truncated, info

    def _draw_noise(self, shape: tuple[int, ...]) -> np.ndarray:
        """The noise of one step, one value per component of ``shape``."""
        assert self._noise_rng is not None
        if self.model == SHARED_NOISE:
            return np.full(shape, self._noise_rng.normal(0.0, self.sigma))
        return self._noise_rng.normal(0.0, self.sigma, size=shape)

    def _perturb_simulator(self, info: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        env = self._mujoco_env
        assert env is not None and self._noise_rng is not None
        model, data = env.model, env.data
        noise = self._draw_noise((model.nq + model.nv,))
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


class MissingCostError(ValueError):
    """An env reports no true cost in its info dict and declares no constraint to compute it from."""


class DeclaredCostWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """
    Puts the true cost of an env's declared constraint (see :mod:`sb3_icrl.common.constraint_spec`) into
    ``info[cost_info_key]`` when the env's own ``step`` does not, so that evaluation, experts and demonstrations read it
    from one place for the benchmark envs and for yours alike.

    The cost is ``spec.true_cost`` of the observation the step returned (the state it reached, as the benchmark envs
    price it) and the action taken. An env that reports ``info[cost_info_key]`` itself is left as it is: its own cost is
    never overwritten. Wrap the env before any wrapper that transforms observations (normalisation, frame stacking):
    the declaration reads the env's own observations. An ICRL learner still never sees this cost: its
    :class:`~sb3_icrl.constraints.wrappers.LearnedCostVecEnvWrapper` moves ``info[cost_info_key]`` away, whoever put it
    there.

    :param env: The env, e.g. ``gymnasium.make("myns/MyEnv-v0")``
    :param spec: The declaration to use; ``None``: the env's own (its ``constraint_spec`` attribute, or
        :func:`~sb3_icrl.common.constraint_spec.declare_constraint` for its registered id)
    :param cost_info_key: The info key of the true per-step cost
    :param required: Raise :class:`MissingCostError` at a step whose info has no cost when there is no declaration
        either; ``False``: pass such steps on unchanged (for learners that do not read the true cost)
    """

    def __init__(
        self,
        env: gym.Env,
        spec: ConstraintSpec | FeatureConstraint | None = None,
        cost_info_key: str = "cost",
        required: bool = True,
    ):
        gym.utils.RecordConstructorArgs.__init__(self, spec=spec, cost_info_key=cost_info_key, required=required)
        gym.Wrapper.__init__(self, env)
        #: The declaration the cost is computed from (``None``: the env declares none)
        self.declared_spec: ConstraintSpec | None = (
            get_constraint_spec(env) if spec is None else as_constraint_spec(spec, "DeclaredCostWrapper(spec=...)")
        )
        self.cost_info_key = cost_info_key
        self.required = required

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        if self.cost_info_key not in info:
            if self.declared_spec is not None:
                info = {**info, self.cost_info_key: self._declared_cost(observation, action)}
            elif self.required:
                env_id = getattr(self.env.spec, "id", None) or type(self.env.unwrapped).__name__
                raise MissingCostError(
                    f"{env_id} reports no true cost (its info has no key {self.cost_info_key!r}, only {sorted(info)}) "
                    "and declares no constraint to compute it from. Declare the constraint: a `constraint_spec` "
                    "attribute on the env (a ConstraintSpec or FeatureConstraint from sb3_icrl.common.constraint_spec), or "
                    f"declare_constraint({env_id!r}, ...) where you register it; or put the per-step cost in "
                    f"info[{self.cost_info_key!r}]."
                )
        return observation, reward, terminated, truncated, info

    def _declared_cost(self, observation: Any, action: Any) -> Any:
        assert self.declared_spec is not None
        # A batch of one: true_cost and user cost functions are batched
        costs = np.asarray(self.declared_spec.true_cost(np.asarray(observation)[None], np.asarray(action)[None]), np.float64)
        cost = costs if costs.ndim == 0 else costs[0]
        return float(cost) if np.ndim(cost) == 0 else cost  # one float, or one per constraint


#: The info keys :class:`EpisodeConstraintWrapper` adds at the end of an episode (the Monitor columns of the paper's
#: protocol: violation and feasible reward of each training episode)
EPISODE_CONSTRAINT_KEYS = ("true_violation", "true_feasible_reward", "true_episode_cost")


class EpisodeConstraintWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """
    Adds each episode's true-constraint totals to the info of its last step, for SB3's ``Monitor`` to write beside the
    return (``Monitor(env, info_keywords=EPISODE_CONSTRAINT_KEYS)``): ``true_violation`` (1.0 if some step's cost was
    > 0), ``true_feasible_reward`` (the reward summed up to the first violating step, that step excluded, as the
    benchmark's evaluation sums it) and ``true_episode_cost``. The paper reports its results on the last training
    episodes this way. An env that reports no cost gives NaN.

    It reads ``info[cost_info_key]`` as the env below reports it (the true cost); it changes nothing else. A learner
    that reads training infos could see the totals in ``info["episode"]``: the ICRL algorithms do not.

    :param env: The env (with its true cost in ``info[cost_info_key]``)
    :param cost_info_key: The info key of the true per-step cost
    """

    def __init__(self, env: gym.Env, cost_info_key: str = "cost"):
        gym.utils.RecordConstructorArgs.__init__(self, cost_info_key=cost_info_key)
        gym.Wrapper.__init__(self, env)
        self.cost_info_key = cost_info_key
        self._reset_totals()

    def _reset_totals(self) -> None:
        self._violated = False
        self._feasible_reward = 0.0
        self._episode_cost = 0.0
        self._cost_reported = True

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._reset_totals()
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        cost = info.get(self.cost_info_key)
        if cost is None:
            self._cost_reported = False
        else:
            # A float as it is (NumPy's float64 included: np.sum costs microseconds per step), a vector summed
            cost = cost if isinstance(cost, float) else float(np.sum(cost))
            self._violated |= cost > 0
            self._episode_cost += cost
        if not self._violated:
            self._feasible_reward += float(reward)
        if terminated or truncated:
            totals = (float(self._violated), self._feasible_reward, self._episode_cost)
            if not self._cost_reported:
                totals = (float("nan"),) * 3
            info = {**info, **dict(zip(EPISODE_CONSTRAINT_KEYS, totals, strict=True))}
        return observation, reward, terminated, truncated, info
