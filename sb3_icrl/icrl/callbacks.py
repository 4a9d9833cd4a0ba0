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
    :param max_episodes: Rows kept in :attr:`episodes`: the most recent ones, trimmed at each rollout's start (a
        3M-step run on a 100-step env ends some 30,000 episodes a million steps; ``None`` keeps every row)
    :param verbose: Verbosity level
    """

    def __init__(
        self,
        true_cost_info_key: str = "true_cost",
        env_reward_info_key: str = "env_reward",
        max_episodes: int | None = 100_000,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        if max_episodes is not None and max_episodes < 1:
            raise ValueError(f"max_episodes must be at least 1, or None to keep every episode (got {max_episodes})")
        self.true_cost_info_key = true_cost_info_key
        self.env_reward_info_key = env_reward_info_key
        self.max_episodes = max_episodes
        #: One row per finished episode, the most recent ``max_episodes``: ``(timesteps, violated, feasible_reward,
        #: episode_cost)``
        self.episodes: list[tuple[int, bool, float, float]] = []
        self._rollout_start = 0
        self._feasible: list[float] = []
        self._cost: list[float] = []
        self._violated: list[bool] = []

    def _on_training_start(self) -> None:
        n_envs = self.training_env.num_envs
        self._feasible, self._cost = [0.0] * n_envs, [0.0] * n_envs
        self._violated = [False] * n_envs

    def _on_rollout_start(self) -> None:
        if self.max_episodes is not None and len(self.episodes) > self.max_episodes:
            del self.episodes[: len(self.episodes) - self.max_episodes]
        self._rollout_start = len(self.episodes)

    def _on_step(self) -> bool:
        infos = self.locals["infos"]
        normalize = getattr(self.model, "_vec_normalize_env", None)
        rewards = np.asarray(normalize.get_original_reward() if normalize is not None else self.locals["rewards"]).tolist()
        dones = np.asarray(self.locals["dones"]).tolist()
        feasible, episode_cost, violated = self._feasible, self._cost, self._violated
        # Python floats and lists, not NumPy: this runs every step, on a few envs, where NumPy's per-call cost dominates
        for env_idx, info in enumerate(infos):
            value = info.get(self.true_cost_info_key)
            if value is None:
                # The env reports no true cost: nothing to evaluate
                continue
            # (a float, NumPy's float64 included, as it is; a vector, one entry per constraint, summed)
            cost = value if isinstance(value, float) else float(np.sum(value))
            if cost > 0:
                violated[env_idx] = True
            episode_cost[env_idx] += cost
            if not violated[env_idx]:
                feasible[env_idx] += float(info.get(self.env_reward_info_key, rewards[env_idx]))
            if dones[env_idx]:
                self.episodes.append((self.num_timesteps, violated[env_idx], feasible[env_idx], episode_cost[env_idx]))
                feasible[env_idx] = episode_cost[env_idx] = 0.0
                violated[env_idx] = False
        return True

    def _on_rollout_end(self) -> None:
        recent = self.episodes[self._rollout_start :]
        if not recent:
            return
        self.logger.record("true/violation_rate", float(np.mean([row[1] for row in recent])))
        self.logger.record("true/feasible_reward", float(np.mean([row[2] for row in recent])))
        self.logger.record("true/episode_cost", float(np.mean([row[3] for row in recent])))
