"""Recording the learner's own ("nominal") state-action pairs, raw and grouped by trajectory, for constraint learning."""

from collections import deque
from dataclasses import dataclass

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize, unwrap_vec_wrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn


@dataclass(frozen=True)
class NominalTrajectory:
    """
    The pairs of one finished training episode, as the constraint model sees them.

    :param obs: Raw observation before each action, ``(T,) + obs_shape``
    :param acts: Action sent to the env at each step, ``(T,) + action_shape``
    """

    obs: np.ndarray
    acts: np.ndarray

    def __len__(self) -> int:
        return len(self.acts)


@dataclass(frozen=True)
class NominalData:
    """
    Nominal trajectories concatenated, in trajectory order (MECL's importance weights are per trajectory).

    :param obs: Observations, ``(N,) + obs_shape``
    :param acts: Actions, ``(N,) + action_shape``
    :param episode_lengths: Length of each trajectory, summing to ``N``
    """

    obs: np.ndarray
    acts: np.ndarray
    episode_lengths: np.ndarray

    def __len__(self) -> int:
        return len(self.acts)

    @classmethod
    def from_trajectories(cls, trajectories: list[NominalTrajectory]) -> "NominalData":
        """
        :param trajectories: At least one trajectory
        :return: The concatenation
        """
        if not trajectories:
            raise ValueError("No nominal trajectories to concatenate.")
        return cls(
            obs=np.concatenate([t.obs for t in trajectories]),
            acts=np.concatenate([t.acts for t in trajectories]),
            episode_lengths=np.array([len(t) for t in trajectories], dtype=np.int64),
        )


class TrajectoryRecorderVecEnvWrapper(VecEnvWrapper):
    """
    Records, for every sub-env, the raw observation before each step and the action sent, and keeps each episode
    as a :class:`NominalTrajectory` once it ends (unfinished episodes are dropped at ``reset``).

    It records nothing else: neither rewards nor the env's true cost, so the constraint learner cannot see them.
    It must sit below any ``VecNormalize`` so that it stores observations as the env returns them.

    :param venv: The env to wrap
    :param max_trajectories: How many finished trajectories to keep (oldest dropped first)
    """

    def __init__(self, venv: VecEnv, max_trajectories: int = 1000):
        if unwrap_vec_wrapper(venv, VecNormalize) is not None:
            raise ValueError(
                "TrajectoryRecorderVecEnvWrapper must record raw observations, but the env it wraps contains a "
                "VecNormalize: wrap the raw env and put VecNormalize on top."
            )
        if max_trajectories < 1:
            raise ValueError(f"`max_trajectories` must be >= 1, got {max_trajectories}.")
        super().__init__(venv)
        self.finished: deque[NominalTrajectory] = deque(maxlen=max_trajectories)
        # The pairs of all envs, one array per step, from the first step of the oldest unfinished episode on: one
        # append per step whatever the number of envs; an episode's rows are gathered once, when it ends
        self._step_obs: list[np.ndarray] = []
        self._step_acts: list[np.ndarray] = []
        self._first_kept_step = 0
        self._episode_starts = np.zeros(self.num_envs, dtype=np.int64)
        self._n_steps = 0
        self._last_obs: np.ndarray | None = None
        self._actions: np.ndarray | None = None

    def reset(self) -> VecEnvObs:
        obs = self.venv.reset()
        if isinstance(obs, (dict, tuple)):
            raise TypeError("TrajectoryRecorderVecEnvWrapper takes flat observations (Box or Discrete), not Dict/Tuple.")
        self._last_obs = np.array(obs, copy=True)
        self._step_obs, self._step_acts = [], []
        self._first_kept_step = self._n_steps = 0
        self._episode_starts[:] = 0
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        if self._last_obs is None:
            raise RuntimeError("Call reset() on the TrajectoryRecorderVecEnvWrapper before step().")
        self._actions = np.array(actions, copy=True)
        self.venv.step_async(actions)

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        assert self._last_obs is not None and self._actions is not None, "step_wait() called without step_async()"
        self._step_obs.append(self._last_obs)
        self._step_acts.append(self._actions)
        self._n_steps += 1
        if dones.any():
            ended = np.flatnonzero(dones)
            starts = self._episode_starts[ended] - self._first_kept_step
            first = int(starts.min())
            # One stack for all the episodes that end here, sliced per env
            obs_block, acts_block = np.stack(self._step_obs[first:]), np.stack(self._step_acts[first:])
            for env_idx, start in zip(ended, starts - first, strict=True):
                self.finished.append(NominalTrajectory(obs_block[start:, env_idx].copy(), acts_block[start:, env_idx].copy()))
            self._episode_starts[ended] = self._n_steps
            unneeded = int(self._episode_starts.min()) - self._first_kept_step
            del self._step_obs[:unneeded], self._step_acts[:unneeded]
            self._first_kept_step += unneeded
        # After an auto-reset the returned obs is the new episode's first one
        self._last_obs = np.array(obs, copy=True)
        self._actions = None
        return obs, rewards, dones, infos

    def pop_trajectories(self, max_trajectories: int | None = None) -> list[NominalTrajectory]:
        """
        Take the finished trajectories recorded since the last call (the most recent ones, oldest first).

        :param max_trajectories: Keep at most this many of the most recent (``None``: all)
        :return: The trajectories; the store is emptied
        """
        trajectories = list(self.finished)
        self.finished.clear()
        if max_trajectories is not None:
            trajectories = trajectories[-max_trajectories:] if max_trajectories > 0 else []
        return trajectories
