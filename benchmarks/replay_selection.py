"""
Replay ``best_model.zip`` selection on a finished ICRL run's checkpoints, with learned quantities only::

    python benchmarks/replay_selection.py logs/s6/mecl456/mecl/BlockedHalfCheetah-v0_1 --episodes 5

Each checkpoint ``rl_model_<N>_steps.zip`` is run for ``--episodes`` deterministic episodes; its score is the learned
penalised reward under its own constraint, multiplier and budget, and the best checkpoint so far is priced again
with each later checkpoint's constraint, as :class:`~sb3_icrl.zoo.callbacks.ConstraintEvalCallback` does at each
evaluation. This picks a model for runs trained before that rule, or among checkpoints only. The true violation rate
and feasible reward are printed beside each row to report; they take no part in the choice.
"""

import argparse
import glob
import os
import re

import numpy as np
import torch as th
import yaml

from sb3_icrl.common.evaluation import evaluate_constraint
from sb3_icrl.hyperparams import preprocess_hyperparams
from sb3_icrl.registry import ALGOS, env_name
from sb3_icrl.zoo.callbacks import learned_episode_stats, learned_selection_score, rescore_episodes
from sb3_icrl.zoo.compare import describe_run
from sb3_icrl.zoo.train import create_env

STEPS = re.compile(r"rl_model_(\d+)_steps\.zip$")


def checkpoints(run: str) -> list[tuple[int, str]]:
    """``(steps, path)`` of the run's checkpoints, in order of steps."""
    paths = glob.glob(os.path.join(run, "rl_model_*_steps.zip"))
    found = [(int(match.group(1)), path) for path in paths if (match := STEPS.search(path)) is not None]
    if not found:
        raise FileNotFoundError(f"{run} has no rl_model_<N>_steps.zip checkpoints (train.py --save-freq).")
    return sorted(found)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", help="Run folder <folder>/<algo>/<EnvName>_<N> of an ICRL algorithm")
    parser.add_argument("--episodes", type=int, default=5, help="Deterministic episodes per checkpoint")
    parser.add_argument("--seed", type=int, default=1000, help="Seed of the evaluation env")
    args = parser.parse_args()
    th.set_num_threads(1)
    algo, env_id, _, _ = describe_run(args.run)
    with open(os.path.join(args.run, env_name(env_id), "config.yml")) as file:
        params = preprocess_hyperparams(yaml.safe_load(file))
    best_score, best_steps, best_episodes = -np.inf, None, []
    print("| steps | learned score | best so far, priced again | best | true violation rate | true feasible reward |")
    print("|---|---|---|---|---|---|")
    for steps, path in checkpoints(args.run):
        stats_path = path.replace("rl_model_", "rl_model_vecnormalize_").replace(".zip", ".pkl")
        stats = stats_path if params["normalize"] else None
        env, recorder = create_env(env_id, params, 1, args.seed, None, 0.0, None, eval_env=True, stats_path=stats)
        assert recorder is not None
        model = ALGOS[algo].load(path, device="cpu", demonstrations_source=None)
        recorder.recording = True
        result = evaluate_constraint(model, env, n_eval_episodes=args.episodes, deterministic=True)
        env.close()
        episodes = recorder.episodes[: args.episodes]
        score = learned_selection_score(model, learned_episode_stats(episodes, model.constraint_net.cost))
        # as the callback does: the best so far, priced again with this checkpoint's constraint, multiplier and budget
        rescored = rescore_episodes(model, best_episodes, model.constraint_net.cost)
        if rescored is not None:
            best_score = rescored
        if score > best_score:
            best_score, best_steps, best_episodes = score, steps, episodes
        print(
            f"| {steps} | {score:.0f} | {'' if rescored is None else f'{rescored:.0f}'} | {best_steps} | "
            f"{result.violation_rate:.0%} | {result.mean_feasible_reward:.0f} |"
        )
    print(f"Selected: rl_model_{best_steps}_steps.zip (enjoy.py --load-checkpoint {best_steps})")


if __name__ == "__main__":
    main()
