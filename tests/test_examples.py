"""The examples of the documentation run and do what their pages say."""

from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from script_loader import load_script

GRID_ID = "sb3_icrl/GridWorldWall-v0"


def load_example(name: str) -> ModuleType:
    """Import ``examples/<name>.py`` as a module (its ``__main__`` block does not run)."""
    return load_script(f"examples/{name}.py", f"example_{name}")


def random_policy_pairs(n_steps: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """State-action pairs of a uniformly random policy on the grid world: mostly where the expert never goes."""
    env = gym.make(GRID_ID)
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    observations, actions = [], []
    for _ in range(n_steps):
        action = env.action_space.sample()
        observations.append(obs)
        actions.append(action)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs, _ = env.reset()
    return np.array(observations), np.array(actions)


def test_custom_icrl_method_loss_matches_its_formula():
    example = load_example("custom_icrl_method")
    model = example.LSCL("MlpPolicy", GRID_ID, demonstrations="GridWorldWall-v0", n_steps=64, seed=0)
    trainer = model._make_trainer()
    obs, acts = random_policy_pairs(8)
    batch = example.Minibatch(model.expert_obs[:8], model.expert_acts[:8], obs, acts, np.arange(8))
    loss, parts = trainer.loss(batch)
    with th.no_grad():
        expert_phi = model.constraint_net.feasibility(batch.expert_obs, batch.expert_acts)
        nominal_phi = model.constraint_net.feasibility(obs, acts)
    expected_expert, expected_nominal = float(((1 - expert_phi) ** 2).mean()), float((nominal_phi**2).mean())
    assert parts["loss_expert"] == pytest.approx(expected_expert, rel=1e-5)
    assert parts["loss_nominal"] == pytest.approx(expected_nominal, rel=1e-5)
    assert float(loss.detach()) == pytest.approx(expected_expert + expected_nominal, rel=1e-5)


def test_custom_icrl_method_updates_its_constraint_and_learns_the_expert_region():
    example = load_example("custom_icrl_method")
    model = example.LSCL("MlpPolicy", GRID_ID, demonstrations="GridWorldWall-v0", n_steps=256, seed=0)
    before = [parameter.detach().clone() for parameter in model.constraint_net.parameters()]
    random_obs, random_acts = random_policy_pairs()
    # Untrained, the model cannot tell the expert's pairs from a random policy's
    gap_before = (
        model.constraint_cost(random_obs, random_acts).mean()
        - model.constraint_cost(model.expert_obs, model.expert_acts).mean()
    )
    assert abs(gap_before) < 0.1

    model.learn(1024)

    # The algorithm trains with the example's trainer: one update at the end of each of the four rollouts
    assert isinstance(model.icrl_trainer, example.LeastSquaresTrainer)
    assert model.n_constraint_updates == 4
    assert any(not th.equal(old, new) for old, new in zip(before, model.constraint_net.parameters(), strict=True))
    # The learner's first trajectories were near random: their pairs now cost clearly more than the expert's
    gap_after = (
        model.constraint_cost(random_obs, random_acts).mean()
        - model.constraint_cost(model.expert_obs, model.expert_acts).mean()
    )
    assert gap_after > 0.15


@pytest.mark.slow
def test_ppolag_quickstart_shows_ppo_crossing_the_line_and_ppolagrangian_stopping_at_it():
    """What the install check prints, and the docs describe: PPOLagrangian earns reward up to the line, not 0."""
    example = load_example("ppolag_quickstart")
    results, _ = example.train_and_evaluate(steps=10_000, budget=2.0, seed=0)
    (ppo_return, ppo_cost), (lag_return, lag_cost) = results["PPO"], results["PPOLagrangian"]
    assert ppo_cost > 2.0 and ppo_return > lag_return  # PPO runs through the costly cells
    assert lag_cost <= 2.0 and lag_return >= 8.0  # stopping at cell 6 earns 10.5; staying at the start earns 0
