"""
Steps per second of the benchmark's environments against their base gymnasium environments.

Each pair is built the same way (``gymnasium.make``, same episode length, same termination setting),
driven by the same pre-drawn random actions, and timed in interleaved repetitions so that load on the
machine hits both alike; the reported figure is the median over repetitions. Target: ratio >= 0.9.

    python benchmarks/env_speed.py [--steps 3000] [--repeats 7]
"""

import argparse
import statistics
import time
import warnings

import gymnasium as gym
import numpy as np

import sb3_icrl.envs  # noqa: F401  (registers the ids)
from sb3_icrl.envs import ENV_SPECS, TransitionNoiseWrapper

#: ours -> (base id, keyword arguments that make the base behave like ours apart from reward and cost)
PAIRS: dict[str, tuple[str, dict]] = {
    "BlockedHalfCheetah-v0": ("HalfCheetah-v5", {"exclude_current_positions_from_observation": False}),
    "BlockedAnt-v0": ("Ant-v5", {"exclude_current_positions_from_observation": False, "terminate_when_unhealthy": False}),
    "BiasedPendulum-v0": ("InvertedPendulum-v5", {}),
    "BlockedWalker-v0": ("Walker2d-v5", {"exclude_current_positions_from_observation": False}),
    "BlockedSwimmer-v0": ("Swimmer-v5", {"exclude_current_positions_from_observation": False}),
}


def steps_per_second(env: gym.Env, actions: np.ndarray, seed: int) -> float:
    """
    :param env: Environment to time
    :param actions: Actions to play, one per step
    :param seed: Seed of the first reset
    :return: Steps per second, resets included
    """
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return len(actions) / (time.perf_counter() - start)


def compare(candidate: gym.Env, reference: gym.Env, n_steps: int, repeats: int, seed: int) -> tuple[float, float]:
    """
    :return: Median steps/s of ``candidate`` and of ``reference``, timed in alternation
    """
    candidate.action_space.seed(seed)
    actions = np.array([candidate.action_space.sample() for _ in range(n_steps)])
    timings: dict[str, list[float]] = {"candidate": [], "reference": []}
    for repeat in range(repeats):
        # Alternate which one goes first so that drifts in machine load cancel out
        order = [("candidate", candidate), ("reference", reference)]
        for name, env in order if repeat % 2 == 0 else order[::-1]:
            timings[name].append(steps_per_second(env, actions, seed + repeat))
    return statistics.median(timings["candidate"]), statistics.median(timings["reference"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000, help="random-action steps per timing")
    parser.add_argument("--repeats", type=int, default=7, help="interleaved timings per environment")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")  # mujoco's deprecation notes on the Ant model

    print(f"{'environment':<34} {'steps/s':>9}  {'base':<22} {'steps/s':>9}  ratio")
    for name, (base_id, base_kwargs) in PAIRS.items():
        max_steps = ENV_SPECS[name][1]
        ours = gym.make(f"sb3_icrl/{name}")
        base = gym.make(base_id, max_episode_steps=max_steps, **base_kwargs)
        ours_speed, base_speed = compare(ours, base, args.steps, args.repeats, args.seed)
        print(f"{name:<34} {ours_speed:>9.0f}  {base_id:<22} {base_speed:>9.0f}  {ours_speed / base_speed:.3f}")

    # Cost of the noise wrapper itself, against the same env without it
    noisy = TransitionNoiseWrapper(gym.make("sb3_icrl/BlockedHalfCheetah-v0"), sigma=0.01)
    plain = gym.make("sb3_icrl/BlockedHalfCheetah-v0")
    noisy_speed, plain_speed = compare(noisy, plain, args.steps, args.repeats, args.seed)
    label, base_label = "BlockedHalfCheetah + noise 0.01", "BlockedHalfCheetah-v0"
    print(f"{label:<34} {noisy_speed:>9.0f}  {base_label:<22} {plain_speed:>9.0f}  {noisy_speed / plain_speed:.3f}")

    grid = gym.make("sb3_icrl/GridWorld-v0", slip_prob=0.1)
    grid.action_space.seed(args.seed)
    grid_actions = np.array([grid.action_space.sample() for _ in range(args.steps)])
    grid_speed = statistics.median(steps_per_second(grid, grid_actions, args.seed + r) for r in range(args.repeats))
    print(f"{'GridWorld-v0 (slip 0.1)':<34} {grid_speed:>9.0f}  (no base environment)")


if __name__ == "__main__":
    main()
