from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.costs import CostError, as_cost_array, costs_from_infos
from sb3_icrl.common.envs import ConstrainedCorridorEnv

TINY = dict(n_steps=16, batch_size=8, n_epochs=1, policy_kwargs=dict(net_arch=[8]), seed=0)


class InfoCostEnv(ConstrainedCorridorEnv):
    """The corridor, 100-step episodes (no truncation in the tests), a custom info["cost"] (None: no cost key)."""

    def __init__(self, cost_value: Any = 0.0):
        super().__init__(max_steps=100)
        self.cost_value = cost_value

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        del info["cost"]
        if self.cost_value is not None:
            info["cost"] = self.cost_value
        return obs, reward, terminated, truncated, info


def make_model(cost_value: Any, **kwargs: Any) -> PPOLagrangian:
    return PPOLagrangian("MlpPolicy", DummyVecEnv([lambda: InfoCostEnv(cost_value)]), **{**TINY, **kwargs})


def test_missing_cost_names_the_env_and_the_key():
    gym.register("TinyNoCost-v0", entry_point=InfoCostEnv, kwargs=dict(cost_value=None), max_episode_steps=20)
    model = PPOLagrangian("MlpPolicy", "TinyNoCost-v0", **TINY)
    with pytest.raises(
        CostError, match=r"'TinyNoCost-v0' \(env index 0\) did not report a cost: its info dict has no key 'cost'"
    ):
        model.learn(16)


def test_custom_cost_info_key():
    model = make_model(None, cost_info_key="danger")
    with pytest.raises(CostError, match="no key 'danger'"):
        model.learn(16)


@pytest.mark.parametrize(
    "bad_cost,message",
    [
        ("high", "not numbers"),
        ([1.0, 0.0], r"shape \(1, 2\), expected \(1,\) or \(1, 1\)"),
        (float("nan"), "non-finite"),
        (np.inf, "non-finite"),
    ],
)
def test_malformed_costs_raise(bad_cost, message):
    with pytest.raises(CostError, match=message):
        make_model(bad_cost).learn(16)


def test_vector_costs_for_several_constraints():
    model = make_model([1.0, 0.0], cost_budget=[0.5, 0.5])
    model.learn(32)
    assert model.rollout_buffer.costs.shape == (16, 1, 2)
    np.testing.assert_array_equal(model.rollout_buffer.costs[:, 0], [[1.0, 0.0]] * 16)
    assert model.lagrange_multiplier.value.shape == (2,)


def test_as_cost_array_shapes():
    np.testing.assert_array_equal(as_cost_array([1, 0, 1], 3, 1, "test"), [[1.0], [0.0], [1.0]])
    with pytest.raises(CostError, match=r"returned costs of shape \(3,\), expected \(3,\) or \(3, 2\)"):
        as_cost_array([1, 0, 1], 3, 2, "test")
    assert costs_from_infos([{"cost": np.float32(1.0)}, {"cost": 0}], "cost", 1, ["a", "b"]).tolist() == [[1.0], [0.0]]


def test_costs_from_infos_reads_every_scalar_type_and_the_edges_of_float32():
    """Python and NumPy scalars of any width, zero and the largest float32, stored as float32 without change."""
    largest = float(np.finfo(np.float32).max)
    infos = [{"cost": 0.25}, {"cost": np.float64(2.5)}, {"cost": np.int64(3)}, {"cost": True}, {"cost": largest}, {"cost": 0}]
    costs = costs_from_infos(infos, "cost", 1, ["env"] * len(infos))
    assert costs.dtype == np.float32 and costs.shape == (6, 1)
    np.testing.assert_array_equal(costs[:, 0], np.array([0.25, 2.5, 3.0, 1.0, largest, 0.0], dtype=np.float32))
    # float16 and a float just above float32's largest, which float32 rounds down to it, as NumPy stores them
    edge = np.nextafter(largest, np.inf)
    costs = costs_from_infos([{"cost": np.float16(0.5)}, {"cost": edge}], "cost", 1, ["env"] * 2)
    np.testing.assert_array_equal(costs[:, 0], np.array([0.5, edge], dtype=np.float32))
    with pytest.raises(CostError, match="non-finite"):
        costs_from_infos([{"cost": np.float16("inf")}], "cost", 1, ["env"])


def test_cost_fn_replaces_info_and_can_be_swapped_between_learn_calls():
    model = make_model(None, cost_fn=lambda obs, actions: np.ones(len(obs)))
    policy = model.policy
    model.learn(16)
    np.testing.assert_array_equal(model.rollout_buffer.costs, 1.0)
    model.set_cost_fn(lambda obs, actions: (obs[:, :1] > 0.25).astype(np.float32))
    model.learn(16, reset_num_timesteps=False)
    assert model.policy is policy, "swapping the cost function must not rebuild the model"
    positions = model.rollout_buffer.observations[:, 0]  # one env: the flattened buffer is in time order
    np.testing.assert_array_equal(model.rollout_buffer.costs[:, 0, 0], (positions > 0.25).astype(np.float32))
    assert 0 < model.rollout_buffer.costs.sum() < 16, "the new cost function must have been used"


def test_cost_fn_sees_original_observations_and_executed_actions():
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    def cost_fn(obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        seen.append((obs.copy(), actions.copy()))
        return np.zeros(len(obs))

    env = VecNormalize(DummyVecEnv([ConstrainedCorridorEnv]))
    PPOLagrangian("MlpPolicy", env, cost_fn=cost_fn, **TINY).learn(16)
    observations = np.concatenate([obs for obs, _ in seen])
    # Raw corridor observations lie on the grid {0, 0.1, ..., 1}; normalised ones do not
    np.testing.assert_allclose(observations[:, 0] * 10, np.round(observations[:, 0] * 10), atol=1e-5)
    assert observations[0, 0] == 0.0 and observations[0, 1] == 0.0
    actions = np.concatenate([actions for _, actions in seen])
    assert set(np.unique(actions)) <= {0, 1, 2}


def test_cost_fn_judges_each_rollout_in_one_call_in_step_major_order():
    calls: list[tuple[np.ndarray, np.ndarray]] = []

    def cost_fn(obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
        calls.append((obs.copy(), actions.copy()))
        return (obs[:, 0] >= 0.3).astype(np.float32)  # cells 3 and beyond cost 1

    envs = DummyVecEnv([lambda: ConstrainedCorridorEnv(max_steps=4) for _ in range(3)])
    # (cost_gamma 0: the time-limit truncations add no bootstrapped cost to the buffer's costs)
    model = PPOLagrangian("MlpPolicy", envs, cost_fn=cost_fn, **{**TINY, "n_steps": 8, "cost_gamma": 0.0})
    model.learn(48)
    assert len(calls) == 2 and all(len(obs) == 8 * 3 for obs, _ in calls)  # one call per rollout, every pair
    obs, actions = calls[-1]
    # Row t * n_envs + i is env i at step t: the same pairs as the buffer holds (raw: no VecNormalize here), which
    # training flattened env by env
    env_major = obs.reshape(8, 3, -1).swapaxes(0, 1).reshape(24, -1)
    np.testing.assert_allclose(env_major, model.rollout_buffer.observations)
    np.testing.assert_array_equal(actions.reshape(8, 3).T.ravel(), model.rollout_buffer.actions.ravel())
    step_costs = (obs[:, 0] >= 0.3).astype(np.float32).reshape(8, 3)
    np.testing.assert_array_equal(model.rollout_buffer.costs[..., 0], step_costs)
    # Episodes of 4 steps: the episode costs are the per-step costs summed, as if they had come one step at a time
    episode_costs = step_costs.reshape(2, 4, 3).sum(axis=1).ravel()
    np.testing.assert_allclose(np.ravel(model.ep_cost_buffer)[-6:], episode_costs)


def test_bad_cost_fn_output_and_type():
    with pytest.raises(CostError, match=r"cost_fn returned costs of shape \(2,\)"):
        make_model(None, cost_fn=lambda obs, actions: np.zeros(2)).learn(16)
    with pytest.raises(TypeError, match="must be callable"):
        make_model(None, cost_fn="not a function")
