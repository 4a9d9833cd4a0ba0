import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

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
    result = evaluate_constraint(FixedAction(2), ConstrainedCorridorEnv(), n_episodes=2)
    np.testing.assert_allclose(result.episode_rewards, [15.5, 15.5])
    np.testing.assert_allclose(result.feasible_rewards, [2.1, 2.1])  # 0.1 + ... + 0.6, before the first violation
    np.testing.assert_array_equal(result.episode_costs, [14.0, 14.0])
    assert result.violation_rate == 1.0
    assert result.summary()["mean_feasible_reward"] == pytest.approx(2.1)

    safe = evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_episodes=1)
    assert safe.violation_rate == 0.0 and safe.mean_reward == 0.0 and safe.mean_cost == 0.0


def test_episode_count_over_several_envs_and_raw_rewards_under_vecnormalize():
    env = VecNormalize(DummyVecEnv([ConstrainedCorridorEnv] * 2))
    result = evaluate_constraint(FixedAction(2), env, n_episodes=3)
    assert len(result.violations) == 3
    np.testing.assert_allclose(result.episode_rewards, 15.5, rtol=1e-6)  # raw, not normalised
    assert env.training, "the normalisation statistics must be unfrozen again afterwards"


def test_errors():
    with pytest.raises(ValueError, match="n_episodes"):
        evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), n_episodes=0)
    with pytest.raises(KeyError, match="true cost in info\\['danger'\\]"):
        evaluate_constraint(FixedAction(1), ConstrainedCorridorEnv(), cost_info_key="danger")
