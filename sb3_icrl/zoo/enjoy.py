"""
Run a trained agent of a zoo run folder, as rl-baselines3-zoo's ``enjoy.py``::

    python enjoy.py --algo mecl --env BlockedHalfCheetah-v0 -f logs --exp-id 0 -n 5000 --no-render
    sb3-icrl enjoy --algo ppolag --env ConstrainedCorridor-v0 --load-best --record

Loads ``<folder>/<algo>/<EnvName>_<exp-id>/<EnvName>.zip`` (``--load-best``: ``best_model.zip``, ``--load-checkpoint N``:
``rl_model_<N>_steps.zip``) with the run's env settings (``config.yml``, ``args.yml``) and its ``VecNormalize``
statistics, frozen. Prints, per finished episode, the reward, the true cost, whether the constraint was violated and
the feasible reward (summed until the first violation), then the violation rate and the mean feasible reward.
``--record`` writes the ``rgb_array`` frames into ``<run>/videos/`` as they come, one file per episode: an mp4 when
imageio-ffmpeg is installed, else a GIF (Pillow), else PNG frames (matplotlib); without a display, MuJoCo renders
off screen (``MUJOCO_GL=egl``, else ``osmesa``, unless ``MUJOCO_GL`` is set).
"""

import argparse
import os
import sys
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from gymnasium.envs.registration import load_env_creator
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_icrl.common.evaluation import ConstraintEvaluation, EpisodeAccumulator
from sb3_icrl.common.utils import plain_docstring
from sb3_icrl.hyperparams import HyperparameterError, preprocess_hyperparams
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id
from sb3_icrl.run_folder import CHECKPOINT_PATTERN, TrainedAgentError, check_trained_agent, failure, find_vecnormalize
from sb3_icrl.zoo.recording import FrameWriter, configure_headless_rendering, has_display, recording_backend
from sb3_icrl.zoo.train import StoreDict, create_env, get_latest_run_id, non_negative_int, positive_int


class RecordingError(RuntimeError):
    """``--record`` cannot be honoured (no rgb_array rendering, or no library to write frames)."""


def get_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """
    The command-line parser, with rl-zoo's ``enjoy.py`` flags plus ``--record``.

    :param prog: Program name in the usage line (default: the script's)
    """
    parser = argparse.ArgumentParser(
        prog=prog, description=plain_docstring(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--algo", type=str, required=True, choices=list(ALGOS), help="Algorithm")
    parser.add_argument(
        "--env", type=str, required=True, help="Env id, with or without the sb3_icrl/ prefix (or MODULE:EnvId)"
    )
    parser.add_argument(
        "--gym-packages", type=str, nargs="+", default=[], help="Modules to import first: they register your own envs"
    )
    parser.add_argument("-f", "--folder", type=str, default="logs", help="Log folder (train.py's -f)")
    parser.add_argument("--exp-id", type=int, default=0, help="Run id N of <EnvName>_N (0: the latest)")
    parser.add_argument("--run", type=str, default=None, help="The run folder itself (instead of -f and --exp-id)")
    parser.add_argument("--load-best", action="store_true", default=False, help="Load best_model.zip")
    parser.add_argument("--load-checkpoint", type=int, help="Load the checkpoint rl_model_<N>_steps.zip")
    parser.add_argument("--load-last-checkpoint", action="store_true", default=False, help="Load the latest checkpoint")
    parser.add_argument("-n", "--n-timesteps", type=positive_int, default=1000, help="Steps to run")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--deterministic", dest="deterministic", action="store_true", help="Deterministic actions (default)")
    group.add_argument("--stochastic", dest="deterministic", action="store_false", help="Sample the actions")
    parser.set_defaults(deterministic=True)
    parser.add_argument("--no-render", action="store_true", default=False, help="Do not render on screen")
    parser.add_argument("--record", action="store_true", default=False, help="Save a video (or frames) in <run>/videos")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="Random seed of the env and the policy")
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=StoreDict, help="Env keyword arguments (override)")
    parser.add_argument("--num-threads", type=int, default=1, help="torch threads (<= 0: torch's default)")
    parser.add_argument("--device", type=str, default="auto", help="torch device")
    parser.add_argument("--verbose", type=int, default=1, help="Verbose mode (0: summary only, 1: every episode)")
    return parser


def run_folder(folder: str, algo: str, name: str, exp_id: int) -> str:
    """
    ``<folder>/<algo>/<name>_<exp_id>`` (the latest run when ``exp_id`` is 0).

    :raises FileNotFoundError: When there is no such run
    """
    log_path = os.path.join(folder, algo)
    if exp_id <= 0:
        exp_id = get_latest_run_id(log_path, name)
        # A benchmark suite names runs by seed, so a <name>_0 folder is a run of its own
        if exp_id == 0 and not os.path.isdir(os.path.join(log_path, f"{name}_0")):
            raise FileNotFoundError(f"No {algo} run of {name} in {log_path} (train one with train.py).")
    path = os.path.join(log_path, f"{name}_{exp_id}")
    if not os.path.isdir(path):
        raise FileNotFoundError(f"No run folder {path}.")
    return path


def model_path(run: str, name: str, load_best: bool, checkpoint: int | None, last_checkpoint: bool) -> str:
    """
    The zip to load from ``run``: the final model, ``best_model.zip`` or a checkpoint.

    :raises FileNotFoundError: When it does not exist (the message lists the run's models)
    """
    checkpoints = {}
    for entry in os.listdir(run):
        match = CHECKPOINT_PATTERN.match(entry)
        if match and match["prefix"] == "rl_model":
            checkpoints[int(match["steps"])] = entry
    if load_best:
        filename = "best_model.zip"
    elif checkpoint is not None:
        filename = f"rl_model_{checkpoint}_steps.zip"
    elif last_checkpoint:
        if not checkpoints:
            raise FileNotFoundError(f"No checkpoint in {run} (train with --save-freq).")
        filename = checkpoints[max(checkpoints)]
    else:
        filename = f"{name}.zip"
        reason = failure(run)
        if reason is not None:
            raise FileNotFoundError(
                f"{run} failed ({reason}), so it has no final model: evaluate its best model (--load-best) or a checkpoint "
                "(--load-last-checkpoint), or finish it with train.py --exp-id N --resume."
            )
    path = os.path.join(run, filename)
    if not os.path.isfile(path):
        available = sorted(entry for entry in os.listdir(run) if entry.endswith(".zip"))
        raise FileNotFoundError(f"No {filename} in {run}; models there: {', '.join(available) or 'none'}.")
    return path


def _metadata(env_id: str) -> dict[str, Any]:
    entry_point = gym.spec(env_id).entry_point
    # Registered as "module:Class" or as the class (or function) itself
    creator = load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point
    return dict(getattr(creator, "metadata", None) or {})


def render_modes(env_id: str) -> list[str]:
    """The render modes the env class declares."""
    return list(_metadata(env_id).get("render_modes", []))


def enjoy(args: argparse.Namespace) -> ConstraintEvaluation:
    """
    Run the agent chosen by ``args`` for ``args.n_timesteps`` steps and report its episodes.

    :param args: From :func:`get_parser`
    :return: The finished episodes (empty arrays when none finished)
    """
    import_gym_packages(args.gym_packages)
    env_id = resolve_env_id(args.env)
    name = env_name(env_id)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)
    if args.run:
        run = args.run
        if not os.path.isdir(run):
            raise FileNotFoundError(f"No run folder {run}.")
    else:
        run = run_folder(args.folder, args.algo, name, args.exp_id)
    path = model_path(run, name, args.load_best, args.load_checkpoint, args.load_last_checkpoint)
    check_trained_agent(path, args.algo)

    params_path = os.path.join(run, name)
    with open(os.path.join(params_path, "config.yml")) as file:
        params = preprocess_hyperparams(yaml.safe_load(file))
    saved_args: dict[str, Any] = {}
    if os.path.isfile(os.path.join(params_path, "args.yml")):
        with open(os.path.join(params_path, "args.yml")) as file:
            saved_args = yaml.safe_load(file) or {}
    env_kwargs = {**(saved_args.get("env_kwargs") or {}), **(args.env_kwargs or {})}
    stats_path = find_vecnormalize(path, name) if params["normalize"] else None
    if params["normalize"] and stats_path is None:
        raise FileNotFoundError(f"{run} was trained with VecNormalize, but its statistics (vecnormalize.pkl) are missing.")

    modes = render_modes(env_id)
    backend = None
    if args.record:
        if "rgb_array" not in modes:
            raise RecordingError(f"{name} cannot render rgb_array frames (render modes: {modes or 'none'}).")
        backend = recording_backend()
        if backend is None:
            raise RecordingError(
                "--record needs imageio-ffmpeg (mp4), Pillow (GIF) or matplotlib (PNG frames): none is installed."
            )
        env_kwargs["render_mode"] = "rgb_array"
        _headless_rendering()
    elif not args.no_render:
        if not has_display():
            print("No display: nothing is shown on screen (--record saves a video, --no-render silences this).")
        elif "human" in modes:
            env_kwargs["render_mode"] = "human"
        else:
            print(f"{name} has no on-screen rendering (render modes: {modes or 'none'}): use --record or --no-render.")

    transition_noise = float(saved_args.get("transition_noise") or 0.0)
    env, _ = create_env(env_id, params, 1, args.seed, env_kwargs, transition_noise, None, eval_env=True, stats_path=stats_path)
    # No env: an ICRL model would wrap it with its learned cost; no demonstrations: they only serve training
    extra: dict[str, Any] = {"demonstrations_source": None} if args.algo in ICRL_ALGOS else {}
    model = ALGOS[args.algo].load(path, device=args.device, **extra)
    model.set_random_seed(args.seed)
    if args.verbose:
        print(f"Loaded {path}" + (f" with {stats_path}" if stats_path else ""))
    writer = None
    if backend is not None:
        stem = f"{args.algo}-{name}-{os.path.splitext(os.path.basename(path))[0]}"
        fps = float(_metadata(env_id).get("render_fps") or 30)
        writer = FrameWriter(backend, os.path.join(run, "videos"), stem, fps)
    try:
        evaluation = _run(model, env, args.n_timesteps, args.deterministic, args.verbose, writer)
    finally:
        env.close()
        written = writer.close() if writer is not None else []
    if writer is not None and written:
        print(f"Recorded {writer.n_frames} frames, one file per episode: {', '.join(written)}")
    return evaluation


#: Whether :func:`_headless_rendering` has said which backend it chose (once per process)
_HEADLESS_SAID = False


def _headless_rendering() -> None:
    """Without a display, render MuJoCo off screen (:func:`configure_headless_rendering`), and say so once."""
    global _HEADLESS_SAID
    backend = configure_headless_rendering()
    if backend is not None and not _HEADLESS_SAID:
        _HEADLESS_SAID = True
        print(f"No display: MuJoCo renders off screen with MUJOCO_GL={backend} (set MUJOCO_GL to choose another)")


def _run(
    model: Any, env: VecEnv, n_timesteps: int, deterministic: bool, verbose: int, writer: FrameWriter | None
) -> ConstraintEvaluation:
    """
    Step the single env ``n_timesteps`` times; per episode the same metrics as :func:`evaluate_constraint`. With a
    ``writer``, each rendered frame is written as it comes, one file per episode.
    """
    normalize = env if isinstance(env, VecNormalize) else None
    episodes = EpisodeAccumulator(1)
    obs = env.reset()
    if writer is not None:
        writer.append(env.render())  # type: ignore[arg-type]
    state, episode_start = None, np.ones(1, dtype=bool)
    for _ in range(n_timesteps):
        action, state = model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        obs, rewards, dones, infos = env.step(action)
        if writer is not None:
            if dones[0]:
                writer.end_episode()  # the env has reset itself: this frame starts the next episode
            writer.append(env.render())  # type: ignore[arg-type]
        episodes.add(0, float((normalize.get_original_reward() if normalize is not None else rewards)[0]), infos[0])
        if dones[0]:
            reward, cost, feasible, violated, length = episodes.end_episode(0, infos[0])
            if verbose:
                print(
                    f"Episode {len(episodes.results['violations'])}: reward {reward:.2f}, true cost {cost:.2f}, "
                    f"violated {'yes' if violated else 'no'}, feasible reward {feasible:.2f} ({int(length)} steps)"
                )
        episode_start = dones
    evaluation = episodes.evaluation()
    n_episodes = len(evaluation.violations)
    if n_episodes:
        print(
            f"{n_episodes} episodes: violation rate {evaluation.violation_rate:.2f}, feasible reward "
            f"{evaluation.mean_feasible_reward:.2f}, reward {evaluation.mean_reward:.2f}, true cost {evaluation.mean_cost:.2f}"
        )
    else:
        print(f"No episode finished in {n_timesteps} steps (use more -n).")
    return evaluation


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """
    Command-line entry point (``enjoy.py`` and ``sb3-icrl enjoy``).

    :param argv: Arguments (default: ``sys.argv[1:]``)
    :param prog: Program name in the usage line
    :return: Exit status: 0, or 2 after a clear error
    """
    args = get_parser(prog).parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        enjoy(args)
    except (FileNotFoundError, RecordingError, TrainedAgentError, HyperparameterError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
