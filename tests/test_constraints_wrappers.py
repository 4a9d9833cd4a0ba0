"""The learned-cost and GACL reward wrappers: what the learner sees, on which (s, a), and the errors."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.costs import CostError
from sb3_icrl.common.envs import ConstrainedCorridorEnv
from sb3_icrl.constraints import FeasibilityNet, GACLRewardWrapper, LearnedCostVecEnvWrapper

TRUE_COST = 1000.0  # far from any learned cost, so a leak cannot go unnoticed


class TrueCostCorridor(ConstrainedCorridorEnv):
    """The corridor (5-step episodes by default) whose info["cost"] is always TRUE_COST."""

    def __init__(self, max_steps: int = 5):
        super().__init__(max_steps=max_steps)

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        info["cost"] = TRUE_COST
        return obs, reward, terminated, truncated, info


class RecordingCost:
    """A learned cost that records its calls: 0.25 + 0.01 * action (distinct from the true cost)."""

    def __init__(self):
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        self.calls.append((obs.copy(), np.asarray(actions).copy()))
        return 0.25 + 0.01 * np.asarray(actions, dtype=np.float32)


def make_venv(n_envs: int = 2) -> DummyVecEnv:
    return DummyVecEnv([TrueCostCorridor for _ in range(n_envs)])


def test_learned_cost_replaces_the_true_cost_on_the_raw_obs_before_the_step():
    cost_fn = RecordingCost()
    env = LearnedCostVecEnvWrapper(make_venv(), cost_fn)
    obs_before = env.reset()
    rng = np.random.default_rng(0)
    for _ in range(12):  # several auto-resets (episodes of 5 steps)
        actions = rng.integers(0, 3, size=2)
        new_obs, _, _, infos = env.step(actions)
        obs_seen, actions_seen = cost_fn.calls[-1]
        np.testing.assert_array_equal(obs_seen, obs_before)
        np.testing.assert_array_equal(actions_seen, actions)
        for info, action in zip(infos, actions, strict=True):
            assert info["cost"] == pytest.approx(0.25 + 0.01 * action)
            assert info["cost"] != TRUE_COST
            assert info["true_cost"] == TRUE_COST
        obs_before = new_obs  # after a done this is the new episode's first observation
    assert len(cost_fn.calls) == 12  # one batched call per step


def test_ppo_lagrangian_trains_on_the_learned_cost_only():
    net = FeasibilityNet(2, 3, discrete_actions=True, hidden_sizes=(4,), normalize_input=False)
    # One env (the buffer's flattening keeps the step order) and no truncation (PPOLagrangian bootstraps the cost there)
    env = LearnedCostVecEnvWrapper(DummyVecEnv([lambda: TrueCostCorridor(max_steps=100)]), net.cost)
    model = PPOLagrangian("MlpPolicy", env, n_steps=8, batch_size=8, n_epochs=1, policy_kwargs=dict(net_arch=[8]), seed=0)
    model.learn(16)
    costs = model.rollout_buffer.costs
    assert np.all((costs >= 0.0) & (costs <= 1.0))  # learned costs 1 - phi, never the true 1000
    buffer_obs = model.rollout_buffer.observations.reshape(-1, 2)
    buffer_actions = model.rollout_buffer.actions.reshape(-1)
    np.testing.assert_allclose(costs.reshape(-1), net.cost(buffer_obs, buffer_actions), rtol=1e-5)


def test_wrapper_below_vec_normalize_sees_raw_obs_and_above_is_refused():
    cost_fn = RecordingCost()
    env = VecNormalize(LearnedCostVecEnvWrapper(make_venv(), cost_fn))
    env.reset()
    env.step(np.array([2, 2]))
    env.step(np.array([2, 2]))
    np.testing.assert_allclose(cost_fn.calls[-1][0][0], [0.1, 0.2])  # raw corridor obs after one step right
    with pytest.raises(ValueError, match=r"contains a VecNormalize.*VecNormalize\(LearnedCostVecEnvWrapper\(venv"):
        LearnedCostVecEnvWrapper(VecNormalize(make_venv()), cost_fn)


def test_learned_cost_errors():
    env = LearnedCostVecEnvWrapper(make_venv(), lambda obs, actions: np.zeros(3))
    env.reset()
    with pytest.raises(CostError, match=r"cost_fn returned costs of shape \(3,\), expected \(2,\)"):
        env.step(np.array([0, 0]))
    with pytest.raises(TypeError, match="must be callable"):
        LearnedCostVecEnvWrapper(make_venv(), cost_fn=0.5)
    with pytest.raises(RuntimeError, match="Call reset"):
        LearnedCostVecEnvWrapper(make_venv(), RecordingCost()).step(np.array([0, 0]))


def test_existing_true_cost_key_is_not_overwritten():
    class AlreadyTrueCost(TrueCostCorridor):
        def step(self, action):
            obs, reward, terminated, truncated, info = super().step(action)
            info["true_cost"] = 0.0
            return obs, reward, terminated, truncated, info

    env = LearnedCostVecEnvWrapper(DummyVecEnv([AlreadyTrueCost]), RecordingCost())
    env.reset()
    with pytest.raises(ValueError, match=r"already reports info\['true_cost'\]"):
        env.step(np.array([1]))


def test_gacl_reward_adds_clipped_log_discriminator():
    calls = []

    def discriminator(obs, actions):
        calls.append(obs.copy())
        return np.where(np.asarray(actions) == 2, 0.5, 0.0)  # D = 0 must not give -inf

    plain, wrapped = make_venv(), GACLRewardWrapper(make_venv(), discriminator, eps=1e-3)
    plain_obs, wrapped_obs = plain.reset(), wrapped.reset()
    for actions in ([2, 0], [2, 1], [0, 2]):
        _, env_rewards, _, _ = plain.step(np.array(actions))
        wrapped_obs, rewards, _, infos = wrapped.step(np.array(actions))
        np.testing.assert_array_equal(calls[-1], plain_obs)
        expected = env_rewards + np.where(np.array(actions) == 2, np.log(0.5), np.log(1e-3))
        np.testing.assert_allclose(rewards, expected, rtol=1e-6)
        for info, env_reward in zip(infos, env_rewards, strict=True):
            assert info["env_reward"] == pytest.approx(env_reward)
            assert "cost" not in info and info["true_cost"] == TRUE_COST
        plain_obs = wrapped_obs


def test_gacl_discriminator_errors():
    env = GACLRewardWrapper(make_venv(), lambda obs, actions: np.array([0.5, 1.5]))
    env.reset()
    with pytest.raises(ValueError, match=r"probabilities in \[0, 1\], got \[0.5, 1.5\]"):
        env.step(np.array([0, 0]))
    env = GACLRewardWrapper(make_venv(), lambda obs, actions: np.array([0.5]))
    env.reset()
    with pytest.raises(ValueError, match=r"returned shape \(1,\), expected \(2,\)"):
        env.step(np.array([0, 0]))
    with pytest.raises(ValueError, match=r"`eps` must be in \(0, 1\)"):
        GACLRewardWrapper(make_venv(), lambda obs, actions: obs, eps=0.0)


class EndsOnAction(gym.Env):
    """Action 1 ends the episode (terminated); otherwise the time limit truncates it after 3 steps. Reward 0."""

    observation_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.steps = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action):
        self.steps += 1
        return np.zeros(1, dtype=np.float32), 0.0, bool(action == 1), self.steps >= 3, {}


@pytest.mark.parametrize("gamma", [0.9, 0.0])
def test_gacl_termination_gamma_charges_the_final_pair_for_ever_on_termination_only(gamma):
    """Terminated: log D * (1 + gamma / (1 - gamma)) on the last step; truncated and other steps: log D."""
    log_d = np.log(0.5)
    env = GACLRewardWrapper(
        DummyVecEnv([EndsOnAction, EndsOnAction]), lambda obs, actions: np.full(2, 0.5), termination_gamma=gamma
    )
    env.reset()
    # env 0 terminates at its first step; env 1 goes on and is truncated at its third
    _, rewards, dones, infos = env.step(np.array([1, 0]))
    assert dones.tolist() == [True, False]
    np.testing.assert_allclose(rewards, [log_d / (1.0 - gamma), log_d], rtol=1e-6)
    env.step(np.array([0, 0]))
    _, rewards, dones, infos = env.step(np.array([0, 0]))
    assert dones.tolist() == [False, True] and infos[1]["TimeLimit.truncated"]
    np.testing.assert_allclose(rewards, [log_d, log_d], rtol=1e-6)
    # Without it (the paper's GACL) a terminated step earns log D like any other
    plain = GACLRewardWrapper(DummyVecEnv([EndsOnAction]), lambda obs, actions: np.full(1, 0.5))
    plain.reset()
    np.testing.assert_allclose(plain.step(np.array([1]))[1], [log_d], rtol=1e-6)
    with pytest.raises(ValueError, match="termination_gamma"):
        GACLRewardWrapper(DummyVecEnv([EndsOnAction]), lambda obs, actions: np.full(1, 0.5), termination_gamma=1.0)
