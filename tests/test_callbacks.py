import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.callbacks import EpisodeCostRecorder
from sb3_icrl.common.envs import ConstrainedCorridorEnv

TINY = dict(n_steps=32, batch_size=16, n_epochs=1, policy_kwargs=dict(net_arch=[8]), seed=0)


def test_recorder_agrees_with_ppolagrangian_episode_costs():
    recorder = EpisodeCostRecorder()
    env = make_vec_env(ConstrainedCorridorEnv, n_envs=2, seed=0, env_kwargs=dict(safe_limit=0))
    model = PPOLagrangian("MlpPolicy", env, **TINY).learn(32 * 2 * 3, callback=recorder)
    episodes = recorder.recent(100)
    assert len(episodes) == len(model.ep_cost_buffer) == 2 * (3 * 32 // 20)  # 2 envs, 96 steps each, 20-step episodes
    np.testing.assert_array_equal(np.sort(episodes[:, 2]), np.sort(np.concatenate(list(model.ep_cost_buffer))))
    np.testing.assert_array_equal(episodes[:, 3], episodes[:, 2] > 0)
    assert np.all(np.isfinite(episodes[:, 1])), "rewards come from the Monitor"


def test_recorder_needs_the_cost_key():
    with pytest.raises(KeyError, match="needs info\\['true_cost'\\]"):
        PPO("MlpPolicy", ConstrainedCorridorEnv(), **TINY).learn(32, callback=EpisodeCostRecorder("true_cost"))
