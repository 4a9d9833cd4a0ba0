"""Logging the true constraint of training episodes (evaluation only: nothing here reaches the learner)."""

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


class TrueConstraintLogger(BaseCallback):
    """
    Tracks every finished training episode against the env's true cost (``info[true_cost_info_key]``, where the ICRL
    wrappers move it) and logs, at each rollout end, over the episodes that ended during that rollout:
    ``true/violation_rate`` (share of episodes with a true cost > 0) and ``true/feasible_reward`` (env reward summed
    until the first violation), plus ``true/episode_cost``.

    The env reward is ``info[env_reward_info_key]`` where present (GACL's wrapper keeps it there), else the raw reward
    (before ``VecNormalize``).

    :param true_cost_info_key: The info key of the true per-step cost
    :param env_reward_info_key: The info key of the env's own reward, when the learner's reward differs
    :param verbose: Verbosity level
    """

    def __init__(self, true_cost_info_key: str = "true_cost", env_reward_info_key: str = "env_reward", verbose: int = 0):
        super().__init__(verbose)
        self.true_cost_info_key = true_cost_info_key
        self.env_reward_info_key = env_reward_info_key
        #: One row per finished episode: ``(timesteps, violated, feasible_reward, episode_cost)``
        self.episodes: list[tuple[int, bool, float, float]] = []
        self._rollout_start = 0
        self._feasible = np.zeros(0)
        self._cost = np.zeros(0)
        self._violated = np.zeros(0, dtype=bool)

    def _on_training_start(self) -> None:
        n_envs = self.training_env.num_envs
        self._feasible, self._cost = np.zeros(n_envs), np.zeros(n_envs)
        self._violated = np.zeros(n_envs, dtype=bool)

    def _on_rollout_start(self) -> None:
        self._rollout_start = len(self.episodes)

    def _on_step(self) -> bool:
        infos, dones = self.locals["infos"], self.locals["dones"]
        normalize = getattr(self.model, "_vec_normalize_env", None)
        rewards = normalize.get_original_reward() if normalize is not None else self.locals["rewards"]
        for env_idx, (info, done) in enumerate(zip(infos, dones, strict=True)):
            if self.true_cost_info_key not in info:
                # The env reports no true cost: nothing to evaluate
                continue
            cost = float(np.sum(info[self.true_cost_info_key]))
            reward = float(info.get(self.env_reward_info_key, rewards[env_idx]))
            self._violated[env_idx] |= cost > 0
            self._cost[env_idx] += cost
            if not self._violated[env_idx]:
                self._feasible[env_idx] += reward
            if done:
                row = (
                    self.num_timesteps,
                    bool(self._violated[env_idx]),
                    float(self._feasible[env_idx]),
                    float(self._cost[env_idx]),
                )
                self.episodes.append(row)
                self._feasible[env_idx] = self._cost[env_idx] = 0.0
                self._violated[env_idx] = False
        return True

    def _on_rollout_end(self) -> None:
        recent = self.episodes[self._rollout_start :]
        if not recent:
            return
        self.logger.record("true/violation_rate", float(np.mean([row[1] for row in recent])))
        self.logger.record("true/feasible_reward", float(np.mean([row[2] for row in recent])))
        self.logger.record("true/episode_cost", float(np.mean([row[3] for row in recent])))
