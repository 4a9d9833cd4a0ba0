"""
Does an env's constraint bind, and can it be identified? Two measurements per env, on held-out episodes
(deterministic policies, env seeds from ``--eval-seed``):

- **binds**: unconstrained PPO breaks the constraint in at least 80% of the episodes;
- **identifiable**: the constrained expert breaks it in at most 5% and comes close to the line. Closest approach is the
  smallest distance between the constrained quantity and the threshold, on the allowed side, over an episode (negative
  when the episode crossed); the table gives its median over the episodes, for the expert and for its demonstrations.
  A line the expert never comes near leaves the threshold undetermined by its demonstrations: any boundary between
  the expert's states and the line explains them as well.

    python benchmarks/binding_check.py --env BlockedHalfCheetahReach-v0 --ppo logs/binding/ppo/BlockedHalfCheetahReach-v0_0 \\
        --expert logs/binding/ppolag/BlockedHalfCheetahReach-v0_0
    python benchmarks/binding_check.py --env BlockedSwimmer-v0 --ppo RUN --expert shipped --demos shipped

``--expert shipped`` / ``--demos shipped`` take the env's shipped expert and demonstrations; a run folder's model is
its final one, with its VecNormalize statistics.
"""

import argparse
import platform
from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import sb3_icrl  # noqa: F401  (registers the envs)
from sb3_icrl.common.utils import atomic_write_json
from sb3_icrl.data.registry import expert_paths, load_demonstrations
from sb3_icrl.envs import get_constraint_spec
from sb3_icrl.envs.constraint_spec import FeatureConstraint
from sb3_icrl.registry import env_name, resolve_env_id
from sb3_icrl.run_evaluation import describe_run, load_run_model
from sb3_icrl.run_folder import find_vecnormalize, model_path

#: PPO breaks the constraint in at least this share of held-out episodes: the constraint binds
BINDS_AT = 0.8
#: The expert may break it in at most this share
EXPERT_MAX_VIOLATION = 0.05


@dataclass
class Episodes:
    """Held-out episodes of one policy."""

    violation_rate: float
    mean_return: float
    mean_feasible_reward: float
    closest_approach: list[float]  # per episode

    @property
    def median_closest(self) -> float:
        return float(np.median(self.closest_approach))


def load_model(path: str, statistics: str | None, env_id: str, algo: str, seed: int) -> tuple[BaseAlgorithm, Any]:
    """
    A saved model (``algo``: its registered name) on a single env with its frozen VecNormalize statistics.

    :param path: The model zip
    :param statistics: Its ``VecNormalize`` statistics, ``None`` without
    :param env_id: The env
    :param algo: ``"ppo"`` or ``"ppolag"``
    :param seed: Seed of the policy (its actions are deterministic here)
    :return: The model and the env
    """
    venv: Any = DummyVecEnv([lambda: gym.make(env_id)])
    if statistics is not None:
        venv = VecNormalize.load(statistics, venv)
        venv.training, venv.norm_reward = False, False
    return load_run_model(algo, path, "cpu", seed), venv


def run_policy(model: BaseAlgorithm, venv: Any, episodes: int, seed: int, feature: FeatureConstraint) -> Episodes:
    """Deterministic episodes, one at a time, env seeds ``seed, seed + 1, ...``."""
    violated, returns, feasible, closest = [], [], [], []
    for episode in range(episodes):
        venv.seed(seed + episode)
        obs = venv.reset()
        raw = venv.get_original_obs() if isinstance(venv, VecNormalize) else obs
        closest_x = float(feature.margin(np.asarray(raw)[0, feature.obs_index]))
        total = feasible_total = 0.0
        broken, done = False, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, dones, infos = venv.step(action)
            info = infos[0]
            reward_value = float(venv.get_original_reward()[0]) if isinstance(venv, VecNormalize) else float(reward[0])
            # The state the step reached (the terminal observation at an episode's end)
            reached = info.get("terminal_observation") if dones[0] else None
            if reached is not None and isinstance(venv, VecNormalize):
                reached = venv.unnormalize_obs(reached)  # VecNormalize normalises the terminal observation too
            if reached is None:
                reached = venv.get_original_obs()[0] if isinstance(venv, VecNormalize) else obs[0]
            closest_x = min(closest_x, float(feature.margin(np.asarray(reached)[feature.obs_index])))
            broken |= float(info["cost"]) > 0
            total += reward_value
            if not broken:
                feasible_total += reward_value
            done = bool(dones[0])
        violated.append(broken)
        returns.append(total)
        feasible.append(feasible_total)
        closest.append(closest_x)
    return Episodes(float(np.mean(violated)), float(np.mean(returns)), float(np.mean(feasible)), closest)


def run_paths(run: str, model: str = "final") -> tuple[str, str | None, str]:
    """The model zip of a run folder (its final model, or ``best_model.zip``), its VecNormalize statistics and algo."""
    algo, env_id, _, _ = describe_run(run)
    name = env_name(env_id)
    zip_path = model_path(run, name, model == "best", None, False)
    return zip_path, find_vecnormalize(zip_path, name), algo


def demonstrations_closest(name: str, source: str, feature: FeatureConstraint) -> list[float]:
    demos = load_demonstrations(name if source == "shipped" else source)
    return [float(feature.margin(np.asarray(t.obs)[:, feature.obs_index]).min()) for t in demos.trajectories]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", required=True, help="A benchmark env or binding variant")
    parser.add_argument("--ppo", required=True, help="Run folder of unconstrained PPO on the env")
    parser.add_argument("--expert", required=True, help="Run folder of the PPO-Lagrangian expert, or 'shipped'")
    parser.add_argument(
        "--expert-model",
        choices=("final", "best"),
        default="final",
        help="with a run folder: its final model or its best_model.zip (picked on its own evaluations, env seed 0)",
    )
    parser.add_argument("--demos", default=None, help="The expert's demonstrations: an .npz path or 'shipped'")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--eval-seed", type=int, default=100)
    parser.add_argument("--json", default=None, help="Also write the numbers here")
    args = parser.parse_args()
    th.set_num_threads(1)

    env_id = resolve_env_id(args.env)
    name = env_name(env_id)
    (feature,) = get_constraint_spec(gym.make(env_id)).features

    ppo_model, ppo_env = load_model(*run_paths(args.ppo)[:2], env_id, "ppo", args.eval_seed)
    ppo = run_policy(ppo_model, ppo_env, args.episodes, args.eval_seed, feature)
    if args.expert == "shipped":
        zip_path, statistics = expert_paths(name)
        expert_args = (str(zip_path), str(statistics) if statistics else None)
    else:
        expert_args = run_paths(args.expert, args.expert_model)[:2]
    expert_model, expert_env = load_model(*expert_args, env_id, "ppolag", args.eval_seed)
    expert = run_policy(expert_model, expert_env, args.episodes, args.eval_seed, feature)
    demos = demonstrations_closest(name, args.demos, feature) if args.demos else None

    row: dict[str, Any] = {
        "env": name,
        "constraint": f"x {feature.op} {feature.threshold:g} (obs[{feature.obs_index}])",
        "ppo": {**asdict(ppo), "median_closest": ppo.median_closest},
        "expert": {**asdict(expert), "median_closest": expert.median_closest},
        "demonstrations_median_closest": float(np.median(demos)) if demos else None,
        "binds": ppo.violation_rate >= BINDS_AT,
        "expert_feasible": expert.violation_rate <= EXPERT_MAX_VIOLATION,
    }
    print(f"{platform.machine()}, torch threads 1, {args.episodes} held-out episodes from seed {args.eval_seed}")
    print(
        "| env | constraint | PPO violations | binds | expert return / violations | expert closest (median) "
        "| demos closest (median) |"
    )
    print("|---|---|---|---|---|---|---|")
    demos_text = f"{row['demonstrations_median_closest']:.3g}" if demos else "-"
    print(
        f"| {name} | {row['constraint']} | {ppo.violation_rate:.0%} | {'yes' if row['binds'] else 'no'} "
        f"| {expert.mean_return:.2f} / {expert.violation_rate:.0%} | {expert.median_closest:.3g} | {demos_text} |"
    )
    if args.json:
        atomic_write_json(args.json, row, indent=2)


if __name__ == "__main__":
    main()
