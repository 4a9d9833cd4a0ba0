"""
Where does a learned constraint put its cost? For a blocked MuJoCo env, prints the mean learned cost of a saved ICRL
model (BC2L, MECL or VICRL) per band of the constrained quantity (``x_position``), on the expert's demonstrations and
on a policy's own episodes, next to the true violation share of each band (evaluation only)::

    python benchmarks/learned_cost_by_region.py --algo vicrl --constraint RUN/rl_model_1000000_steps.zip \\
        --policy OTHER_RUN/rl_model_800000_steps.zip --policy-algo vicrl

The policy (default: the constraint's own model) is run for ``--episodes`` episodes from ``--seed`` on; its
``VecNormalize`` statistics are found as ``enjoy.py`` finds them. Pairing one model's constraint with another model's
policy shows whether the constraint penalises behaviour the learner has stopped showing: a constraint fitted only to
the latest nominal data can forget a region, and a policy that goes there is then not stopped
(``benchmarks/RESULTS.md``, BlockedHalfCheetah ICRL).
"""

import argparse
import itertools
import os

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import sb3_icrl.envs  # noqa: F401  (registers the environments)
from sb3_icrl.constraints import BetaFeasibilityNet
from sb3_icrl.data import NormalizedExpert, Trajectory, load_demonstrations
from sb3_icrl.data.generate import rollout_trajectory
from sb3_icrl.envs import CONSTRAINED_FEATURE
from sb3_icrl.envs.constraint_spec import OPERATORS
from sb3_icrl.registry import ALGOS
from sb3_icrl.run_folder import find_vecnormalize

DEFAULT_EDGES = (-10.0, -3.0, 0.0, 5.0, 20.0)


def learned_cost(
    model, obs: np.ndarray, acts: np.ndarray, cost_mode: str | None, confidence: float | None = None
) -> np.ndarray:
    """The learned cost per pair (``1 - phi``; for a Beta model, ``cost_mode`` and ``confidence`` override its own)."""
    net = model.constraint_net
    if isinstance(net, BetaFeasibilityNet) and (cost_mode is not None or confidence is not None):
        return 1.0 - net.predict_feasibility(obs, acts, cost_mode=cost_mode, confidence=confidence)
    return net.cost(obs, acts)


def episodes(policy, env_id: str, stats_path: str | None, n_episodes: int, seed: int, deterministic: bool) -> list[Trajectory]:
    """``n_episodes`` episodes of ``policy`` with raw observations (env seeds from ``seed`` on)."""
    env = gym.make(f"sb3_icrl/{env_id}")
    if stats_path is not None:
        policy = NormalizedExpert(policy, VecNormalize.load(stats_path, DummyVecEnv([lambda: gym.make(f"sb3_icrl/{env_id}")])))
    trajectories = [
        rollout_trajectory(lambda obs: policy.predict(obs, deterministic=deterministic)[0], env, seed=seed + episode)
        for episode in range(n_episodes)
    ]
    env.close()
    return trajectories


def rollouts(policy, env_id: str, stats_path: str | None, n_episodes: int, seed: int, deterministic: bool):
    """Raw observations, actions and the constrained quantity after each step, over ``n_episodes`` episodes."""
    trajectories = episodes(policy, env_id, stats_path, n_episodes, seed, deterministic)
    return pairs_and_values(trajectories, CONSTRAINED_FEATURE[env_id].obs_index)


def pairs_and_values(trajectories, obs_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observations and actions of all steps, and the constrained quantity after each (in the next observation)."""
    return (
        np.concatenate([t.obs[:-1] for t in trajectories]),
        np.concatenate([t.acts for t in trajectories]),
        np.concatenate([t.obs[1:, obs_index] for t in trajectories]),
    )


def band_rows(values: np.ndarray, costs: np.ndarray, edges: np.ndarray, env_id: str) -> list[str]:
    constraint = CONSTRAINED_FEATURE[env_id]
    bounds = np.concatenate([[-np.inf], edges, [np.inf]])
    rows = []
    for low, high in itertools.pairwise(bounds):
        in_band = (values >= low) & (values < high)
        if not in_band.any():
            continue
        broken = OPERATORS[constraint.op](values[in_band], constraint.threshold)
        rows.append(
            f"  {constraint.name} in [{low:7.1f}, {high:7.1f}) {in_band.sum():7d} pairs"
            f"  learned cost {costs[in_band].mean():.3f}  (true violation in {broken.mean():4.0%})"
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", required=True, choices=["bc2l", "mecl", "vicrl"], help="Algorithm of --constraint")
    parser.add_argument("--constraint", required=True, help="Saved model whose constraint is read")
    parser.add_argument("--env", default="BlockedHalfCheetah-v0", choices=sorted(CONSTRAINED_FEATURE))
    parser.add_argument("--policy", help="Saved model whose policy is run (default: --constraint)")
    parser.add_argument("--policy-algo", help="Algorithm of --policy (default: --algo)")
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--seed", type=int, default=200)
    parser.add_argument("--stochastic", action="store_true", help="Sample the policy's actions")
    parser.add_argument("--cost-mode", help="VICRL: cost mode to read (default: the model's own)")
    parser.add_argument("--confidence", type=float, help="VICRL: level of the var and cvar cost modes (default: the model's)")
    parser.add_argument("--edges", type=float, nargs="+", default=list(DEFAULT_EDGES), help="Band edges")
    args = parser.parse_args()
    th.set_num_threads(1)

    for path in filter(None, (args.constraint, args.policy)):
        if not os.path.isfile(path):
            raise SystemExit(f"No saved model at {path}.")
    model = ALGOS[args.algo].load(args.constraint, device="cpu")
    policy_path = args.policy or args.constraint
    policy = ALGOS[args.policy_algo or args.algo].load(policy_path, device="cpu")
    edges = np.sort(np.array(args.edges))

    demonstrations = load_demonstrations(args.env)
    expert_obs, expert_acts, expert_values = pairs_and_values(
        demonstrations.trajectories, CONSTRAINED_FEATURE[args.env].obs_index
    )
    expert_costs = learned_cost(model, expert_obs, expert_acts, args.cost_mode, args.confidence)
    print(f"Constraint of {args.constraint}")
    print(f"Expert demonstrations: {len(expert_obs)} pairs, learned cost {expert_costs.mean():.3f}")
    print("\n".join(band_rows(expert_values, expert_costs, edges, args.env)))

    stats_path = find_vecnormalize(policy_path, args.env)
    obs, acts, values = rollouts(policy, args.env, stats_path, args.episodes, args.seed, not args.stochastic)
    costs = learned_cost(model, obs, acts, args.cost_mode, args.confidence)
    mode = "stochastic" if args.stochastic else "deterministic"
    print(f"Policy of {policy_path} ({args.episodes} {mode} episodes): {len(obs)} pairs, learned cost {costs.mean():.3f}")
    print("\n".join(band_rows(values, costs, edges, args.env)))


if __name__ == "__main__":
    main()
