"""
The throughput recipe family's bar for experts: PPO-Lagrangian trained with it on the true cost against the shipped
expert of the same env, both evaluated here on the same held-out episodes (deterministic, env seeds from
``--eval-seed``), with the training CPU time of each.

A run passes where its return is at least ``--bar`` (0.9) of the shipped expert's, its violation rate at most 5% or
the shipped expert's (whichever is higher: some shipped experts break their line in a few held-out episodes), and its
training took no more CPU time than the shipped expert's recipe did. The shipped experts' times are the wall times
recorded when they were trained (benchmarks/RESULTS.md, "Experts shipped with the package", 2026-11-21: two or three
jobs on the two cores of the dev machine, so their CPU time was at most that); a run's CPU time is ``cpu_time_s`` of
its ``finished.json``.

    python train.py --algo ppolag --env BlockedWalker-v0 --seed 0 -f logs/family --exp-id 0 -n 2000000
    python benchmarks/throughput_experts.py logs/family/ppolag/BlockedWalker-v0_0 [more run folders]
"""

import argparse
import platform
from typing import Any

import gymnasium as gym
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import sb3_icrl  # noqa: F401  (registers the envs)
from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.common.utils import atomic_write_json
from sb3_icrl.data.registry import expert_paths
from sb3_icrl.registry import env_name
from sb3_icrl.run_evaluation import describe_run, load_run_model
from sb3_icrl.run_folder import find_vecnormalize, model_path, read_finished

#: Training time of each shipped expert's recipe, in seconds (benchmarks/RESULTS.md, 2026-11-21; HalfCheetah: the
#: 800k-step run's 29.8 min and 400k of the 15.7 min continuation that reached 1.41M steps)
SHIPPED_EXPERT_SECONDS = {
    "BlockedHalfCheetah-v0": 29.8 * 60 + 15.7 * 60 * 400 / 610,
    "BlockedAnt-v0": 10.4 * 60,
    "BiasedPendulum-v0": 1.4 * 60,
    "BlockedWalker-v0": 15.4 * 60,
    "BlockedSwimmer-v0": 13 * 60,
    "HighwayVelocity-v0": 3.2 * 60,
    "HighwayDistance-v0": 2.9 * 60,
    "HighwayVelocityDistance-v0": 7.5 * 60,
}


#: The violation rate an expert may have (or the shipped expert's, where higher)
MAX_VIOLATION_RATE = 0.05


def evaluate(env_id: str, path: str, statistics: str | None, episodes: int, seed: int) -> dict[str, float]:
    """Held-out return, feasible reward and violation rate of a saved PPOLagrangian with its normalisation statistics."""
    venv: Any = DummyVecEnv([lambda: gym.make(env_id)])
    if statistics is not None:
        venv = VecNormalize.load(statistics, venv)
        venv.training, venv.norm_reward = False, False
    model = load_run_model("ppolag", path, "cpu", seed)
    evaluation = evaluate_constraint(model, venv, n_eval_episodes=episodes, seed=seed)
    return {
        "return": evaluation.mean_reward,
        "feasible_reward": evaluation.mean_feasible_reward,
        "violation_rate": evaluation.violation_rate,
    }


def check_run(run: str, episodes: int, seed: int, bar: float) -> dict[str, Any]:
    """The run's and its env's shipped expert's held-out numbers, and whether the run meets the bar."""
    _, env_id, _, _ = describe_run(run)
    name = env_name(env_id)
    expert_zip, expert_statistics = expert_paths(name)
    shipped = evaluate(env_id, str(expert_zip), str(expert_statistics) if expert_statistics else None, episodes, seed)
    path = model_path(run, name, False, None, False)
    trained = evaluate(env_id, path, find_vecnormalize(path, name), episodes, seed)
    finished = read_finished(run) or {}
    cpu = finished.get("cpu_time_s")
    budget = SHIPPED_EXPERT_SECONDS.get(name)
    ratio = trained["return"] / shipped["return"] if shipped["return"] > 0 else float("nan")
    return {
        "env": name,
        "run": run,
        "steps": finished.get("num_timesteps"),
        "shipped": shipped,
        "trained": trained,
        "return_ratio": ratio,
        "cpu_time_s": cpu,
        "shipped_seconds": budget,
        "passes": bool(
            ratio >= bar
            and trained["violation_rate"] <= max(MAX_VIOLATION_RATE, shipped["violation_rate"]) + 1e-9
            and cpu is not None
            and budget is not None
            and cpu <= budget
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="ppolag run folders trained with the throughput family")
    parser.add_argument("--episodes", type=int, default=20, help="Held-out episodes per model")
    parser.add_argument("--eval-seed", type=int, default=100, help="Seed of the held-out episodes")
    parser.add_argument("--bar", type=float, default=0.9, help="Fraction of the shipped expert's return to reach")
    parser.add_argument("--json", type=str, default=None, help="Also write the rows here")
    args = parser.parse_args()
    th.set_num_threads(1)
    machine = platform.processor() or platform.machine()
    print(f"{machine}, torch threads 1, {args.episodes} held-out episodes from seed {args.eval_seed}")
    columns = ["env", "steps", "shipped expert: return / violation", "family: return / violation", "ratio"]
    print("| " + " | ".join([*columns, "CPU s (shipped's)", "passes"]) + " |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for run in args.runs:
        row = check_run(run, args.episodes, args.eval_seed, args.bar)
        rows.append(row)
        shipped, trained = row["shipped"], row["trained"]
        cpu = f"{row['cpu_time_s']:.0f}" if row["cpu_time_s"] is not None else "-"
        print(
            f"| {row['env']} | {row['steps']} | {shipped['return']:.2f} / {100 * shipped['violation_rate']:.0f}% | "
            f"{trained['return']:.2f} / {100 * trained['violation_rate']:.0f}% | {row['return_ratio']:.2f} | "
            f"{cpu} ({row['shipped_seconds']:.0f}) | {'yes' if row['passes'] else 'no'} |"
        )
    if args.json:
        atomic_write_json(args.json, rows, indent=2)


if __name__ == "__main__":
    main()
