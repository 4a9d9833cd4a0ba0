"""A ``DummyVecEnv`` for training loops where every step's copies count."""

import pickle
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn
from stable_baselines3.common.vec_env.util import dict_to_obs


class ShallowCopyDummyVecEnv(DummyVecEnv):
    """
    SB3's ``DummyVecEnv`` with one difference: it returns copies of the observation arrays and of each info dict
    instead of deep copies of both. SB3 deep-copies the list of info dicts at every step, which costs about 90 us
    for 16 HalfCheetah envs (a few percent of a training run); a shallow copy of each dict costs about 2.

    The values inside an info dict are not copied: an env must not change a value it returned (an array it keeps and
    fills in place) after the step. Gymnasium's envs and sb3-icrl's build a new info dict with new values at each
    step; an env that reuses its arrays should be run in SB3's ``DummyVecEnv``.
    """

    def step_wait(self) -> VecEnvStepReturn:
        # SB3's loop, then shallow copies where it deep-copies
        for env_idx in range(self.num_envs):
            obs, self.buf_rews[env_idx], terminated, truncated, self.buf_infos[env_idx] = self.envs[env_idx].step(  # type: ignore[assignment]
                self.actions[env_idx]
            )
            self.buf_dones[env_idx] = terminated or truncated
            self.buf_infos[env_idx]["TimeLimit.truncated"] = truncated and not terminated
            if self.buf_dones[env_idx]:
                self.buf_infos[env_idx]["terminal_observation"] = obs
                obs, self.reset_infos[env_idx] = self.envs[env_idx].reset()
            self._save_obs(env_idx, obs)
        infos: list[dict[str, Any]] = [dict(info) for info in self.buf_infos]
        return (self._obs_from_buf(), np.copy(self.buf_rews), np.copy(self.buf_dones), infos)

    def _obs_from_buf(self) -> VecEnvObs:
        return dict_to_obs(self.observation_space, {key: np.copy(value) for key, value in self.buf_obs.items()})


def load_vec_normalize(path: str, venv: VecEnv) -> VecNormalize:
    """
    ``VecNormalize.load``, whose errors on a damaged file (a pickle cut short), on a pickle of something else and on
    the statistics of another env (observations of another shape) name neither the file nor the cause, and which
    takes the statistics of another env whose observations have the same shape (CartPole's for BiasedPendulum).

    :param path: The saved statistics
    :param venv: The env to wrap
    :return: The wrapper, with the statistics
    :raises ValueError: When the file does not unpickle, holds no ``VecNormalize``, or was saved for other spaces
    """
    try:
        with open(path, "rb") as file:
            saved = pickle.load(file)
    except (pickle.UnpicklingError, EOFError) as error:
        raise ValueError(
            f"The VecNormalize statistics {path} cannot be read ({type(error).__name__}: {error}): the file is cut short "
            "or damaged; restore it, or use a checkpoint of the run with its own rl_model_vecnormalize_<steps>_steps.pkl."
        ) from error
    if not isinstance(saved, VecNormalize):
        raise ValueError(
            f"The VecNormalize statistics {path} hold a {type(saved).__name__}, not VecNormalize statistics: the file was "
            "overwritten; restore it, or use a checkpoint of the run with its own rl_model_vecnormalize_<steps>_steps.pkl."
        )
    another_env = ValueError(
        f"The VecNormalize statistics {path} were saved for another env (observations {saved.observation_space}, "
        f"this env's are {venv.observation_space}): use the statistics saved with this model."
    )
    try:
        saved.set_venv(venv)  # (which asserts that the observations have the shape of the statistics)
    except AssertionError as error:
        raise another_env from error
    if not _same_observations(saved.observation_space, venv.observation_space):
        raise another_env
    return saved


def _same_observations(saved: spaces.Space, current: spaces.Space) -> bool:
    """
    Whether statistics saved with the observation space ``saved`` fit an env with the space ``current`` of the same
    shape: the same kind of space, values of the same kind (floats, integers), and the same bounds finite. The finite
    bounds themselves may differ (an env argument such as a speed limit moves them), as may the float
    width (float32 against float64): a shape that happens to match is told from another env by its bounds (CartPole's
    observations, of BiasedPendulum's shape, have finite bounds where BiasedPendulum's have none).

    :param saved: The observation space the statistics were saved with
    :param current: The observation space of the env they are to normalize
    :return: Whether they fit
    """
    if isinstance(saved, spaces.Dict) and isinstance(current, spaces.Dict):
        return saved.spaces.keys() == current.spaces.keys() and all(
            _same_observations(space, current.spaces[key]) for key, space in saved.spaces.items()
        )
    if isinstance(saved, spaces.Box) and isinstance(current, spaces.Box):
        return (
            saved.dtype is not None
            and current.dtype is not None
            and saved.dtype.kind == current.dtype.kind
            and all(
                np.array_equal(np.isfinite(before), np.isfinite(now))
                for before, now in ((saved.low, current.low), (saved.high, current.high))
            )
        )
    return type(saved) is type(current)
