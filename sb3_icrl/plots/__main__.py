"""
Constraint plots from the command line::

    # violation rate and feasible reward over training, mean +- std over the seeds in logs/<algo>/<EnvName>_<N>
    python -m sb3_icrl.plots curves -f logs --algos mecl vicrl --env BlockedHalfCheetah-v0 -o curves.png

    # the learned constraint of a trained ICRL run: grid map (grid worlds) or partial-dependence plot (others)
    python -m sb3_icrl.plots constraint logs/vicrl/BlockedHalfCheetah-v0_1 -o constraint.png
"""

import argparse
import pathlib
import sys
import warnings
from typing import Any

import numpy as np
import yaml

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


def get_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m sb3_icrl.plots``."""
    parser = argparse.ArgumentParser(
        prog="python -m sb3_icrl.plots", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)

    curves = commands.add_parser("curves", help="Evaluation metrics over training, mean +- std over seeds")
    curves.add_argument("-f", "--log-folder", default="logs", help="Training log folder (holds <algo>/<EnvName>_<N>)")
    curves.add_argument("--algos", nargs="+", required=True, help="Algorithms, one line each (e.g. mecl vicrl)")
    curves.add_argument("--env", required=True, help="Env name or id (e.g. BlockedHalfCheetah-v0)")
    curves.add_argument("--metrics", nargs="+", default=["violation_rate", "feasible_reward"], choices=list(CURVE_METRICS))
    curves.add_argument("--skip-missing", action="store_true", help="Skip runs without evaluations.npz (default: error)")
    curves.add_argument("--title", default=None, help="Figure title (default: the env)")
    curves.add_argument("-o", "--output", required=True, help="Image file (.png, .pdf, .svg)")

    constraint = commands.add_parser("constraint", help="The learned constraint of a trained ICRL run")
    constraint.add_argument("run_folder", help="A run folder: <log folder>/<algo>/<EnvName>_<N>")
    constraint.add_argument("--model", default=None, help="'final' (<EnvName>.zip), 'best' (best_model.zip) or a path")
    constraint.add_argument("--demonstrations", default=None, help="Dataset name or .npz (default: the run's)")
    constraint.add_argument("--feature", default=None, help="Constrained feature (name or index) when there are several")
    constraint.add_argument("--episodes", type=int, default=5, help="Policy episodes for the visited-values histogram")
    constraint.add_argument("--no-beta-samples", action="store_true", help="VICRL: no spread of sampled costs")
    constraint.add_argument("--seed", type=int, default=0, help="Seed of the rollouts and samples")
    constraint.add_argument("-o", "--output", required=True, help="Image file (.png, .pdf, .svg)")
    return parser


def plot_curves(args: argparse.Namespace) -> pathlib.Path:
    """The ``curves`` command; returns the image written."""
    try:
        with warnings.catch_warnings(record=True) as skipped:
            warnings.simplefilter("always")
            runs = load_runs(args.log_folder, args.algos, args.env, skip_missing=args.skip_missing)
    except FileNotFoundError as error:
        hint = " Pass --skip-missing to plot the other runs." if "No evaluations.npz" in str(error) else ""
        raise FileNotFoundError(f"{error}{hint}") from error
    for warning in skipped:
        print(f"warning: {warning.message}", file=sys.stderr)
    title = args.title if args.title is not None else args.env.split("/")[-1]
    return save_figure(training_curves_figure(runs, metrics=args.metrics, title=title), args.output)


def read_run(run_folder: str) -> tuple[pathlib.Path, dict[str, Any]]:
    """
    The arguments a training run was started with (``<run>/<EnvName>/args.yml``).

    :param run_folder: The run folder
    :return: The folder and its arguments
    """
    folder = pathlib.Path(run_folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"No run folder {folder}.")
    found = sorted(folder.glob("*/args.yml"))
    if not found:
        raise FileNotFoundError(f"{folder} is not a training run folder: no <EnvName>/args.yml in it.")
    with open(found[0]) as file:
        run_args = yaml.safe_load(file) or {}
    for key in ("algo", "env"):
        if key not in run_args:
            raise ValueError(f"{found[0]} has no {key!r}.")
    return folder, run_args


def _model_path(folder: pathlib.Path, name: str, choice: str | None) -> pathlib.Path:
    candidates = {"final": folder / f"{name}.zip", "best": folder / "best_model.zip"}
    if choice is None:
        path = next((p for p in candidates.values() if p.is_file()), candidates["final"])
    else:
        path = candidates.get(choice, pathlib.Path(choice))
    if not path.is_file():
        raise FileNotFoundError(f"No model {path} (saved models there: {sorted(p.name for p in folder.glob('*.zip'))}).")
    return path


def _pick_constraint(constraints: tuple[TrueConstraint, ...], feature: str | None) -> TrueConstraint:
    if feature is None:
        if len(constraints) > 1:
            others = ", ".join(c.name for c in constraints[1:])
            print(f"note: plotting {constraints[0].name}; the env also constrains {others} (--feature).", file=sys.stderr)
        return constraints[0]
    for constraint in constraints:
        if feature in (constraint.name, str(constraint.obs_index)):
            return constraint
    raise ValueError(f"Unknown feature {feature!r}: this env constrains {', '.join(c.name for c in constraints)}.")


def policy_observations(
    model: Any,
    env_id: str,
    env_kwargs: dict[str, Any],
    folder: pathlib.Path,
    run_args: dict[str, Any],
    n_episodes: int,
    seed: int,
) -> np.ndarray:
    """
    Raw observations visited by the model's deterministic policy (with the run's saved normalisation, if any).

    :return: ``(n_steps, obs_dim)``
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_icrl.envs.wrappers import TransitionNoiseWrapper

    noise = float(run_args.get("transition_noise") or 0.0)
    wrapper = (lambda env: TransitionNoiseWrapper(env, sigma=noise)) if noise > 0 else None
    venv: Any = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=env_kwargs, wrapper_class=wrapper)
    statistics = folder / env_id.split("/")[-1] / "vecnormalize.pkl"
    if statistics.is_file():
        venv = VecNormalize.load(str(statistics), venv)
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

    from sb3_icrl.data import load_demonstrations
    from sb3_icrl.zoo.hyperparams import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id

    folder, run_args = read_run(args.run_folder)
    algo = run_args["algo"]
    if algo not in ICRL_ALGOS:
        raise ValueError(f"{folder} is a {algo} run: only ICRL runs ({', '.join(ICRL_ALGOS)}) learn a constraint to plot.")
    import_gym_packages(run_args.get("gym_packages"))  # a user's env registers itself on import
    env_id = resolve_env_id(run_args["env"])
    name = env_name(env_id)  # the run folder's name for the env, as train.py wrote it
    env_kwargs = dict(run_args.get("env_kwargs") or {})
    model = ALGOS[algo].load(str(_model_path(folder, name, args.model)), device="cpu")
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
        constraint = _pick_constraint(constraint_features(env_id, env_kwargs), args.feature)
        visited_values = {"expert": np.asarray(transitions.obs)[:, constraint.obs_index]}
        if args.episodes > 0:
            policy_obs = policy_observations(model, env_id, env_kwargs, folder, run_args, args.episodes, args.seed)
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
        path = plot_curves(args) if args.command == "curves" else plot_constraint(args)
    except (FileNotFoundError, ValueError, TypeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"Saved {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
