"""
Run a trained agent of a zoo run folder, as rl-baselines3-zoo's ``enjoy.py``::

    python enjoy.py --algo mecl --env BlockedHalfCheetah-v0 -f logs --exp-id 0 -n 5000 --no-render
    sb3-icrl enjoy --algo ppolag --env ConstrainedCorridor-v0 --load-best --record

Loads ``<folder>/<algo>/<EnvName>_<exp-id>/<EnvName>.zip`` (``--load-best``: ``best_model.zip``, ``--load-checkpoint N``:
``rl_model_<N>_steps.zip``) with the run's env settings (``config.yml``, ``args.yml``) and its ``VecNormalize``
statistics, frozen. Prints, per finished episode, the reward, the true cost, whether the constraint was violated and
the feasible reward (summed until the first violation), then the violation rate and the mean feasible reward.
``--record`` makes the env with ``render_mode="rgb_array"`` (an env class must declare it in ``metadata``, a factory
function entry point must accept it and pass it on) and writes the frames into ``<run>/videos/`` as they come, one file
per episode: an mp4 when imageio-ffmpeg is installed, else a GIF (Pillow), else PNG frames (matplotlib); without a
display, MuJoCo renders off screen (``MUJOCO_GL=egl``, else ``osmesa``, unless ``MUJOCO_GL`` is set).
"""

import argparse
import inspect
import os
import sys
from typing import Any

import gymnasium as gym
import torch as th
from gymnasium.envs.registration import load_env_creator

from sb3_icrl.common.evaluation import ConstraintEvaluation
from sb3_icrl.common.utils import plain_docstring
from sb3_icrl.hyperparams import HyperparameterError
from sb3_icrl.registry import NAMESPACE, env_name, import_gym_packages, resolve_env_id
from sb3_icrl.run_env import create_env
from sb3_icrl.run_evaluation import load_run_model, run_episodes, saved_settings
from sb3_icrl.run_folder import (
    TrainedAgentError,
    check_trained_agent,
    get_latest_run_id,
    model_path,
    read_run_record,
    rl_zoo3_env_name,
    run_env_name,
)
from sb3_icrl.zoo.arguments import (
    StoreDict,
    algo_help,
    non_negative_int,
    parse_after_packages,
    positive_int,
    registered_algo,
)
from sb3_icrl.zoo.recording import FrameWriter, configure_headless_rendering, has_display, recording_backend


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
    parser.add_argument("--algo", type=registered_algo, required=True, metavar="ALGO", help=algo_help())
    parser.add_argument(
        "--env", type=str, required=True, help="Env id, with or without the sb3_icrl/ prefix (or MODULE:EnvId)"
    )
    parser.add_argument(
        "--gym-packages", type=str, nargs="+", default=[], help="Modules to import first: they register your own envs"
    )
    parser.add_argument("-f", "--folder", type=str, default="logs", help="Log folder (train.py's -f)")
    parser.add_argument("--exp-id", type=non_negative_int, default=None, help="Run id N of <EnvName>_N (0: the latest)")
    parser.add_argument("--run", type=str, default=None, help="The run folder itself (instead of -f and --exp-id)")
    # One model at a time: a second flag would be ignored without a word
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--load-best", action="store_true", default=False, help="Load best_model.zip")
    which.add_argument("--load-checkpoint", type=non_negative_int, help="Load the checkpoint rl_model_<N>_steps.zip")
    which.add_argument("--load-last-checkpoint", action="store_true", default=False, help="Load the latest checkpoint")
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


def check_videos_folder(run: str) -> None:
    """
    Fail before the run starts unless ``<run>/videos`` (where ``--record`` writes) is, or can be made, a writable folder.

    :param run: The run folder
    :raises ValueError: When it cannot be written
    """
    videos = os.path.join(run, "videos")
    try:
        os.makedirs(videos, exist_ok=True)
        why = None if os.access(videos, os.W_OK | os.X_OK) else "not writable"
    except OSError as error:
        why = error.strerror or str(error)
    if why is not None:
        raise ValueError(
            f"--record writes into {videos}, which cannot be written ({why}): copy the run folder to a place you can "
            "write to and pass it with --run, or leave out --record."
        )


def check_run_matches(run: str, env_id: str, algo: str) -> None:
    """
    Refuse ``--run`` with an ``--env`` or ``--algo`` other than the run's own (``args.yml``): its model would be
    looked up under the other env's name, or loaded as another algorithm's.

    :param run: The run folder
    :param env_id: ``--env``, resolved
    :param algo: ``--algo``
    :raises FileNotFoundError: When the folder or its ``args.yml`` is missing
    :raises ValueError: When the run trained on another env or with another algorithm
    """
    record = read_run_record(run)
    if record.env != env_id:
        typed = record.env.removeprefix(f"{NAMESPACE}/")
        raise ValueError(f"{run} trained on {typed}, not on {env_id.removeprefix(f'{NAMESPACE}/')}: pass --env {typed}.")
    if record.algo is not None and record.algo != algo:
        raise ValueError(f"{run} trained with {record.algo}, not with {algo}: use --algo {record.algo}.")


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


def _run_folder_ours_or_rl_zoo3(folder: str, algo: str, env_id: str, exp_id: int) -> str:
    """:func:`run_folder` of ``train.py``'s name of the env, else of rl_zoo3's (``sb3_icrl-MyEnv-v0_1``)."""
    name, theirs = env_name(env_id), rl_zoo3_env_name(env_id)
    try:
        return run_folder(folder, algo, name, exp_id)
    except FileNotFoundError as error:
        if theirs == name:
            raise
        try:
            return run_folder(folder, algo, theirs, exp_id)
        except FileNotFoundError:
            raise error from None  # (the message of train.py's name: rl_zoo3's is the exception)


def _creator(env_id: str) -> Any:
    entry_point = gym.spec(env_id).entry_point
    # Registered as "module:Class" or as the class (or function) itself
    return load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point


def _metadata(env_id: str) -> dict[str, Any]:
    return dict(getattr(_creator(env_id), "metadata", None) or {})


def factory_takes_render_mode(env_id: str) -> bool:
    """
    Whether the env's entry point is a factory function (no class metadata to read) that accepts ``render_mode``, by
    name or as ``**kwargs``: gym.make passes it on, and only the env it makes can tell which modes it renders.

    :param env_id: A registered env id
    """
    creator = _creator(env_id)
    if isinstance(creator, type) or getattr(creator, "metadata", None) is not None:
        return False
    try:
        parameters = inspect.signature(creator).parameters.values()
    except (TypeError, ValueError):  # a builtin or C callable: let gym.make try
        return True
    return any(parameter.name == "render_mode" or parameter.kind is parameter.VAR_KEYWORD for parameter in parameters)


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
        if args.exp_id is not None:
            raise ValueError("--run names the run folder itself: leave out --exp-id (or give -f and --exp-id instead).")
        run = args.run
        check_run_matches(run, env_id, args.algo)
    else:
        run = _run_folder_ours_or_rl_zoo3(args.folder, args.algo, env_id, args.exp_id or 0)
    name = run_env_name(run, env_id)  # (rl_zoo3 names its files after the whole id)
    if args.record:
        check_videos_folder(run)
    path = model_path(run, name, args.load_best, args.load_checkpoint, args.load_last_checkpoint)
    check_trained_agent(path, args.algo)
    params, env_kwargs, stats_path, transition_noise, noise_model = saved_settings(run, name, path, args.env_kwargs)

    modes = render_modes(env_id)
    backend = None
    if args.record:
        if "rgb_array" not in modes and not factory_takes_render_mode(env_id):
            creator = _creator(env_id)
            if not isinstance(creator, type) and not modes:
                raise RecordingError(
                    f"{name} is made by {getattr(creator, '__qualname__', creator)!r}, which takes no render_mode: "
                    "it cannot make rgb_array frames (accept render_mode and pass it to the env)."
                )
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

    env, _ = create_env(
        env_id,
        params,
        1,
        args.seed,
        env_kwargs,
        transition_noise,
        None,
        eval_env=True,
        stats_path=stats_path,
        transition_noise_model=noise_model,
    )
    if backend is not None and getattr(env, "render_mode", None) != "rgb_array":
        # A factory function may take render_mode and drop it: the env it made is the only judge
        env.close()
        raise RecordingError(
            f"{name} was made with render_mode='rgb_array' but renders {getattr(env, 'render_mode', None)!r}: "
            "pass render_mode on to the env."
        )
    model = load_run_model(args.algo, path, args.device, args.seed)
    if args.verbose:
        print(f"Loaded {path}" + (f" with {stats_path}" if stats_path else ""))
    writer = None
    if backend is not None:
        stem = f"{args.algo}-{name}-{os.path.splitext(os.path.basename(path))[0]}"
        # The env's own metadata: a factory function has none of its own
        fps = float(env.get_attr("metadata", [0])[0].get("render_fps") or _metadata(env_id).get("render_fps") or 30)
        writer = FrameWriter(backend, os.path.join(run, "videos"), stem, fps)
    try:
        evaluation = run_episodes(model, env, args.n_timesteps, args.deterministic, args.verbose, writer)
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


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """
    Command-line entry point (``enjoy.py`` and ``sb3-icrl enjoy``).

    :param argv: Arguments (default: ``sys.argv[1:]``)
    :param prog: Program name in the usage line
    :return: Exit status: 0, or 2 after a clear error
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_after_packages(get_parser, argv, prog)
    if args is None:
        return 2
    try:
        enjoy(args)
    except (FileNotFoundError, RecordingError, TrainedAgentError, HyperparameterError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
