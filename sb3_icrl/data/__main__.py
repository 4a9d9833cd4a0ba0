"""
Command line for demonstrations::

    python -m sb3_icrl.data generate --env BlockedHalfCheetah-v0 --expert expert.zip --vecnormalize vecnormalize.pkl \\
        --n 50 --out BlockedHalfCheetah-v0.npz [--violating-fraction 0.2] [--seed 0] [--no-deterministic]
    python -m sb3_icrl.data generate --env GridWorldWall-v0 --expert pilag --n 50 --out GridWorldWall-v0.npz
    # the expert of a train.py run: its env, model and VecNormalize statistics ([--model best|final])
    python -m sb3_icrl.data generate --run logs/ppolag/MyEnv-v0_1 --n 50 --out MyEnv-v0.npz
    python -m sb3_icrl.data shipped   # regenerate the datasets shipped with the package
    python -m sb3_icrl.data list      # list them
    python -m sb3_icrl.data table     # Markdown table of them (the README's)
    python -m sb3_icrl.data info FILE_OR_NAME
"""

import argparse
import json
import os
import shlex
import sys
from collections.abc import Sequence
from typing import Any

from sb3_icrl.common.utils import write_error_message
from sb3_icrl.data.generate import EXPERT_ALGORITHMS, build_dataset, resolve_env_id
from sb3_icrl.data.registry import (
    DEMONSTRATIONS_DIR,
    available_demonstrations,
    datasets_table,
    load_demonstrations,
    regenerate_shipped,
)
from sb3_icrl.data.serialize import DemonstrationError
from sb3_icrl.registry import env_name, import_gym_packages
from sb3_icrl.run_folder import failure, read_run_record, run_vecnormalize


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sb3_icrl.data", description="Expert demonstrations for ICRL.")
    commands = parser.add_subparsers(dest="command", required=True)

    generate = commands.add_parser("generate", help="Run an expert and save the trajectories that respect the constraint.")
    generate.add_argument(
        "--env", default=None, help="Env id or benchmark name, e.g. BlockedHalfCheetah-v0 or MODULE:myns/MyEnv-v0"
    )
    generate.add_argument(
        "--expert", default=None, help="'pilag' (train PI-Lagrangian, grid world), a PILagrangian .npz or an SB3 .zip"
    )
    generate.add_argument(
        "--run", default=None, help="A train.py run folder of the expert (instead of --env, --expert, --vecnormalize)"
    )
    generate.add_argument("--model", choices=["final", "best"], default="final", help="With --run: the model to use")
    generate.add_argument("--gym-packages", nargs="+", default=[], help="Modules to import first: they register your own envs")
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


def expert_of_run(run: str, model: str = "final") -> dict[str, Any]:
    """
    The expert of a ``train.py`` run folder: its env, model, algorithm, ``VecNormalize`` statistics and the modules
    that register its env.

    :param run: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :param model: ``"final"`` (``<EnvName>.zip``) or ``"best"`` (``best_model.zip``)
    :return: ``env``, ``expert``, ``algo``, ``vecnormalize``, ``env_kwargs`` and ``gym_packages``
    :raises FileNotFoundError: When the folder, its ``args.yml``, the model or its statistics are missing
    :raises ValueError: When the run's algorithm cannot be an expert
    """
    record = read_run_record(run)
    if record.algo not in EXPERT_ALGORITHMS:
        raise ValueError(f"{run} is a {record.algo} run; an expert is one of {', '.join(sorted(EXPERT_ALGORITHMS))}.")
    name = env_name(record.env)
    path = os.path.join(run, f"{name}.zip" if model == "final" else "best_model.zip")
    reason = failure(run)
    if model == "final" and reason is not None:
        raise ValueError(f"{run} failed ({reason}), so it has no final model: use --model best, or finish the run first.")
    if not os.path.isfile(path):
        there = sorted(entry for entry in os.listdir(run) if entry.endswith(".zip"))
        raise FileNotFoundError(f"No {os.path.basename(path)} in {run}; models there: {', '.join(there) or 'none'}.")
    return {
        "env": record.env,
        "expert": path,
        "algo": record.algo,
        "vecnormalize": run_vecnormalize(run, path, name),
        "env_kwargs": record.env_kwargs,
        "gym_packages": record.gym_packages,
    }


def regeneration_command(args: argparse.Namespace, argv: Sequence[str]) -> str:
    """
    Complete ``args`` of ``generate`` (from ``--run``, and importing ``--gym-packages``) and return the command that
    regenerates the file: env, expert and statistics spelled out, with the modules that register the env.

    :param args: Parsed ``generate`` arguments (completed in place)
    :param argv: The command line as given
    :return: The command, for the sidecar
    """
    import_gym_packages(args.gym_packages)
    if args.run is not None:
        if args.expert is not None or args.vecnormalize is not None:
            raise ValueError(
                "--run takes the expert and its statistics from the run folder: leave out --expert and --vecnormalize."
            )
        found = expert_of_run(args.run, args.model)
        if args.env is not None and resolve_env_id(args.env) != found["env"]:
            raise ValueError(f"{args.run} trained on {found['env']}, not on {args.env}: leave out --env.")
        args.env, args.expert, args.algo, args.vecnormalize = (
            found["env"],
            found["expert"],
            found["algo"],
            found["vecnormalize"],
        )
        args.env_kwargs = {**found["env_kwargs"], **args.env_kwargs}
        args.gym_packages = list(dict.fromkeys([*args.gym_packages, *found["gym_packages"]]))
    elif args.env is None or args.expert is None:
        raise ValueError("generate needs --env and --expert, or --run with a train.py run folder of the expert.")
    if args.run is None:  # the command as given names the env's modules already (--gym-packages, MODULE:EnvId)
        return shlex.join(["python", "-m", "sb3_icrl.data", *argv])
    words = ["python", "-m", "sb3_icrl.data", "generate", "--env", resolve_env_id(args.env), "--expert", args.expert]
    words += ["--algo", args.algo] + (["--vecnormalize", args.vecnormalize] if args.vecnormalize else [])
    words += ["--gym-packages", *args.gym_packages] if args.gym_packages else []
    words += ["--env-kwargs", json.dumps(args.env_kwargs)] if args.env_kwargs else []
    words += ["--n", str(args.n), "--out", args.out, "--violating-fraction", f"{args.violating_fraction:g}"]
    words += ["--random-action-prob", f"{args.random_action_prob:g}", "--seed", str(args.seed)]
    words += ["--deterministic" if args.deterministic else "--no-deterministic"]
    words += ["--max-attempts", str(args.max_attempts)] if args.max_attempts is not None else []
    return shlex.join(words)


def _check_output_folder(out: str) -> None:
    """
    Fail before any rollout when ``--out`` is not an ``.npz`` path (numpy would write ``d.txt`` as ``d.txt.npz``, this
    command as ``d.txt``: neither is what was meant) or cannot be written: a file where a folder should be, or a
    read-only folder.
    """
    if not out.endswith(".npz"):
        stem, suffix = os.path.splitext(out)
        fixed = (stem if suffix else out) + ".npz"
        raise ValueError(
            f"--out {out!r} does not end in .npz: the demonstrations are an .npz archive (with a .json sidecar beside it); "
            f"pass --out {fixed}."
        )
    folder = os.path.dirname(os.path.abspath(out))
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ValueError(f"--out {out!r} cannot be written: {folder} is a file, not a folder.")
    if os.path.isdir(out):
        raise ValueError(f"--out {out!r} is a folder: give the path of the .npz file to write.")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(
            f"--out {out!r} cannot be written: {folder} is not writable; give a path in a folder you can write to."
        )


def main(argv: Sequence[str] | None = None) -> int:
    """
    :param argv: Command-line arguments (default: ``sys.argv[1:]``)
    :return: Exit status
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(argv)
    try:
        if args.command == "generate":
            _check_output_folder(args.out)
            if args.seed < 0:
                raise ValueError(f"--seed must be an integer >= 0, got {args.seed}.")
            command = regeneration_command(args, argv)
            sidecar = build_dataset(
                args.out,
                args.env,
                args.expert,
                args.n,
                env_kwargs=args.env_kwargs,
                algo=args.algo,
                vec_normalize_path=args.vecnormalize,
                command=command,
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
            shown = {key: demos.metadata.get(key) for key in keys}
            if demos.metadata.get("true_costs_known") is False:
                # The costs are zeros standing for unknown ones: a share of 0 would say the data is clean
                shown["violating_share"] = "unknown (the source recorded no true costs)"
            print(json.dumps(shown, indent=2))
    except (DemonstrationError, ValueError, OSError, RuntimeError) as error:
        # OSError: e.g. a disk that fills up while --out is written
        message = write_error_message(error) if isinstance(error, OSError) else None
        print(f"error: {message or error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        # Each file is written whole (atomically): what an interrupted command leaves is complete or absent
        print(f"\ninterrupted: `{args.command}` stopped before its end; run it again to finish it.", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
