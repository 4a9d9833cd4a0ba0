"""
Does a learned constraint generalise along the constrained quantity, or only recognise the gait it was fitted on?
Fits a fresh constraint net (MECL's feasibility net, or with ``--model vicrl`` VICRL's Beta net read by its posterior
mean) on the expert's demonstrations against one policy's episodes (the "nominal" data of a few ICRL updates), once
with the constraint net's input normalisation (fitted on the expert data, the library's default) and once on raw
inputs (the reference code's ``cn_normalize: False``), then prints the learned cost per band
of the constrained quantity on the episodes of other policies::

    python benchmarks/constraint_generalisation.py --fit mecl:RUN/rl_model_300000_steps.zip \\
        --probe vicrl:OTHER/rl_model_800000_steps.zip mecl:RUN/rl_model_500000_steps.zip

Policies are given as ``ALGO:PATH``; their ``VecNormalize`` statistics are found as ``enjoy.py`` finds them. The
true violation share of each band is printed for evaluation only: the fit never sees it.
"""

import argparse
import os
from typing import Any

import numpy as np
import torch as th
from learned_cost_by_region import DEFAULT_EDGES, band_rows, episodes, pairs_and_values

from sb3_icrl.constraints import BetaFeasibilityNet, FeasibilityNet
from sb3_icrl.data import Trajectory, load_demonstrations
from sb3_icrl.envs import CONSTRAINED_FEATURE
from sb3_icrl.icrl.recorder import NominalData, NominalTrajectory
from sb3_icrl.icrl.trainer import ICRLTrainer
from sb3_icrl.mecl import MECLTrainer
from sb3_icrl.registry import ALGOS
from sb3_icrl.run_folder import find_vecnormalize
from sb3_icrl.vicrl import VICRLTrainer


def policy_episodes(spec: str, env_id: str, n_episodes: int, seed: int) -> list[Trajectory]:
    """``n_episodes`` deterministic episodes of the policy ``ALGO:PATH``, raw observations (env seeds from ``seed``)."""
    algo, _, path = spec.partition(":")
    if algo not in ALGOS or not path:
        raise SystemExit(f"Policies are given as ALGO:PATH with ALGO in {sorted(ALGOS)}, got {spec!r}.")
    if not os.path.isfile(path):
        raise SystemExit(f"No saved model at {path}.")
    policy = ALGOS[algo].load(path, device="cpu")
    return episodes(policy, env_id, find_vecnormalize(path, env_id), n_episodes, seed, deterministic=True)


def fit_constraint(
    model: str,
    expert: tuple[np.ndarray, np.ndarray],
    nominal: NominalData,
    normalize_input: bool,
    args: argparse.Namespace,
) -> FeasibilityNet | BetaFeasibilityNet:
    """``args.updates`` constraint updates of the library's own trainer (MECL's or VICRL's) on the same nominal data."""
    th.manual_seed(args.seed)
    net_kwargs: dict[str, Any] = dict(hidden_sizes=args.hidden, normalize_input=normalize_input)
    net: FeasibilityNet | BetaFeasibilityNet
    trainer_type: type[ICRLTrainer]
    if model == "vicrl":
        net = BetaFeasibilityNet(expert[0].shape[1], expert[1].shape[1], cost_mode="mean", **net_kwargs)
        trainer_type, trainer_kwargs = VICRLTrainer, dict(kl_coef=args.delta)
    else:
        net = FeasibilityNet(expert[0].shape[1], expert[1].shape[1], **net_kwargs)
        trainer_type, trainer_kwargs = MECLTrainer, dict(regularizer_coef=args.delta)
    if normalize_input:
        net.fit_normalizer(*expert)
    trainer = trainer_type(
        net,
        th.optim.Adam(net.parameters(), lr=args.learning_rate),
        *expert,
        recorder=None,
        wrapper=None,
        update_every=1,
        constraint_steps=args.passes,
        batch_size=args.batch_size,
        seed=args.seed,
        **trainer_kwargs,
    )
    for _ in range(args.updates):
        stats = trainer.update(nominal)
        print(
            f"  update {trainer.n_updates}: {int(stats['n_passes'])} passes, expert feasibility "
            f"{stats['expert_feasibility']:.3f}, nominal {stats['nominal_feasibility']:.3f}"
        )
    return net


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--fit", required=True, help="ALGO:PATH of the policy whose episodes are the nominal data")
    parser.add_argument("--model", default="mecl", choices=["mecl", "vicrl"], help="Constraint model and loss to fit")
    parser.add_argument("--probe", nargs="+", default=[], help="ALGO:PATH of policies to read the learned cost on")
    parser.add_argument("--env", default="BlockedHalfCheetah-v0", choices=sorted(CONSTRAINED_FEATURE))
    parser.add_argument("--episodes", type=int, default=10, help="Nominal episodes of --fit")
    parser.add_argument("--probe-episodes", type=int, default=4)
    parser.add_argument("--seed", type=int, default=300, help="Episode seeds start here; the fit uses it too")
    parser.add_argument("--updates", type=int, default=3, help="Constraint updates on the nominal data")
    parser.add_argument("--passes", type=int, default=10, help="Passes over the nominal pairs per update")
    parser.add_argument("--batch-size", type=int, default=1000)
    parser.add_argument("--learning-rate", type=float, default=5e-3, help="Constraint learning rate (MECL's recipe: 1e-3)")
    parser.add_argument("--delta", type=float, default=0.5, help="MECL's regulariser; VICRL's KL weight")
    parser.add_argument("--hidden", type=int, nargs="+", default=[20], help="Hidden layer sizes")
    parser.add_argument("--edges", type=float, nargs="+", default=list(DEFAULT_EDGES), help="Band edges")
    args = parser.parse_args()
    th.set_num_threads(1)

    obs_index = CONSTRAINED_FEATURE[args.env].obs_index
    expert_obs, expert_acts, expert_values = pairs_and_values(load_demonstrations(args.env).trajectories, obs_index)
    fitted = policy_episodes(args.fit, args.env, args.episodes, args.seed)
    nominal = NominalData.from_trajectories([NominalTrajectory(t.obs[:-1], t.acts) for t in fitted])
    probes = [(f"{args.fit} (fitted on)", pairs_and_values(fitted, obs_index))] + [
        (spec, pairs_and_values(policy_episodes(spec, args.env, args.probe_episodes, args.seed + 1000 * (i + 1)), obs_index))
        for i, spec in enumerate(args.probe)
    ]
    edges = np.sort(np.array(args.edges))
    print(f"Expert: {len(expert_obs)} pairs; nominal ({args.fit}): {len(nominal)} pairs from {args.episodes} episodes")
    for normalize_input in (True, False):
        label = "inputs normalised on the expert data" if normalize_input else "raw inputs"
        print(f"\n=== {args.model}, {label}")
        net = fit_constraint(args.model, (expert_obs, expert_acts), nominal, normalize_input, args)
        expert_costs = net.cost(expert_obs, expert_acts)
        print(f" expert: learned cost {expert_costs.mean():.3f}")
        print("\n".join(band_rows(expert_values, expert_costs, edges, args.env)))
        for spec, (obs, acts, values) in probes:
            costs = net.cost(obs, acts)
            print(f" {spec}: learned cost {costs.mean():.3f}")
            print("\n".join(band_rows(values, costs, edges, args.env)))


if __name__ == "__main__":
    main()
