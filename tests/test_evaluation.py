import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import sb3_icrl  # noqa: F401  (registers the envs)
from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.common.evaluation import evaluate_constraint


class FixedAction:
    """A policy with SB3's predict signature that always takes the same action."""

    def __init__(self, action: int):
        self.action = action

    def predict(self, observations, state=None, episode_start=None, deterministic=True):
        return np.full(len(observations), self.action), state


def test_metrics_match_hand_computation():
    # Always right on the corridor: positions 1..10 then 10; reward x/10; cost from position 7 (step 7) on
    result = evaluate_constraint(FixedAction(2), ConstrainedCorridorEnv(), n_eval_episodes=2)
    np.testing.assert_allclose(result.episode_rewards, [15.5, 15.5])
    np.testing.assert_allclose(result.feasible_rewards, [2.1, 2.1])  # 0.1 + ... + 0.6, before the first violation
    np.testing.assert_array_equal(result.episode_costs, [14.0, 14.0])
    assert result.violation_rate == 1.0
    assert result.summary()["mean_feasible_reward"] == pytest.approx(2.1)

    safe = evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_eval_episodes=1)
    assert safe.violation_rate == 0.0 and safe.mean_reward == 0.0 and safe.mean_cost == 0.0


def test_episode_count_over_several_envs_and_raw_rewards_under_vecnormalize():
    env = VecNormalize(DummyVecEnv([ConstrainedCorridorEnv] * 2))
    result = evaluate_constraint(FixedAction(2), env, n_eval_episodes=3)
    assert len(result.violations) == 3
    np.testing.assert_allclose(result.episode_rewards, 15.5, rtol=1e-6)  # raw, not normalised
    assert env.training, "the normalisation statistics must be unfrozen again afterwards"


def test_the_old_episode_count_name_still_works_and_says_it_is_deprecated():
    with pytest.warns(DeprecationWarning, match="use n_eval_episodes"):
        result = evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_episodes=2)
    assert len(result.violations) == 2
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="`n_episodes` must be >= 1"):
        evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_episodes=0)  # the error names what was passed


def test_errors():
    with pytest.raises(ValueError, match="n_eval_episodes"):
        evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_eval_episodes=0)
    with pytest.raises(KeyError, match="true cost in info\\['danger'\\]"):
        evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), cost_info_key="danger")


class _ConstantPolicy:
    def __init__(self, action: np.ndarray):
        self.action = action

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.tile(self.action, (len(observation), 1)), None


def test_driving_outcome_rates():
    env = gym.make("sb3_icrl/HighwayVelocity-v0")
    # Full steering: every episode ends off the road (or in a collision on the way), never at the goal
    result = evaluate_constraint(_ConstantPolicy(np.array([0.0, 1.0], dtype=np.float32)), env, n_eval_episodes=3, seed=0)
    assert set(result.outcomes) == {"collision", "off_road", "time_out", "goal_reached"}
    flags = np.stack([result.outcomes[key] for key in ("collision", "off_road", "time_out", "goal_reached")])
    assert flags.shape == (4, 3) and flags.any(axis=0).all()  # each episode ends one of the four ways
    assert result.outcomes["off_road"].all() and not result.outcomes["goal_reached"].any()
    assert result.summary()["off_road_rate"] == 1.0 and result.summary()["goal_reached_rate"] == 0.0
    assert result.to_dict()["outcomes"]["off_road"] == [True, True, True]
    # Envs without outcome flags report none
    corridor = evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_eval_episodes=1)
    assert corridor.outcomes == {} and "collision_rate" not in corridor.summary()
