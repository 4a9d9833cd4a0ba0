"""
Quick start: PPO ignores a constraint, PPOLagrangian keeps it within budget.

The corridor env (``sb3_icrl/ConstrainedCorridor-v0``, 20-step episodes) pays more the further right the agent
stands, and charges a cost of 1 for every step right of cell 6. With a budget of 2 cost units per episode,
PPOLagrangian learns to stop at the line; plain PPO runs to the end. About half a minute on 2 CPU cores.

    python examples/ppolag_quickstart.py --steps 10000
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--budget", type=float, default=2.0, help="cost budget per episode")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)

    settings = dict(n_steps=256, batch_size=64, learning_rate=3e-3, policy_kwargs=dict(net_arch=[32, 32]), seed=args.seed)
    start = time.time()
    ppo = PPO("MlpPolicy", ENV_ID, **settings).learn(args.steps)
    ppolag = PPOLagrangian(
        "MlpPolicy",
        ENV_ID,
        cost_budget=args.budget,
        lagrange_kwargs=dict(init=0.0, lr=0.1),
        **settings,
    ).learn(args.steps, progress_bar=False)

    print(f"\nConstrainedCorridor, {args.steps} steps each, episode cost budget {args.budget}")
    print(f"{'algorithm':15s} {'return':>8s} {'episode cost':>13s}")
    for name, model in (("PPO", ppo), ("PPOLagrangian", ppolag)):
        mean_return, mean_cost = evaluate(model)
        print(f"{name:15s} {mean_return:8.2f} {mean_cost:13.2f}")
    print(f"final Lagrange multiplier: {ppolag.lagrange_multiplier.value[0]:.3f}   ({time.time() - start:.0f} s)")


if __name__ == "__main__":
    main()
