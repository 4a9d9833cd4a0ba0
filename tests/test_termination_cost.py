"""PPOLagrangian's ``termination_cost``: what an episode that terminates costs after its last step."""

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_icrl import PPOLagrangian


class EndsAfterThreeSteps(gym.Env):
    """Every step costs 0.5 and pays 1; episodes terminate (not truncate) after three steps."""

    observation_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
    action_space = spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        return np.array([self.t / 3], dtype=np.float32), 1.0, self.t == 3, False, {"cost": 0.5}


def small_model(termination_cost: str | float, n_steps: int = 6, env: type[gym.Env] | None = None, **kwargs) -> PPOLagrangian:
    """A tiny PPOLagrangian on three-step episodes; ``kwargs`` go to it (cost_gamma 0.9 unless given)."""
    return PPOLagrangian(
        "MlpPolicy",
        DummyVecEnv([env or EndsAfterThreeSteps]),
        n_steps=n_steps,
        batch_size=n_steps,
        termination_cost=termination_cost,
        policy_kwargs=dict(net_arch=[8]),
        seed=0,
        **{"cost_gamma": 0.9, **kwargs},
    )


def collected_costs(termination_cost: str | float, cost_gamma: float = 0.9) -> tuple[np.ndarray, PPOLagrangian]:
    model = small_model(termination_cost, cost_gamma=cost_gamma)
    model.learn(6)  # one rollout of two episodes, then one update
    return model.rollout_buffer.costs[:, 0, 0].copy(), model


def test_zero_leaves_the_costs_alone():
    costs, _ = collected_costs("zero")
    np.testing.assert_allclose(costs, [0.5] * 6)


def test_float_charges_an_absorbing_state_for_ever():
    costs, _ = collected_costs(0.2, cost_gamma=0.9)
    # The last step of each episode (steps 2 and 5) adds gamma * c / (1 - gamma) = 0.9 * 0.2 / 0.1 = 1.8
    np.testing.assert_allclose(costs, [0.5, 0.5, 2.3, 0.5, 0.5, 2.3])


def test_bootstrap_adds_the_cost_value_of_the_final_observation():
    model = small_model("bootstrap")
    # Value of the final observation [1.0] before the update changes the critic: read it from a rollout only
    model._setup_learn(6, None)
    with th.no_grad():
        _, final_cost_value = model.policy.predict_all_values(th.ones((1, 1)))
    callback = CallbackList([])
    callback.init_callback(model)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, 6)
    costs = model.rollout_buffer.costs[:, 0, 0]
    expected = 0.5 + 0.9 * float(final_cost_value.flatten()[0])
    np.testing.assert_allclose(costs[[2, 5]], [expected, expected], rtol=1e-5)
    np.testing.assert_allclose(costs[[0, 1, 3, 4]], [0.5] * 4)


def test_rewards_are_never_changed():
    _, model = collected_costs(5.0)
    np.testing.assert_allclose(model.rollout_buffer.rewards[:, 0], [1.0] * 6)


def test_saved_and_loaded(tmp_path):
    _, model = collected_costs("bootstrap")
    model.save(tmp_path / "model")
    assert PPOLagrangian.load(tmp_path / "model").termination_cost == "bootstrap"


@pytest.mark.parametrize(
    "value, error, fragment",
    [
        ("forever", ValueError, "Unknown `termination_cost`"),
        (-1.0, ValueError, ">= 0"),
        (float("nan"), ValueError, "finite"),
        (True, TypeError, "'zero', 'bootstrap', 'budget' or a float"),
        ([1.0], TypeError, "'zero', 'bootstrap', 'budget' or a float"),
    ],
)
def test_bad_values_are_refused(value, error, fragment):
    with pytest.raises(error, match=fragment):
        PPOLagrangian("MlpPolicy", DummyVecEnv([EndsAfterThreeSteps]), termination_cost=value)


def test_a_float_needs_a_discount():
    with pytest.raises(ValueError, match="cost_gamma < 1"):
        PPOLagrangian("MlpPolicy", DummyVecEnv([EndsAfterThreeSteps]), cost_gamma=1.0, termination_cost=1.0)


def test_budget_charges_the_per_step_budget_for_ever():
    model = small_model("budget", cost_budget=0.3, budget_statistic="step")
    model.learn(6)
    # The last step of each episode adds gamma * budget / (1 - gamma) = 0.9 * 0.3 / 0.1 = 2.7
    np.testing.assert_allclose(model.rollout_buffer.costs[:, 0, 0], [0.5, 0.5, 3.2, 0.5, 0.5, 3.2])
    # The multiplier judges the env's costs, not the charges
    np.testing.assert_allclose(model._rollout_mean_step_cost, [0.5])
    # The budget of the moment: a new one (as ICRL sets the expert's) is what the next rollout charges
    model.set_cost_budget(0.1)
    model.learn(6, reset_num_timesteps=False)
    np.testing.assert_allclose(model.rollout_buffer.costs[:, 0, 0], [0.5, 0.5, 1.4, 0.5, 0.5, 1.4])


def test_budget_is_the_lagrangian_of_the_per_step_constraint():
    """Charging the budget for ever after a termination = summing (c_t - budget) over the episode, up to a constant."""
    gamma, budget = 0.9, 0.3
    model = small_model("budget", n_steps=3, cost_gamma=gamma, cost_budget=budget, budget_statistic="step")
    model.learn(3)  # one episode of three steps costing 0.5 each
    discounts = gamma ** np.arange(3)
    constant = budget / (1 - gamma)  # the same for every episode, whatever its length: no policy prefers it
    charged = discounts @ model.rollout_buffer.costs[:, 0, 0]
    assert charged - constant == pytest.approx(discounts @ (np.full(3, 0.5) - budget))


def test_budget_needs_a_per_step_budget():
    with pytest.raises(ValueError, match="budget_statistic='step'"):
        PPOLagrangian("MlpPolicy", DummyVecEnv([EndsAfterThreeSteps]), termination_cost="budget")
    with pytest.raises(ValueError, match="cost_gamma < 1"):
        PPOLagrangian(
            "MlpPolicy", DummyVecEnv([EndsAfterThreeSteps]), cost_gamma=1.0, budget_statistic="step", termination_cost="budget"
        )


class TwoCostsEndsAfterThreeSteps(EndsAfterThreeSteps):
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, reward, terminated, truncated, _ = super().step(action)
        return obs, reward, terminated, truncated, {"cost": [0.5, 0.0]}


def test_budget_charges_each_constraint_its_own_budget_and_survives_save_and_load(tmp_path):
    model = small_model("budget", n_steps=3, env=TwoCostsEndsAfterThreeSteps, cost_budget=[0.3, 0.1], budget_statistic="step")
    model.learn(3)
    np.testing.assert_allclose(model.rollout_buffer.costs[:, 0], [[0.5, 0.0], [0.5, 0.0], [3.2, 0.9]])
    model.save(tmp_path / "model")
    loaded = PPOLagrangian.load(tmp_path / "model")
    assert loaded.termination_cost == "budget"
    np.testing.assert_allclose(loaded.cost_budget, [0.3, 0.1])
