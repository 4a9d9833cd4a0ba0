"""
Command line for demonstrations::

    python -m sb3_icrl.data generate --env BlockedHalfCheetah-v0 --expert expert.zip --vecnormalize vecnormalize.pkl \\
        --n 50 --out BlockedHalfCheetah-v0.npz [--violating-fraction 0.2] [--seed 0] [--no-deterministic]
    python -m sb3_icrl.data generate --env GridWorldWall-v0 --expert pilag --n 50 --out GridWorldWall-v0.npz
    python -m sb3_icrl.data shipped   # regenerate the datasets shipped with the package
    python -m sb3_icrl.data list      # list them
    python -m sb3_icrl.data table     # Markdown table of them (the README's)
    python -m sb3_icrl.data info FILE_OR_NAME
"""

import argparse
import json
import shlex
import sys
from collections.abc import Sequence

from sb3_icrl.data.generate import EXPERT_ALGORITHMS, build_dataset
from sb3_icrl.data.registry import (
    DEMONSTRATIONS_DIR,
    available_demonstrations,
    datasets_table,
    load_demonstrations,
    regenerate_shipped,
)
from sb3_icrl.data.serialize import DemonstrationError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sb3_icrl.data", description="Expert demonstrations for ICRL.")
    commands = parser.add_subparsers(dest="command", required=True)

    generate = commands.add_parser("generate", help="Run an expert and save the trajectories that respect the constraint.")
    generate.add_argument("--env", required=True, help="Env id or benchmark name, e.g. BlockedHalfCheetah-v0")
    generate.add_argument(
        "--expert", required=True, help="'pilag' (train PI-Lagrangian, grid world), a PILagrangian .npz or an SB3 .zip"
    )
    generate.add_argument("--algo", default="ppolag", choices=sorted(EXPERT_ALGORITHMS), help="Algorithm of a .zip expert")
    generate.add_argument("--vecnormalize", default=None, help="VecNormalize statistics saved with the expert")
    generate.add_argument("--n", type=int, default=50, help="Trajectories to keep")
    generate.add_argument("--out", required=True, help="Destination .npz (a .json sidecar is written beside it)")
    generate.add_argument(
        "--violating-fraction", type=float, default=0.0, help="Share of violating trajectories (0.2/0.5/0.8)"
    )
    generate.add_argument(
        "--random-action-prob", type=float, default=0.5, help="Per-step random actions in violating rollouts"
    )
    generate.add_argument("--seed", type=int, default=0)
    generate.add_argument(
        "--deterministic", action=argparse.BooleanOptionalAction, default=True, help="Deterministic expert (the paper's)"
    )
    generate.add_argument(
        "--env-kwargs", type=json.loads, default={}, help="JSON keyword arguments of gym.make, e.g. '{\"slip_prob\": 0.1}'"
    )
    generate.add_argument("--max-attempts", type=int, default=None, help="Episodes to try before giving up")

    shipped = commands.add_parser("shipped", help=f"Regenerate the datasets shipped in {DEMONSTRATIONS_DIR}.")
    shipped.add_argument("--env", nargs="+", default=None, help="Only these env names (default: all)")
    commands.add_parser("list", help="List the shipped datasets.")
    commands.add_parser("table", help="Markdown table of the shipped datasets (the README's).")
    info = commands.add_parser("info", help="Validate a dataset and print its statistics.")
    info.add_argument("name_or_path")
    info.add_argument("--violating-fraction", type=float, default=None)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """
    :param argv: Command-line arguments (default: ``sys.argv[1:]``)
    :return: Exit status
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(argv)
    try:
        if args.command == "generate":
            sidecar = build_dataset(
                args.out,
                args.env,
                args.expert,
                args.n,
                env_kwargs=args.env_kwargs,
                algo=args.algo,
                vec_normalize_path=args.vecnormalize,
                command=shlex.join(["python", "-m", "sb3_icrl.data", *argv]),
                violating_fraction=args.violating_fraction,
                random_action_prob=args.random_action_prob,
                seed=args.seed,
                deterministic=args.deterministic,
                max_attempts=args.max_attempts,
            )
            generation = sidecar["generation"]
            print(
                f"Wrote {args.out}: {sidecar['n_trajectories']} trajectories, mean return {sidecar['mean_return']:.3f}, "
                f"{sidecar['n_violating_trajectories']} violating; the expert broke the constraint in "
                f"{generation['expert_violation_rate']:.1%} of its episodes."
            )
        elif args.command == "shipped":
            regenerate_shipped(names=args.env)
        elif args.command == "table":
            print(datasets_table())
        elif args.command == "list":
            for name, fractions in available_demonstrations().items():
                print(f"{name}: violating_fraction {', '.join(f'{f:g}' for f in fractions)}")
        else:
            demos = load_demonstrations(args.name_or_path, violating_fraction=args.violating_fraction)
            keys = ("env_id", "n_trajectories", "n_transitions", "mean_return", "std_return", "violating_share", "sha256")
            print(json.dumps({key: demos.metadata.get(key) for key in keys}, indent=2))
    except (DemonstrationError, ValueError, FileNotFoundError, RuntimeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
