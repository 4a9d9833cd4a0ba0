"""
PPOLagrangian's training speed over SB3 PPO's, same env and settings, measured in the same run.

Both learn HalfCheetah-v5 with a velocity cost in ``info["cost"]`` (PPO ignores it), default MlpPolicy and PPO
hyper-parameters; the runs are interleaved (PPO, PPOLag, PPO, PPOLag, ...) so machine noise hits both alike.
Each run's fps is env steps over the wall time of ``learn`` (rollouts and updates), after a warm-up.

    python benchmarks/ppolag_speed.py --steps 20480 --repeats 3
"""

import argparse
import platform
import statistics
import time

import gymnasium as gym
import torch as th
from stable_baselines3 import PPO

from sb3_icrl import PPOLagrangian
from sb3_icrl.common.envs import VelocityCostWrapper


def make_env() -> gym.Env:
    return VelocityCostWrapper(gym.make("HalfCheetah-v5"))


def measure_fps(algo: str, steps: int, seed: int) -> float:
    """Env steps per second of ``learn(steps)``; model construction is not timed."""
    if algo == "ppo":
        model = PPO("MlpPolicy", make_env(), seed=seed)
    else:
        model = PPOLagrangian("MlpPolicy", make_env(), seed=seed, cost_budget=25.0)
    start = time.perf_counter()
    model.learn(steps)
    return model.num_timesteps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20480, help="env steps per run (a multiple of n_steps=2048)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved (PPO, PPOLag) pairs")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest for small MLPs)")
    args = parser.parse_args()
    th.set_num_threads(args.threads)

    measure_fps("ppo", 2048, seed=0)  # warm-up: imports, MuJoCo and torch kernels
    fps: dict[str, list[float]] = {"ppo": [], "ppolag": []}
    for repeat in range(args.repeats):
        for algo in ("ppo", "ppolag"):
            fps[algo].append(measure_fps(algo, args.steps, seed=repeat))
            print(f"repeat {repeat} {algo:7s} {fps[algo][-1]:8.1f} steps/s", flush=True)

    ratios = [lag / ppo for ppo, lag in zip(fps["ppo"], fps["ppolag"], strict=True)]
    print(f"\nmachine: {platform.processor() or platform.machine()}, torch threads {args.threads}, {args.steps} steps per run")
    print(f"PPO          mean {statistics.mean(fps['ppo']):8.1f} steps/s")
    print(f"PPOLagrangian mean {statistics.mean(fps['ppolag']):8.1f} steps/s")
    print(f"per-pair ratios: {', '.join(f'{ratio:.3f}' for ratio in ratios)}")
    ratio = statistics.mean(fps["ppolag"]) / statistics.mean(fps["ppo"])
    print(f"PPOLagrangian fps / PPO fps = {ratio:.3f} (target >= 0.85): {'PASS' if ratio >= 0.85 else 'FAIL'}")


if __name__ == "__main__":
    main()
