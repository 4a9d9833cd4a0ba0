"""
The envs of a run, as ``train.py`` builds them and its evaluations rebuild them: Monitor, transition noise, the true
cost of a declared constraint, the recipe's wrappers and ``VecNormalize``; and the recorder of evaluation episodes that
a later constraint prices again.
"""

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sb3_icrl.common.vec_env import ShallowCopyDummyVecEnv, load_vec_normalize
from sb3_icrl.envs.wrappers import (
    COMPONENT_NOISE,
    EPISODE_CONSTRAINT_KEYS,
    DeclaredCostWrapper,
    EpisodeConstraintWrapper,
    TransitionNoiseWrapper,
)


@dataclass
class RecordedEpisode:
    """
    One evaluation episode as the constraint sees it, kept so that it can be priced again by a later constraint.

    :param observations: Raw observations, one per step, ``(T, *obs_shape)``
    :param actions: Actions as the env applied them (clipped to a Box), ``(T, *action_shape)``
    :param rewards: Per-step rewards, ``(T,)``
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray


class LearnedCostRecorder(VecEnvWrapper):
    """
    Records each finished episode's raw observations, actions and rewards while ``recording`` is on, so that the
    evaluation can price them with the learned cost (:func:`~sb3_icrl.zoo.callbacks.learned_episode_stats`), now and
    after later constraint updates. Goes below any ``VecNormalize``: it sees raw observations.

    :param venv: The evaluation env
    """

    def __init__(self, venv: VecEnv):
        super().__init__(venv)
        self.recording = False
        self.episodes: list[RecordedEpisode] = []
        #: The sub-env of each recorded episode
        self.episode_envs: list[int] = []
        self._obs: Any = None  # VecEnvObs
        self._actions: np.ndarray | None = None
        self._steps: list[list[tuple[Any, np.ndarray, float]]] = [[] for _ in range(self.num_envs)]

    def reset(self) -> Any:
        self._obs = self.venv.reset()
        self._steps = [[] for _ in range(self.num_envs)]
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        if self.recording and self._obs is not None and self._actions is not None:
            actions = np.asarray(self._actions)
            if isinstance(self.action_space, spaces.Box):
                actions = np.clip(actions, self.action_space.low, self.action_space.high)
            for idx in range(self.num_envs):
                self._steps[idx].append((np.array(self._obs[idx]), np.array(actions[idx]), float(rewards[idx])))
                if dones[idx]:
                    steps = self._steps[idx]
                    observations, episode_actions, episode_rewards = (np.array(part) for part in zip(*steps, strict=True))
                    self.episodes.append(RecordedEpisode(observations, episode_actions, episode_rewards))
                    self.episode_envs.append(idx)
                    self._steps[idx] = []
        self._obs = obs
        return obs, rewards, dones, infos

    def clear(self) -> None:
        """Forget the recorded episodes (before an evaluation)."""
        self.episodes, self.episode_envs = [], []

    def counted_episodes(self, n_episodes: int) -> list[RecordedEpisode]:
        """
        The episodes an evaluation of ``n_episodes`` counted: on each sub-env, its first ones, as many as
        :func:`~sb3_icrl.common.evaluation.evaluate_constraint` fixes for it upfront (sub-envs that finish their share go
        on stepping, and the episodes they finish then are not counted).
        """
        taken = [0] * self.num_envs
        counted = []
        for episode, idx in zip(self.episodes, self.episode_envs, strict=True):
            if taken[idx] < (n_episodes + idx) // self.num_envs:
                counted.append(episode)
                taken[idx] += 1
        return counted


def _wrapper_class(wrappers: list[tuple[Any, dict[str, Any]]]) -> Any:
    def wrap(env: gym.Env) -> gym.Env:
        for wrapper, kwargs in wrappers:
            env = wrapper(env, **kwargs)
        return env

    return wrap


def _env_factory(env_id: str, transition_noise: float, noise_model: str, require_cost: bool) -> Callable[..., gym.Env]:
    """
    The env below ``Monitor``: gymnasium's (as ``make_vec_env`` makes it), the transition noise, the true cost of a
    declared constraint, and each episode's constraint totals for the Monitor files (``EPISODE_CONSTRAINT_KEYS``).
    """

    def make(**env_kwargs: Any) -> gym.Env:
        try:  # rgb_array unless asked otherwise, as make_vec_env does
            env = gym.make(env_id, **{"render_mode": "rgb_array", **env_kwargs})
        except TypeError:
            env = gym.make(env_id, **env_kwargs)
        if transition_noise > 0:
            env = TransitionNoiseWrapper(env, sigma=transition_noise, model=noise_model)
        # Outside the noise (the cost of the state the agent sees), inside the yml's wrappers (raw observations)
        env = DeclaredCostWrapper(env, required=require_cost)
        return EpisodeConstraintWrapper(env)

    return make


def _monitor_keywords(monitor_dir: str | None, append_monitor: bool) -> tuple[str, ...]:
    """The Monitor's extra columns: the episode's constraint totals, unless a resumed run's files were written without."""
    if append_monitor and monitor_dir is not None:
        existing = os.path.join(monitor_dir, "0.monitor.csv")
        if os.path.isfile(existing):
            with open(existing) as file:
                file.readline()  # the JSON line
                if EPISODE_CONSTRAINT_KEYS[0] not in file.readline().strip().split(","):
                    return ()
    return EPISODE_CONSTRAINT_KEYS


def create_env(
    env_id: str,
    params: dict[str, Any],
    n_envs: int,
    seed: int,
    env_kwargs: dict[str, Any],
    transition_noise: float,
    monitor_dir: str | None,
    eval_env: bool = False,
    stats_path: str | None = None,
    append_monitor: bool = False,
    require_cost: bool | None = None,
    transition_noise_model: str = COMPONENT_NOISE,
) -> tuple[VecEnv, LearnedCostRecorder | None]:
    """
    Vectorised env (:class:`~sb3_icrl.common.vec_env.ShallowCopyDummyVecEnv`) with Monitor, transition noise, the true
    cost of a declared constraint where the env reports none
    (:class:`~sb3_icrl.envs.wrappers.DeclaredCostWrapper`), the yml's wrappers and VecNormalize (eval: frozen, raw
    reward).

    :param env_id: Registered env id
    :param params: Preprocessed hyper-parameters (``normalize``, ``normalize_kwargs``, ``env_wrapper``)
    :param n_envs: Number of sub-envs
    :param seed: Seed of the first sub-env
    :param env_kwargs: Keyword arguments of the env
    :param transition_noise: Std of the next-state noise (0: none)
    :param monitor_dir: Folder of the Monitor files (``None``: not written)
    :param eval_env: Build an evaluation env: a :class:`LearnedCostRecorder` at its bottom, statistics frozen
    :param stats_path: ``VecNormalize`` statistics to start from (``vecnormalize.pkl``), when normalising
    :param append_monitor: Append to the Monitor files instead of replacing them (a resumed run)
    :param require_cost: Fail at a step without ``info["cost"]`` when the env declares no constraint either;
        ``None``: for evaluation envs only (learners other than PPO-Lagrangian do not read the true cost)
    :param transition_noise_model: How the next-state noise is drawn (see
        :class:`~sb3_icrl.envs.wrappers.TransitionNoiseWrapper`)
    :return: The env and its recorder (eval envs only)
    """
    if require_cost is None:
        require_cost = eval_env
    monitor_kwargs: dict[str, Any] = {"info_keywords": _monitor_keywords(monitor_dir, append_monitor)}
    if append_monitor:
        monitor_kwargs["override_existing"] = False
    venv = make_vec_env(
        _env_factory(env_id, transition_noise, transition_noise_model, require_cost),
        n_envs=n_envs,
        seed=seed,
        env_kwargs=env_kwargs,
        monitor_dir=monitor_dir,
        monitor_kwargs=monitor_kwargs,
        wrapper_class=_wrapper_class(params["env_wrapper"]),
        vec_env_cls=ShallowCopyDummyVecEnv,
    )
    recorder = None
    if eval_env:
        venv = recorder = LearnedCostRecorder(venv)
    if params["normalize"]:
        if stats_path is not None:
            venv = load_vec_normalize(stats_path, venv)
            if eval_env:
                venv.training, venv.norm_reward = False, False
        else:
            kwargs = dict(params.get("normalize_kwargs") or {})
            if eval_env:
                kwargs.update(training=False, norm_reward=False)
            venv = VecNormalize(venv, **kwargs)
    return venv, recorder
