"""
Constraint plots from the command line::

    # violation rate and feasible reward over training, mean +- std over the seeds in logs/<algo>/<EnvName>_<N>
    python -m sb3_icrl.plots curves -f logs --algos mecl vicrl --env BlockedHalfCheetah-v0 -o curves.png

    # the learned constraint of a trained ICRL run: grid map (grid worlds) or partial-dependence plot (others)
    python -m sb3_icrl.plots constraint logs/vicrl/BlockedHalfCheetah-v0_1 -o constraint.png

    # per method, the learned cost over the constrained feature (one line per seed), the true threshold marked
    python -m sb3_icrl.plots methods logs/mecl/BlockedHalfCheetah-v0_* logs/vicrl/BlockedHalfCheetah-v0_* -o methods.png
"""

import argparse
import pathlib
import sys
import warnings
from typing import Any

import numpy as np

from sb3_icrl.common.utils import plain_docstring, write_error_message
from sb3_icrl.common.vec_env import load_vec_normalize
from sb3_icrl.data import load_demonstrations
from sb3_icrl.envs.wrappers import recorded_transition_noise, transition_noise_wrapper
from sb3_icrl.metrics.identification import methods_figure
from sb3_icrl.plots.figures import (
    CURVE_METRICS,
    TrueConstraint,
    constraint_features,
    grid_constraint_figure,
    grid_cost_map,
    load_runs,
    partial_dependence_figure,
    save_figure,
    training_curves_figure,
)
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id
from sb3_icrl.run_folder import load_run_args, run_vecnormalize


def get_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m sb3_icrl.plots``."""
    parser = argparse.ArgumentParser(
        prog="python -m sb3_icrl.plots",
        description=plain_docstring(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    commands = parser.add_subparsers(dest="command", required=True)

    curves = commands.add_parser("curves", help="Evaluation metrics over training, mean +- std over seeds")
    curves.add_argument("-f", "--log-folder", default="logs", help="Training log folder (holds <algo>/<EnvName>_<N>)")
    curves.add_argument("--algos", nargs="+", required=True, help="Algorithms, one line each (e.g. mecl vicrl)")
    curves.add_argument("--env", required=True, help="Env name or id (e.g. BlockedHalfCheetah-v0, myns/MyEnv-v0)")
    curves.add_argument("--gym-packages", nargs="+", default=[], help="Modules to import first: they register your envs")
    curves.add_argument("--metrics", nargs="+", default=["violation_rate", "feasible_reward"], choices=list(CURVE_METRICS))
    curves.add_argument("--skip-missing", action="store_true", help="Skip runs without evaluations.npz (default: error)")
    curves.add_argument("--title", default=None, help="Figure title (default: the env)")
    curves.add_argument("-o", "--output", required=True, help="Image file (.png, .pdf, .svg)")

    constraint = commands.add_parser("constraint", help="The learned constraint of a trained ICRL run")
    constraint.add_argument("run_folder", help="A run folder: <log folder>/<algo>/<EnvName>_<N>")
    constraint.add_argument("--model", default=None, help="'final' (<EnvName>.zip), 'best' (best_model.zip) or a path")
    constraint.add_argument("--demonstrations", default=None, help="Dataset name or .npz (default: the run's)")
    constraint.add_argument(
        "--feature",
        default=None,
        help="Constrained feature: its name or index when the env declares several; for an env that declares none, the "
        "observation index to plot (with --threshold and --op)",
    )
    constraint.add_argument(
        "--threshold", type=float, default=None, help="True threshold on --feature (an env without a declared constraint)"
    )
    constraint.add_argument(
        "--op", choices=["<=", "<", ">=", ">"], default=None, help="Side of --threshold that breaks the constraint"
    )
    constraint.add_argument(
        "--gym-packages", nargs="+", default=[], help="Modules to import first (besides those the run's args.yml names)"
    )
    constraint.add_argument("--episodes", type=int, default=5, help="Policy episodes for the visited-values histogram")
    constraint.add_argument("--no-beta-samples", action="store_true", help="VICRL: no spread of sampled costs")
    constraint.add_argument("--seed", type=int, default=0, help="Seed of the rollouts and samples")
    constraint.add_argument("-o", "--output", required=True, help="Image file (.png, .pdf, .svg)")

    methods = commands.add_parser("methods", help="Learned cost over the constrained feature, per method, one env")
    methods.add_argument("runs", nargs="+", help="ICRL run folders on one env (<log folder>/<algo>/<EnvName>_<N>)")
    methods.add_argument("--feature", default=None, help="Constrained feature (name) when the env has several")
    methods.add_argument("--level", type=float, default=0.5, help="Level t drawn as a dotted line")
    methods.add_argument("--title", default=None, help="Figure title (default: the env)")
    methods.add_argument("-o", "--output", required=True, help="Image file (.png, .pdf, .svg)")
    return parser


def plot_methods(args: argparse.Namespace) -> pathlib.Path:
    """The ``methods`` command (curves from each run's identification scores); returns the image written."""
    return save_figure(methods_figure(args.runs, args.feature, args.level, args.title), args.output)


def plot_curves(args: argparse.Namespace) -> pathlib.Path:
    """The ``curves`` command; returns the image written."""
    import_gym_packages(args.gym_packages)
    try:
        with warnings.catch_warnings(record=True) as skipped:
            warnings.simplefilter("always")
            runs = load_runs(args.log_folder, args.algos, args.env, skip_missing=args.skip_missing, metrics=args.metrics)
    except FileNotFoundError as error:
        hint = " Pass --skip-missing to plot the other runs." if "No evaluations.npz" in str(error) else ""
        raise FileNotFoundError(f"{error}{hint}") from error
    except ValueError as error:  # an evaluations.npz that is damaged or was not written by train.py (named)
        raise ValueError(f"{error} Pass --skip-missing to plot the other runs.") from error
    for warning in skipped:
        print(f"warning: {warning.message}", file=sys.stderr)
    title = args.title if args.title is not None else env_name(args.env)
    return save_figure(training_curves_figure(runs, metrics=args.metrics, title=title), args.output)


def read_run(run_folder: str) -> tuple[pathlib.Path, dict[str, Any]]:
    """
    The arguments a training run was started with (``<run>/<EnvName>/args.yml``).

    :param run_folder: The run folder
    :return: The folder and its arguments
    """
    path, run_args = load_run_args(run_folder)
    for key in ("algo", "env"):
        if key not in run_args:
            raise ValueError(f"{path} has no {key!r}.")
    return pathlib.Path(run_folder), run_args


def _model_path(folder: pathlib.Path, name: str, choice: str | None) -> pathlib.Path:
    candidates = {"final": folder / f"{name}.zip", "best": folder / "best_model.zip"}
    if choice is None:
        path = next((p for p in candidates.values() if p.is_file()), candidates["final"])
    else:
        path = candidates.get(choice, pathlib.Path(choice))
    if not path.is_file():
        raise FileNotFoundError(f"No model {path} (saved models there: {sorted(p.name for p in folder.glob('*.zip'))}).")
    return path


def _pick_constraint(
    constraints: tuple[TrueConstraint, ...],
    feature: str | None,
    threshold: float | None = None,
    op: str | None = None,
) -> TrueConstraint:
    """
    The constraint to plot: the env's declared one (``feature`` picks among several; ``threshold``/``op`` override),
    or, for an env that declares none (``constraints`` empty), the observation index ``feature``.

    :return: The constraint; its threshold is ``nan`` when none is known (the figure then draws no threshold)
    """
    if not constraints:
        if feature is None or not feature.lstrip("-").isdigit():
            raise ValueError(
                "This env declares no feature constraint: name the observation feature to plot with --feature INDEX "
                "[--threshold X] [--op '<=' or '>='], or give the env a `constraint_spec` (sb3_icrl.common.constraint_spec)."
            )
        if int(feature) < 0:
            raise ValueError(f"--feature must be an observation index >= 0, got {feature}.")
        if (threshold is None) != (op is None):
            raise ValueError("--threshold and --op go together: the side of the threshold that breaks the constraint.")
        return TrueConstraint(f"obs[{feature}]", int(feature), float("nan") if threshold is None else threshold, op or ">=")
    if feature is None:
        chosen = constraints[0]
        if len(constraints) > 1:
            others = ", ".join(c.name for c in constraints[1:])
            print(f"note: plotting {chosen.name}; the env also constrains {others} (--feature).", file=sys.stderr)
    else:
        matches = [c for c in constraints if feature in (c.name, str(c.obs_index))]
        if not matches:
            if not feature.isdigit():
                raise ValueError(f"Unknown feature {feature!r}: this env constrains {', '.join(c.name for c in constraints)}.")
            matches = [TrueConstraint(f"obs[{feature}]", int(feature), float("nan"), op or ">=")]
        chosen = matches[0]
    if threshold is not None:
        chosen = chosen._replace(threshold=threshold)
    if op is not None:
        chosen = chosen._replace(op=op)
    return chosen


def policy_observations(
    model: Any,
    env_id: str,
    env_kwargs: dict[str, Any],
    stats_path: str | None,
    run_args: dict[str, Any],
    n_episodes: int,
    seed: int,
) -> np.ndarray:
    """
    Raw observations visited by the model's deterministic policy, with the run's saved normalisation.

    :param model: The trained model
    :param env_id: Registered env id
    :param env_kwargs: The run's env keyword arguments
    :param stats_path: The model's ``VecNormalize`` statistics (``None``: the run did not normalise; see
        :func:`~sb3_icrl.run_folder.run_vecnormalize`)
    :param run_args: The run's ``args.yml`` (its transition noise)
    :param n_episodes: Episodes to run
    :param seed: Seed of the env
    :return: ``(n_steps, obs_dim)``
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    wrapper = transition_noise_wrapper(*recorded_transition_noise(run_args))
    venv: Any = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=env_kwargs, wrapper_class=wrapper)
    if stats_path is not None:
        venv = load_vec_normalize(stats_path, venv)
        venv.training, venv.norm_reward = False, False
    observations: list[np.ndarray] = []
    obs = venv.reset()
    finished = 0
    while finished < n_episodes:
        observations.append(np.asarray(venv.get_original_obs() if isinstance(venv, VecNormalize) else obs))
        action, _ = model.predict(obs, deterministic=True)
        obs, _, dones, _ = venv.step(action)
        finished += int(dones.sum())
    venv.close()
    return np.concatenate(observations).reshape(-1, np.shape(observations[0])[-1])


def plot_constraint(args: argparse.Namespace) -> pathlib.Path:
    """The ``constraint`` command; returns the image written."""
    import gymnasium as gym

    import_gym_packages(args.gym_packages)
    folder, run_args = read_run(args.run_folder)
    algo = run_args["algo"]
    if algo not in ICRL_ALGOS:
        raise ValueError(f"{folder} is a {algo} run: only ICRL runs ({', '.join(ICRL_ALGOS)}) learn a constraint to plot.")
    import_gym_packages(run_args.get("gym_packages"))  # a user's env registers itself on import
    env_id = resolve_env_id(run_args["env"])
    name = env_name(env_id)  # the run folder's name for the env, as train.py wrote it
    env_kwargs = dict(run_args.get("env_kwargs") or {})
    model_file = _model_path(folder, name, args.model)
    model = ALGOS[algo].load(str(model_file), device="cpu")
    net: Any = model.constraint_net  # type: ignore[attr-defined]
    source = args.demonstrations or run_args.get("demonstrations") or name
    fraction = None if args.demonstrations else run_args.get("violating_fraction")
    demonstrations = load_demonstrations(source, violating_fraction=fraction)
    transitions = demonstrations.transitions
    title = f"{algo.upper()} on {name} ({folder.name})"

    if net.discrete_obs:
        grid: Any = gym.make(env_id, **env_kwargs).unwrapped
        visited = np.zeros(grid.n_states, dtype=bool)
        visited[np.asarray(transitions.obs, dtype=int).reshape(-1)] = True
        figure = grid_constraint_figure(
            grid_cost_map(net, grid),
            grid.unsafe_mask,
            grid.start_cell,
            grid.goal_cell,
            visited=visited.reshape(grid.unsafe_mask.shape),
            title=title,
        )
    else:
        try:
            declared = constraint_features(env_id, env_kwargs)
        except ValueError:
            declared = ()  # no declaration: --feature INDEX names what to plot
        constraint = _pick_constraint(declared, args.feature, args.threshold, args.op)
        obs_dim = np.asarray(transitions.obs).shape[1]
        if constraint.obs_index >= obs_dim:
            raise ValueError(f"--feature {constraint.obs_index} is outside the {obs_dim} observation features.")
        visited_values = {"expert": np.asarray(transitions.obs)[:, constraint.obs_index]}
        if args.episodes > 0:
            stats_path = run_vecnormalize(str(folder), str(model_file), name)
            policy_obs = policy_observations(model, env_id, env_kwargs, stats_path, run_args, args.episodes, args.seed)
            visited_values[f"policy ({args.episodes} episodes)"] = policy_obs[:, constraint.obs_index]
        figure = partial_dependence_figure(
            net,
            transitions.obs,
            transitions.acts,
            constraint.obs_index,
            constraint.threshold,
            constraint.op,
            visited_values,
            beta_samples=not args.no_beta_samples,
            feature_name=constraint.name,
            title=title,
            seed=args.seed,
        )
    return save_figure(figure, args.output)


def main(argv: list[str] | None = None) -> int:
    """
    Command-line entry point.

    :param argv: Arguments (default: ``sys.argv[1:]``)
    :return: Exit status: 0, or 2 after a clear error
    """
    args = get_parser().parse_args(argv)
    try:
        commands = {"curves": plot_curves, "constraint": plot_constraint, "methods": plot_methods}
        path = commands[args.command](args)
    except (FileNotFoundError, ValueError, TypeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        message = write_error_message(error)  # -o in a folder that cannot be written
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        return 2
    print(f"Saved {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
