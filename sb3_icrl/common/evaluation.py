"""Evaluation against the true constraint (for reporting only: never for training or model selection)."""

import warnings
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize

#: The per-episode arrays of :class:`ConstraintEvaluation`, in order
EPISODE_FIELDS = ("episode_rewards", "episode_costs", "feasible_rewards", "violations", "episode_lengths")
#: Episode outcomes that driving envs flag in the last step's info; their rates are reported when an env sets them
OUTCOME_KEYS = ("collision", "off_road", "time_out", "goal_reached")
#: The key of each outcome's rate in :attr:`ConstraintEvaluation.outcome_rates`, run results and reports
OUTCOME_RATE_KEYS = {key: f"{key}_rate" for key in OUTCOME_KEYS}
#: The info key where an env with several constraints reports each one's true cost of the step, ``{name: cost}`` (the
#: driving envs: ``{"velocity": ..., "distance": ...}``), besides their combined cost in ``info["cost"]``
CONSTRAINT_COSTS_INFO_KEY = "constraint_costs"


#: The start of each constraint's violation-rate key (see :func:`constraint_violation_key`)
CONSTRAINT_VIOLATION_PREFIX = "violation_rate_"


def constraint_violation_key(name: str) -> str:
    """
    :param name: A constraint's name in ``info[CONSTRAINT_COSTS_INFO_KEY]``
    :return: The key of its violation rate in :attr:`ConstraintEvaluation.constraint_violation_rates`, run results and
        reports, e.g. ``"violation_rate_velocity"``
    """
    return f"{CONSTRAINT_VIOLATION_PREFIX}{name}"


@dataclass
class ConstraintEvaluation:
    """
    Per-episode results and their means.

    :param episode_rewards: Undiscounted return of each episode
    :param episode_costs: Sum of the true per-step costs of each episode
    :param feasible_rewards: Reward summed until (excluding) the first step that breaks the constraint
    :param violations: Whether each episode broke the constraint at least once
    :param episode_lengths: Steps per episode
    :param outcomes: For envs that flag them (driving): ``{key: whether each episode ended that way}`` for the
        :data:`OUTCOME_KEYS` present in every episode's last info
    :param constraint_violations: For envs that report each constraint's cost (``info[CONSTRAINT_COSTS_INFO_KEY]``):
        ``{name: whether each episode broke that constraint at least once}``
    """

    episode_rewards: np.ndarray
    episode_costs: np.ndarray
    feasible_rewards: np.ndarray
    violations: np.ndarray
    episode_lengths: np.ndarray
    outcomes: dict[str, np.ndarray] = field(default_factory=dict)
    constraint_violations: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def mean_reward(self) -> float:
        return float(np.mean(self.episode_rewards))

    @property
    def mean_feasible_reward(self) -> float:
        return float(np.mean(self.feasible_rewards))

    @property
    def violation_rate(self) -> float:
        return float(np.mean(self.violations))

    @property
    def mean_cost(self) -> float:
        return float(np.mean(self.episode_costs))

    @property
    def outcome_rates(self) -> dict[str, float]:
        """``{"<key>_rate": share of episodes}`` for each flagged outcome (empty for envs without outcome flags)."""
        return {OUTCOME_RATE_KEYS[key]: float(np.mean(flags)) for key, flags in self.outcomes.items()}

    @property
    def constraint_violation_rates(self) -> dict[str, float]:
        """
        ``{"violation_rate_<name>": share of episodes that broke that constraint}`` for each constraint the env reports
        apart (empty for envs that report only the combined cost). An episode that breaks two constraints counts in
        both, so the rates may sum to more than :attr:`violation_rate`.
        """
        return {constraint_violation_key(name): float(np.mean(flags)) for name, flags in self.constraint_violations.items()}

    def summary(self) -> dict[str, float]:
        """The means, as plain floats (for JSON and loggers)."""
        return {
            "mean_reward": self.mean_reward,
            "mean_feasible_reward": self.mean_feasible_reward,
            "violation_rate": self.violation_rate,
            "mean_cost": self.mean_cost,
            "n_episodes": float(len(self.violations)),
            **self.outcome_rates,
            **self.constraint_violation_rates,
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            **{key: np.asarray(getattr(self, key)).tolist() for key in EPISODE_FIELDS},
            "outcomes": {key: np.asarray(flags).tolist() for key, flags in self.outcomes.items()},
            "constraint_violations": {name: np.asarray(flags).tolist() for name, flags in self.constraint_violations.items()},
        }


class EpisodeAccumulator:
    """
    Sums each sub-env's steps into the benchmark's per-episode metrics, in the order episodes finish: what
    :func:`evaluate_constraint` and ``enjoy`` both measure.

    :param n_envs: Number of sub-envs stepped together
    :param cost_info_key: The info key of the true per-step cost
    """

    def __init__(self, n_envs: int, cost_info_key: str = "cost"):
        self.cost_info_key = cost_info_key
        self.results: dict[str, list] = {key: [] for key in EPISODE_FIELDS}
        self._outcomes: dict[str, list[bool | None]] = {key: [] for key in OUTCOME_KEYS}
        self._rewards, self._costs, self._feasible, self._lengths = (np.zeros(n_envs) for _ in range(4))
        self._violated = np.zeros(n_envs, dtype=bool)
        # Per constraint the env reports apart: each episode's flag (None: not reported in that episode), and the
        # sub-envs' running episodes (reported in them yet, broken in them yet)
        self._constraint_flags: dict[str, list[bool | None]] = {}
        self._constraint_reported: dict[str, np.ndarray] = {}
        self._constraint_violated: dict[str, np.ndarray] = {}

    def add(self, idx: int, reward: float, info: dict[str, Any]) -> None:
        """
        :param idx: The sub-env
        :param reward: Its raw reward for the step
        :param info: Its info for the step (with the true cost)
        """
        if self.cost_info_key not in info:
            raise KeyError(f"Evaluation needs the true cost in info[{self.cost_info_key!r}]; the env reports {sorted(info)}.")
        step_cost = float(np.sum(info[self.cost_info_key]))
        self._violated[idx] |= step_cost > 0
        self._rewards[idx] += reward
        self._costs[idx] += step_cost
        self._lengths[idx] += 1
        if not self._violated[idx]:
            self._feasible[idx] += reward
        for name, cost in (info.get(CONSTRAINT_COSTS_INFO_KEY) or {}).items():
            if name not in self._constraint_flags:
                # The episodes that ended before the env first reported it did not report it
                self._constraint_flags[name] = [None] * len(self.results["violations"])
                self._constraint_reported[name] = np.zeros(len(self._violated), dtype=bool)
                self._constraint_violated[name] = np.zeros(len(self._violated), dtype=bool)
            self._constraint_reported[name][idx] = True
            self._constraint_violated[name][idx] |= float(np.sum(cost)) > 0

    def end_episode(self, idx: int, info: dict[str, Any]) -> tuple[float, float, float, bool, float]:
        """
        Record sub-env ``idx``'s finished episode and start its next one.

        :param idx: The sub-env
        :param info: Its last step's info (for the outcome flags)
        :return: The episode's reward, cost, feasible reward, violation and length
        """
        episode = (
            float(self._rewards[idx]),
            float(self._costs[idx]),
            float(self._feasible[idx]),
            bool(self._violated[idx]),
            float(self._lengths[idx]),
        )
        for key, value in zip(EPISODE_FIELDS, episode, strict=True):
            self.results[key].append(value)
        for key, flags in self._outcomes.items():
            flags.append(bool(info[key]) if key in info else None)
        for name, constraint_flags in self._constraint_flags.items():
            reported = self._constraint_reported[name]
            constraint_flags.append(bool(self._constraint_violated[name][idx]) if reported[idx] else None)
            reported[idx] = self._constraint_violated[name][idx] = False
        self._rewards[idx] = self._costs[idx] = self._feasible[idx] = self._lengths[idx] = 0.0
        self._violated[idx] = False
        return episode

    def evaluation(self) -> ConstraintEvaluation:
        """The finished episodes; outcome flags where every episode's last info had them, and each constraint's
        violations where every episode reported it."""
        flagged = {key: np.array(flags, dtype=bool) for key, flags in self._outcomes.items() if None not in flags}
        per_constraint = {
            name: np.array(flags, dtype=bool) for name, flags in self._constraint_flags.items() if flags and None not in flags
        }
        return ConstraintEvaluation(
            **{key: np.array(value) for key, value in self.results.items()},
            outcomes=flagged,
            constraint_violations=per_constraint,
        )


def evaluate_constraint(
    model: BaseAlgorithm,
    env: gym.Env | VecEnv,
    n_eval_episodes: int = 10,
    deterministic: bool = True,
    cost_info_key: str = "cost",
    seed: int | None = None,
    *,
    n_episodes: int | None = None,
) -> ConstraintEvaluation:
    """
    Run a policy and measure the paper's metrics against the true cost in ``info[cost_info_key]``: the
    constraint violation rate (share of episodes with any cost > 0) and the feasible cumulative reward
    (reward summed until the first violation), plus mean reward and mean episode cost.

    With a ``VecNormalize`` env, normalisation statistics are frozen for the evaluation and the raw rewards are used.

    :param model: Anything with SB3's ``predict``
    :param env: The evaluation env (a gymnasium env is wrapped in a ``DummyVecEnv``)
    :param n_eval_episodes: Episodes to run (spread over the sub-envs), as SB3's ``evaluate_policy``
    :param deterministic: Whether to use deterministic actions
    :param cost_info_key: The info key of the true per-step cost
    :param seed: Optional seed for the env resets
    :param n_episodes: Deprecated name of ``n_eval_episodes``
    :return: Per-episode results
    """
    if n_episodes is not None:
        warnings.warn(
            "evaluate_constraint(n_episodes=...) is deprecated: use n_eval_episodes, as SB3's evaluate_policy.",
            DeprecationWarning,
            stacklevel=2,
        )
    argument = "n_eval_episodes" if n_episodes is None else "n_episodes"  # the name the caller used
    n_episodes = n_eval_episodes if n_episodes is None else n_episodes
    if n_episodes < 1:
        raise ValueError(f"`{argument}` must be >= 1, got {n_episodes}.")
    vec_env = env if isinstance(env, VecEnv) else DummyVecEnv([lambda: env])  # type: ignore[list-item, return-value]
    normalize = vec_env if isinstance(vec_env, VecNormalize) else None
    if normalize is not None:
        was_training, normalize.training = normalize.training, False
    if seed is not None:
        vec_env.seed(seed)
    n_envs = vec_env.num_envs
    # Episodes per sub-env fixed upfront, as SB3's evaluate_policy does, so short episodes do not bias the sample
    targets = np.array([(n_episodes + i) // n_envs for i in range(n_envs)])
    counts = np.zeros(n_envs, dtype=int)
    episodes = EpisodeAccumulator(n_envs, cost_info_key)

    observations = vec_env.reset()
    states, episode_starts = None, np.ones(n_envs, dtype=bool)
    while (counts < targets).any():
        actions, states = model.predict(
            observations,  # type: ignore[arg-type]
            state=states,
            episode_start=episode_starts,
            deterministic=deterministic,
        )
        observations, step_rewards, dones, infos = vec_env.step(actions)
        raw_rewards = normalize.get_original_reward() if normalize is not None else step_rewards
        for idx in range(n_envs):
            if counts[idx] >= targets[idx]:
                continue
            episodes.add(idx, float(raw_rewards[idx]), infos[idx])
            if dones[idx]:
                episodes.end_episode(idx, infos[idx])
                counts[idx] += 1
        episode_starts = dones
    if normalize is not None:
        normalize.training = was_training
    return episodes.evaluation()
