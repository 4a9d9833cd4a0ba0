"""
Do the benchmark's constraints matter? For each environment, PPO trained without the constraint should break it
in most episodes, while PPOLagrangian trained with the true cost should not (the paper's appendix figure).

Each (env, algorithm, seed) run is its own process with one torch thread, ``--jobs`` at a time; each saves a
JSON result atomically in ``--out``; ``--summarize`` re-prints the table from those files:

    python benchmarks/constraints_matter.py --jobs 2 --out benchmarks/out/constraints_matter
    python benchmarks/constraints_matter.py --summarize --out benchmarks/out/constraints_matter

Both algorithms use the same PPO settings (SB3 defaults, n_steps 2048, VecNormalize on observations and rewards).
PPOLagrangian uses the ICRL reference code's multiplier settings (per-step cost, budget 0, SGD, the per-env init
and learning rate of the reference ICRL code's runs). Reported per run: the training episodes' violation rate and
reward over the last 10% of steps, and a deterministic evaluation (10 episodes): violation rate, feasible cumulative
reward, reward.
"""

import argparse
import json
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import sb3_icrl  # noqa: F401  (registers the environments)
from sb3_icrl import PPOLagrangian
from sb3_icrl.common.callbacks import EpisodeCostRecorder
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.common.utils import atomic_write_json

#: env -> (training steps, lambda init, lambda lr of the ICRL reference code); the MuJoCo envs run by default
ENVS = {
    "BlockedHalfCheetah-v0": (300_000, 1.0, 0.1),
    "BlockedAnt-v0": (300_000, 0.1, 0.05),
    "BiasedPendulum-v0": (100_000, 0.1, 0.01),
    "BlockedWalker-v0": (300_000, 0.1, 0.05),
    "BlockedSwimmer-v0": (300_000, 1.0, 0.01),
    # Driving: no reference settings (the paper's driving envs differ); the multiplier settings of Walker/Ant
    "HighwayVelocity-v0": (200_000, 0.1, 0.05),
    "HighwayDistance-v0": (200_000, 0.1, 0.05),
    "HighwayVelocityDistance-v0": (200_000, 0.1, 0.05),
}


def run(env_name: str, algo: str, seed: int, steps: int | None, out: str) -> str:
    th.set_num_threads(1)
    default_steps, lambda_init, lambda_lr = ENVS[env_name]
    steps = steps or default_steps
    env = VecNormalize(make_vec_env(f"sb3_icrl/{env_name}", n_envs=1, seed=seed))
    if algo == "ppo":
        model = PPO("MlpPolicy", env, seed=seed)
    else:
        model = PPOLagrangian(
            "MlpPolicy",
            env,
            seed=seed,
            cost_budget=0.0,
            budget_statistic="step",
            lagrange_kwargs=dict(init=lambda_init, lr=lambda_lr, optimizer="sgd"),
        )
    recorder = EpisodeCostRecorder()
    start = time.time()
    model.learn(steps, callback=recorder)
    wall_time = time.time() - start
    evaluation = evaluate_constraint(model, env, n_eval_episodes=10, deterministic=True, seed=seed + 1000)
    result = dict(
        env=env_name,
        algo=algo,
        seed=seed,
        steps=steps,
        wall_time_s=wall_time,
        train_episodes=recorder.episodes,
        evaluation=evaluation.summary(),
        lagrange_multiplier=float(model.lagrange_multiplier.value[0]) if algo == "ppolag" else None,
        machine=platform.processor() or platform.machine(),
        date=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )
    path = os.path.join(out, f"{env_name}_{algo}_seed{seed}.json")
    atomic_write_json(path, result)
    return path


def summarize(out: str) -> None:
    files = sorted(name for name in os.listdir(out) if name.endswith(".json"))
    if not files:
        raise SystemExit(f"No results in {out}: run the benchmark first.")
    print(
        f"{'env':22s} {'algo':7s} {'seed':>4s} {'steps':>7s} | {'train viol.':>11s} {'train reward':>12s} | "
        f"{'eval viol.':>10s} {'feasible rew.':>13s} {'eval reward':>11s} | {'wall(min)':>9s}"
    )
    for name in files:
        with open(os.path.join(out, name)) as handle:
            result = json.load(handle)
        episodes = np.array(result["train_episodes"], dtype=np.float64).reshape(-1, 4)
        last = episodes[episodes[:, 0] > 0.9 * result["steps"]]
        evaluation = result["evaluation"]
        print(
            f"{result['env']:22s} {result['algo']:7s} {result['seed']:4d} {result['steps']:7d} | "
            f"{last[:, 3].mean():11.0%} {last[:, 1].mean():12.1f} | {evaluation['violation_rate']:10.0%} "
            f"{evaluation['mean_feasible_reward']:13.1f} {evaluation['mean_reward']:11.1f} | {result['wall_time_s'] / 60:9.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--envs", nargs="+", default=[env for env in ENVS if not env.startswith("Highway")], choices=list(ENVS)
    )
    parser.add_argument("--algos", nargs="+", default=["ppo", "ppolag"], choices=["ppo", "ppolag"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--steps", type=int, default=None, help="override the per-env training steps")
    parser.add_argument("--jobs", type=int, default=2, help="runs in parallel (one core each)")
    parser.add_argument("--out", default="benchmarks/out/constraints_matter")
    parser.add_argument("--summarize", action="store_true", help="only print the table of saved runs")
    args = parser.parse_args()
    gym.logger.min_level = 40  # silence gymnasium's deprecation chatter in worker logs
    os.makedirs(args.out, exist_ok=True)
    if not args.summarize:
        runs = [(env, algo, seed) for env in args.envs for seed in args.seeds for algo in args.algos]
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futures = [pool.submit(run, env, algo, seed, args.steps, args.out) for env, algo, seed in runs]
            for future in futures:
                print("saved", future.result(), flush=True)
    summarize(args.out)


if __name__ == "__main__":
    main()
