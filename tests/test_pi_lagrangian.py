"""PI-Lagrangian on the grid world: safe goal-reaching policies, the multiplier's role, SB3-like API, persistence."""

import os

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

import sb3_icrl.envs  # noqa: F401
from sb3_icrl.envs import MAPS
from sb3_icrl.pi_lagrangian import PILagrangian


def make_grid(map_name: str, **kwargs) -> gym.Env:
    return gym.make("sb3_icrl/GridWorld-v0", map_name=map_name, **kwargs)


def rollout(model: PILagrangian, env: gym.Env) -> tuple[float, bool, int]:
    """Run the deterministic policy for one episode: (summed true cost, reached the goal, length)."""
    obs, _ = env.reset(seed=0)
    total_cost, steps = 0.0, 0
    while True:
        action, _ = model.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        total_cost += info["cost"]
        steps += 1
        if terminated or truncated:
            return total_cost, terminated, steps


@pytest.mark.parametrize("map_name", list(MAPS))
def test_lagrangian_avoids_unsafe_cells_and_plain_pi_does_not(map_name):
    lagrangian = PILagrangian(make_grid(map_name), lagrange_init=0.0, lagrange_lr=0.5).learn()
    cost, reached, _ = rollout(lagrangian, make_grid(map_name))
    assert reached and cost == 0.0
    # The multiplier had to grow from 0: the first policy (lambda = 0) crossed unsafe cells
    assert lagrangian.history[0]["episode_cost"] > 0 and lagrangian.lagrange_multiplier > 0

    plain = PILagrangian(make_grid(map_name), lagrange_init=0.0, lagrange_lr=0.0).learn()
    cost, reached, _ = rollout(plain, make_grid(map_name))
    assert reached and cost > 0.0
    assert plain.lagrange_multiplier == 0.0


def test_budget_allows_violations():
    # The shortest path crosses the wall once: a budget of 1 costly step per episode allows it
    model = PILagrangian(make_grid("wall"), cost_budget=1.0, lagrange_init=0.0, lagrange_lr=0.5).learn()
    cost, reached, length = rollout(model, make_grid("wall"))
    assert reached and cost == 1.0 and length == 6 and model.lagrange_multiplier == 0.0


def test_table_returns_match_monte_carlo_with_slip():
    env = make_grid("zigzag", slip_prob=0.1)
    model = PILagrangian(env, lagrange_init=0.0, lagrange_lr=0.5, seed=0).learn(total_iterations=50)
    table_reward, table_cost = model.episode_returns()
    vec_env = model.get_env()
    vec_env.seed(0)
    obs = vec_env.reset()
    costs, rewards, episode_cost, episode_reward = [], [], 0.0, 0.0
    while len(costs) < 400:
        actions, _ = model.predict(obs)
        obs, reward, done, infos = vec_env.step(actions)
        episode_cost += infos[0]["cost"]
        episode_reward += float(reward[0])
        if done[0]:
            costs.append(episode_cost)
            rewards.append(episode_reward)
            episode_cost = episode_reward = 0.0
    assert np.mean(costs) == pytest.approx(table_cost, abs=4 * np.std(costs) / 20 + 1e-3)
    assert np.mean(rewards) == pytest.approx(table_reward, abs=4 * np.std(rewards) / 20 + 1e-3)


def test_custom_cost_table():
    env = make_grid("square")
    # A zero cost: nothing to avoid, so the agent takes the diagonal through the square
    free = PILagrangian(env, cost_table=np.zeros((49, 8))).learn()
    assert rollout(free, make_grid("square"))[0] > 0
    # The true cost given by hand: the same as the default
    true_cost = env.unwrapped.C.copy()
    model = PILagrangian(make_grid("square")).learn()
    by_hand = PILagrangian(make_grid("square"), cost_table=true_cost).learn()
    np.testing.assert_array_equal(model.policy_table, by_hand.policy_table)
    with pytest.raises(ValueError, match="shape"):
        by_hand.set_cost_table(np.zeros((49, 4)))


def test_predict_is_batched_like_sb3():
    model = PILagrangian("sb3_icrl/GridWorldZigzag-v0").learn()
    action, state = model.predict(0)
    assert isinstance(action, np.ndarray) and action.shape == () and state is None
    actions, _ = model.predict(np.array([0, 8, 16]))
    assert actions.shape == (3,)
    np.testing.assert_array_equal(actions, model.policy_table[[0, 8, 16]])
    # VecEnv observations
    vec_env = DummyVecEnv([lambda: make_grid("zigzag")] * 2)
    actions, _ = model.predict(vec_env.reset(), episode_start=np.ones(2, dtype=bool))
    assert actions.shape == (2,)
    for bad in (-1, 49, np.array([0.5])):
        with pytest.raises(ValueError, match=r"0\.\.48"):
            model.predict(bad)


def test_stochastic_predict_picks_among_optimal_actions():
    model = PILagrangian(make_grid("big-square"), seed=3).learn()
    obs = np.zeros(200, dtype=np.int64)  # the start: several moves are optimal there
    actions, _ = model.predict(obs, deterministic=False)
    q_start = model.q_values[0]
    optimal = set(np.flatnonzero(q_start >= q_start.max() - 1e-10))
    assert set(actions.tolist()) == optimal and len(optimal) > 1
    again, _ = PILagrangian(make_grid("big-square"), seed=3).learn().predict(obs, deterministic=False)
    np.testing.assert_array_equal(actions, again)


def test_save_load_roundtrip(tmp_path):
    model = PILagrangian(make_grid("zigzag"), lagrange_init=0.0, lagrange_lr=0.5, seed=1).learn()
    path = tmp_path / "models" / "pi_lag.npz"
    model.save(path)
    model.save(path)  # overwrite in place
    assert os.listdir(path.parent) == ["pi_lag.npz"]

    loaded = PILagrangian.load(path)
    assert loaded.get_env() is None
    np.testing.assert_array_equal(loaded.policy_table, model.policy_table)
    np.testing.assert_array_equal(loaded.q_values, model.q_values)
    assert loaded.lagrange_multiplier == model.lagrange_multiplier and loaded.history == model.history
    assert loaded.predict(np.arange(49))[0].tolist() == model.predict(np.arange(49))[0].tolist()
    with pytest.raises(ValueError, match="set_env"):
        loaded.learn()

    resumed = PILagrangian.load(path, env=make_grid("zigzag")).learn()
    assert rollout(resumed, make_grid("zigzag"))[:2] == (0.0, True)
    with pytest.raises(ValueError, match="states, actions"):
        PILagrangian.load(path, env=gym.make("sb3_icrl/GridWorld-v0", desc=["S.X", "..G"]))


def test_save_is_atomic(tmp_path, monkeypatch):
    model = PILagrangian(make_grid("wall")).learn()
    path = tmp_path / "model.npz"
    model.save(path)
    before = path.read_bytes()

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    model.lagrange_multiplier = 123.0
    with pytest.raises(OSError, match="disk full"):
        model.save(path)
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["model.npz"]


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"gamma": 1.0}, ValueError, "gamma"),
        ({"lagrange_lr": -0.1}, ValueError, "lagrange_lr"),
        ({"cost_budget": float("nan")}, ValueError, "cost_budget"),
        ({"lagrange_init": 2.0, "lagrange_upper_bound": 1.0}, ValueError, "lagrange_upper_bound"),
        ({"cost_table": np.zeros(3)}, ValueError, "cost_table"),
    ],
)
def test_bad_arguments(kwargs, error, message):
    with pytest.raises(error, match=message):
        PILagrangian(make_grid("wall"), **kwargs)


def test_env_without_tables():
    with pytest.raises(TypeError, match="tables"):
        PILagrangian(gym.make("CartPole-v1"))
