"""
Quick start: PPO ignores a constraint, PPOLagrangian keeps it within budget.

The corridor env (``sb3_icrl/ConstrainedCorridor-v0``, 20-step episodes) pays more the further right the agent
stands, and charges a cost of 1 for every step right of cell 6. With a budget of 2 cost units per episode,
PPOLagrangian learns to stop at the line; plain PPO runs to the end. About 20 seconds on one CPU core:

    python examples/ppolag_quickstart.py --steps 10000

prints (seeds 0, 1 and 2 alike; the multiplier differs)::

    algorithm         return  episode cost
    PPO                15.50         14.00
    PPOLagrangian      10.50          0.00

PPO walks to the far end (cell 10) and pays a cost on 14 of the 20 steps; PPOLagrangian walks to cell 6, the last
safe cell, and stays there.
"""

import argparse
import time

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_icrl import PPOLagrangian

ENV_ID = "sb3_icrl/ConstrainedCorridor-v0"


def evaluate(model: BaseAlgorithm, n_episodes: int = 5) -> tuple[float, float]:
    """Mean return and mean episode cost of the deterministic policy."""
    env = gym.make(ENV_ID)
    returns, costs = [], []
    for episode in range(n_episodes):
        obs, _ = env.reset(seed=episode)
        total_reward, total_cost, done = 0.0, 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(int(action))
            total_reward += float(reward)
            total_cost += info["cost"]
            done = terminated or truncated
        returns.append(total_reward)
        costs.append(total_cost)
    return float(np.mean(returns)), float(np.mean(costs))


def train_and_evaluate(steps: int, budget: float, seed: int) -> tuple[dict[str, tuple[float, float]], float]:
    """
    Train PPO and PPOLagrangian for ``steps`` steps each.

    :param steps: Training steps of each algorithm
    :param budget: PPOLagrangian's cost budget per episode
    :param seed: Seed of both
    :return: ``{name: (mean return, mean episode cost)}`` of the deterministic policies, and the final multiplier
    """
    # Short rollouts: about 80 multiplier updates in 10000 steps, enough for the multiplier to settle
    settings = dict(n_steps=128, batch_size=64, learning_rate=3e-3, policy_kwargs=dict(net_arch=[32, 32]), seed=seed)
    ppo = PPO("MlpPolicy", ENV_ID, **settings).learn(steps)
    ppolag = PPOLagrangian(
        "MlpPolicy",
        ENV_ID,
        cost_budget=budget,
        # Plain gradient steps, lr * (episode cost - budget): Adam's momentum kept raising the multiplier after the
        # agent had stopped paying costs, until it stayed in cell 0 (return 0)
        lagrange_kwargs=dict(init=0.0, lr=0.05, optimizer="sgd"),
        **settings,
    ).learn(steps, progress_bar=False)
    results = {name: evaluate(model) for name, model in (("PPO", ppo), ("PPOLagrangian", ppolag))}
    return results, float(ppolag.lagrange_multiplier.value[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--budget", type=float, default=2.0, help="cost budget per episode")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)

    start = time.time()
    results, multiplier = train_and_evaluate(args.steps, args.budget, args.seed)
    print(f"\nConstrainedCorridor, {args.steps} steps each, episode cost budget {args.budget}")
    print(f"{'algorithm':15s} {'return':>8s} {'episode cost':>13s}")
    for name, (mean_return, mean_cost) in results.items():
        print(f"{name:15s} {mean_return:8.2f} {mean_cost:13.2f}")
    print(f"final Lagrange multiplier: {multiplier:.3f}   ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
