"""
Steps per second of the driving environments against stock highway-env ``highway-fast-v0``.

Both are built with ``gymnasium.make`` (highway-fast-v0 with its default configuration: Kinematics
observation, discrete meta-actions, 20 IDM vehicles) and driven by random actions, resets included.
They are timed in interleaved repetitions, alternating which goes first, so that load on the machine
hits both alike; the reported figures are medians over repetitions. Target: ratio >= 4.

    python benchmarks/highway_speed.py [--steps 3000] [--stock-steps 300] [--repeats 5]
"""

import argparse
import statistics
import warnings

import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-fast-v0)
import numpy as np
from env_speed import steps_per_second  # benchmarks/ is on the path when this script runs

import sb3_icrl.envs  # noqa: F401  (registers the ids)


def timed(env: gym.Env, n_steps: int, seed: int) -> float:
    """
    :param env: Environment to time
    :param n_steps: Random-action steps to play (drawn before the clock starts)
    :param seed: Seed of the actions and of the first reset
    :return: Steps per second, resets included
    """
    env.action_space.seed(seed)
    return steps_per_second(env, [env.action_space.sample() for _ in range(n_steps)], seed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="HighwayVelocityDistance-v0", help="our environment (sb3_icrl namespace)")
    parser.add_argument("--steps", type=int, default=3000, help="random-action steps per timing of ours")
    parser.add_argument("--stock-steps", type=int, default=300, help="steps per timing of highway-fast-v0 (slow)")
    parser.add_argument("--repeats", type=int, default=5, help="interleaved timings per environment")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")

    ours = gym.make(f"sb3_icrl/{args.env}")
    stock = gym.make("highway-fast-v0")
    timings: dict[str, list[float]] = {"ours": [], "stock": []}
    for repeat in range(args.repeats):
        order = [("ours", ours, args.steps), ("stock", stock, args.stock_steps)]
        for name, env, n_steps in order if repeat % 2 == 0 else order[::-1]:
            timings[name].append(timed(env, n_steps, args.seed + repeat))
    ours_speed, stock_speed = statistics.median(timings["ours"]), statistics.median(timings["stock"])
    print(f"{'environment':<34} {'steps/s (median)':>17}  {'min':>7}  {'max':>7}")
    for label, name in ((args.env, "ours"), ("highway-fast-v0 (stock)", "stock")):
        values = np.array(timings[name])
        print(f"{label:<34} {statistics.median(values):>17.0f}  {values.min():>7.0f}  {values.max():>7.0f}")
    print(f"ratio {ours_speed / stock_speed:.1f} (target >= 4)")


if __name__ == "__main__":
    main()
