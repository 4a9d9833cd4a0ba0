"""Callbacks for constrained RL."""

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


class EpisodeCostRecorder(BaseCallback):
    """
    Records every finished training episode as ``(timesteps, reward, cost, violated)``, with the reward from SB3's
    ``Monitor`` (raw, before any ``VecNormalize``) and the cost summed from ``info[cost_info_key]``. Works with any
    on-policy or off-policy algorithm, since it only reads ``infos`` and ``dones``.

    Pass the key of the *true* cost here for reporting; a learner must not be driven by it.

    :param cost_info_key: The info key holding the per-step cost to sum
    :param verbose: Verbosity level
    """

    def __init__(self, cost_info_key: str = "cost", verbose: int = 0):
        super().__init__(verbose)
        self.cost_info_key = cost_info_key
        self.episodes: list[tuple[int, float, float, bool]] = []
        self._costs: np.ndarray | None = None

    def _on_training_start(self) -> None:
        self._costs = np.zeros(self.training_env.num_envs)

    def _on_step(self) -> bool:
        assert self._costs is not None
        for env_idx, (info, done) in enumerate(zip(self.locals["infos"], self.locals["dones"], strict=True)):
            if self.cost_info_key not in info:
                raise KeyError(f"EpisodeCostRecorder needs info[{self.cost_info_key!r}]; the env reports {sorted(info)}.")
            self._costs[env_idx] += float(np.sum(info[self.cost_info_key]))
            if done:
                reward = float(info["episode"]["r"]) if "episode" in info else float("nan")
                cost = float(self._costs[env_idx])
                self.episodes.append((self.num_timesteps, reward, cost, cost > 0))
                self._costs[env_idx] = 0.0
        return True

    def recent(self, n_episodes: int) -> np.ndarray:
        """The last ``n_episodes`` as an array of rows ``(timesteps, reward, cost, violated)``."""
        return np.array(self.episodes[-n_episodes:], dtype=np.float64).reshape(-1, 4)
