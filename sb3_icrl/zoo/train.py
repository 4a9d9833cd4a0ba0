"""
Train any sb3-icrl algorithm the rl-baselines3-zoo way::

    python train.py --algo mecl --env BlockedHalfCheetah-v0 --demonstrations experts.npz -tb runs/
    sb3-icrl train --algo vicrl --env GridWorldWall-v0 -n 20000 --seed 123
    sb3-icrl train --algo mecl --env BlockedHalfCheetah-v0 -i logs/mecl/BlockedHalfCheetah-v0_1/rl_model_400000_steps.zip

Hyper-parameters come from ``zoo_hyperparams/<algo>.yml`` (the one source of truth), overridden with ``-params``.
A run writes ``<folder>/<algo>/<EnvName>_<N>/``: the final model ``<EnvName>.zip``, ``best_model.zip``, periodic
``rl_model_<steps>_steps.zip`` (with ``rl_model_vecnormalize_<steps>_steps.pkl`` when normalising, and for an
off-policy algorithm the newest one's replay buffer ``rl_model_replay_buffer_<steps>_steps.pkl``),
``evaluations.npz``, monitor files, ``<EnvName>/{config,args,versions}.yml``, ``<EnvName>/vecnormalize.pkl`` when
normalising, and ``command.txt``. Every file is written atomically: a run killed at any moment leaves whole files only.

Resuming. ``-i PATH.zip`` continues a saved model for ``-n`` more steps: its timestep count, hyper-parameters,
multiplier and constraint net go on, with the ``VecNormalize`` statistics and the training state saved with it (the
ICRL trainer's nominal memory, sampler and last update step; the model selection's best score and episodes), and an
off-policy model's replay buffer (an older checkpoint, whose buffer was removed, goes on with an empty one). A model
of a run folder (a checkpoint, or the final model) goes on in that same folder: monitor files, ``evaluations.npz``
and TensorBoard curves continue, so plots and ``compare`` see one run. ``--new-folder`` writes the continuation to a
new run folder instead (needed to branch from an earlier checkpoint). ``--exp-id N --resume`` continues run N from its
latest checkpoint for the steps it had left (skipped once ``finished.json`` is there).
"""

import argparse
import contextlib
import json
import os
import shlex
import shutil
import sys
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import unwrap_wrapper
from stable_baselines3.common.logger import configure as configure_logger
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.utils import get_latest_run_id as sb3_latest_run_id
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_icrl.benchmark import cli as benchmark_cli
from sb3_icrl.common.utils import (
    atomic_save_model,
    atomic_save_pickle,
    atomic_write_json,
    atomic_write_text,
    atomic_write_yaml,
    check_writable_folder,
    did_you_mean,
    plain_docstring,
    remove_temporaries,
    sigterm_interrupts,
    write_error_message,
)
from sb3_icrl.common.versions import versions
from sb3_icrl.data import load_demonstrations
from sb3_icrl.envs.wrappers import COMPONENT_NOISE, TRANSITION_NOISE_MODELS, recorded_transition_noise
from sb3_icrl.hyperparams import (
    ZOO_KEYS,
    HyperparameterError,
    algo_kwargs,
    check_hyperparameter_types,
    forward_solver,
    load_hyperparams,
    preprocess_hyperparams,
)
from sb3_icrl.icrl.tabular import learn_function
from sb3_icrl.metrics import transfer
from sb3_icrl.plots import ConstraintFigureCallback
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id
from sb3_icrl.run_env import create_env
from sb3_icrl.run_folder import (
    CHECKPOINT_PATTERN,
    FAILED_FILE,
    FINISHED_FILE,
    TrainedAgentError,
    check_trained_agent,
    checkpoints,
    find_vecnormalize,
    get_latest_run_id,
    is_finished,
    latest_checkpoint,
    load_run_yaml,
    trim_monitors,
    write_attempt,
)
from sb3_icrl.zoo.arguments import (
    StoreDict,
    algo_help,
    fraction,
    non_negative_float,
    non_negative_int,
    parse_after_packages,
    positive_int,
    registered_algo,
)
from sb3_icrl.zoo.callbacks import (
    AtomicCheckpointCallback,
    ConstraintEvalCallback,
    ReplayBufferRefill,
    WallClock,
    load_replay_buffer,
    load_training_state,
    replay_buffer_path,
    save_training_state,
    training_state_cpu_time,
    training_state_monitor_rows,
    training_state_path,
    training_state_wall_time,
)
from sb3_icrl.zoo.summary import print_recovered_constraint, show_progress_bar


def get_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """
    The command-line parser, with rl-zoo's flags plus the ICRL ones.

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
    parser.add_argument(
        "-n", "--n-timesteps", type=positive_int, default=None, help="Timesteps (default: the yml's n_timesteps)"
    )
    parser.add_argument(
        "-i",
        "--trained-agent",
        type=str,
        default="",
        help="Continue training this saved model for -n more steps (.zip of --algo; keeps its hyper-parameters, timestep "
        "count and training state). A model of a run folder goes on in that folder (logs, evaluations and TensorBoard "
        "continue); see --new-folder",
    )
    parser.add_argument(
        "--seed", type=non_negative_int, default=None, help="Random seed (default: drawn at random, then saved)"
    )
    parser.add_argument("-f", "--log-folder", type=str, default="logs", help="Log folder")
    parser.add_argument("-tb", "--tensorboard-log", type=str, default="", help="TensorBoard log dir")
    parser.add_argument("--eval-freq", type=int, default=25000, help="Evaluate every n steps (<= 0: never)")
    parser.add_argument("--eval-episodes", type=positive_int, default=5, help="Episodes per evaluation")
    parser.add_argument("--save-freq", type=int, default=-1, help="Checkpoint every n steps (<= 0: never)")
    parser.add_argument("-params", "--hyperparams", type=str, nargs="+", action=StoreDict, help="Overrides: k:v")
    parser.add_argument(
        "-conf",
        "--conf-file",
        type=str,
        default=None,
        help="yml file of entries by env name (replaces <algo>.yml), or one entry: a small yml file or a JSON object, "
        "applied over the shipped entry",
    )
    parser.add_argument(
        "--forward-recipe",
        type=str,
        default=None,
        choices=list(ALGOS),
        help="ppo and ppolag: learn with the forward learner of this algorithm's entry (its PPO settings and steps; "
        "ppolag on the true cost with budget 0): a benchmark's reference rows, on the same footing as its ICRL cells",
    )
    parser.add_argument(
        "--recipe-version",
        type=str,
        default=None,
        help="A name for the recipe this run uses (a benchmark suite's recipe_version), recorded in its args.yml",
    )
    parser.add_argument("--env-kwargs", type=str, nargs="+", action=StoreDict, help="Env keyword arguments: k:v")
    parser.add_argument(
        "--progress", action="store_true", default=False, help="Show a progress bar (default: on a terminal, with -v 0)"
    )
    parser.add_argument(
        "-v",
        "--verbose",
        type=int,
        default=0,
        help="0: a progress bar on a terminal, one line per evaluation, the recovered constraint at the end; "
        "1: also SB3's training tables and every evaluation metric; 2: debug",
    )
    parser.add_argument("--num-threads", type=int, default=1, help="torch threads (<= 0: torch's default)")
    parser.add_argument("--device", type=str, default="auto", help="torch device")
    parser.add_argument("--demonstrations", type=str, default=None, help="Shipped dataset name or .npz path (ICRL)")
    parser.add_argument(
        "--violating-fraction", type=fraction, default=None, help="Shipped imperfect-expert variant (0.2, 0.5, 0.8)"
    )
    parser.add_argument(
        "--transition-noise", type=non_negative_float, default=0.0, help="Std of N(0, sigma) next-state noise (0: none)"
    )
    parser.add_argument(
        "--transition-noise-model",
        choices=TRANSITION_NOISE_MODELS,
        default=COMPONENT_NOISE,
        help="How --transition-noise is drawn: component (an independent draw per state component) or shared (one draw "
        "per step added to every component, as the paper's code does)",
    )
    parser.add_argument(
        "--allow-env-mismatch",
        action="store_true",
        default=False,
        help="Accept --demonstrations recorded on another env id whose spaces fit (ICRL)",
    )
    parser.add_argument(
        "--exp-id",
        type=int,
        default=None,
        help="Write the run to <folder>/<algo>/<EnvName>_<exp-id> (default: the next free N); it must not exist yet "
        "unless --resume",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        default=False,
        help="With --exp-id: skip the run if it finished, continue it from its latest checkpoint if it has one, else "
        "start it afresh in that folder",
    )
    parser.add_argument(
        "--new-folder",
        action="store_true",
        default=False,
        help="With -i: write the continuation to a new run folder (the next free N, or --exp-id) instead of the model's "
        "own run folder; needed to branch from a checkpoint that later ones follow",
    )
    return parser


def _demonstrations(algo: str, env_id: str, args: argparse.Namespace, env: VecEnv) -> Any:
    if algo not in ICRL_ALGOS:
        if args.demonstrations is not None or args.violating_fraction is not None:
            raise ValueError(
                f"--demonstrations and --violating-fraction are for the ICRL algorithms ({', '.join(ICRL_ALGOS)}), not {algo}."
            )
        if getattr(args, "allow_env_mismatch", False):
            raise ValueError(
                f"--allow-env-mismatch accepts demonstrations recorded on another env: it is for the ICRL algorithms "
                f"({', '.join(ICRL_ALGOS)}), which learn from demonstrations; {algo} learns from none, so leave it out."
            )
        return None
    name = args.demonstrations if args.demonstrations is not None else env_name(env_id)
    allow = getattr(args, "allow_env_mismatch", False)
    try:
        return load_demonstrations(name, env=env, violating_fraction=args.violating_fraction, allow_env_mismatch=allow)
    except Exception as error:
        if args.demonstrations is None:
            raise ValueError(
                f"{algo} learns from demonstrations and none are shipped for {env_name(env_id)}: pass "
                f"--demonstrations PATH.npz (see `python -m sb3_icrl.data generate --help`). ({error})"
            ) from error
        raise


def _check_noise_model_has_noise(args: argparse.Namespace, argv: list[str] | None) -> None:
    """
    Refuse ``--transition-noise-model`` given without noise to draw (no ``--transition-noise``, or 0): it would do
    nothing. Its default is left as it is (runs record it, and resume compares it), so ``argv`` tells whether it was
    given.

    :param args: The parsed arguments
    :param argv: The command line they were parsed from (``None``: not known, nothing is checked)
    """
    if argv is None or args.transition_noise:
        return
    probe = get_parser()
    probe.set_defaults(transition_noise_model=None)
    with contextlib.suppress(SystemExit):  # (argv parsed already: it parses again)
        if probe.parse_known_args(argv)[0].transition_noise_model is not None:
            raise ValueError(
                f"--transition-noise-model {args.transition_noise_model} says how the next-state noise of "
                "--transition-noise is drawn, and there is none (--transition-noise is 0): give its level with "
                "--transition-noise SIGMA, or leave out --transition-noise-model."
            )


def _warn_without_constraint_updates(args: argparse.Namespace, params: dict[str, Any], n_timesteps: int, source: str) -> None:
    update_every = params.get("update_every")
    if args.algo in ICRL_ALGOS and update_every and n_timesteps < update_every and not args.trained_agent:
        warnings.warn(
            f"{args.algo} updates its constraint every {update_every} steps (update_every in the {source!r} entry), but this "
            f"run trains {n_timesteps}: it will make no constraint update and learn against the untrained constraint. "
            f"Train longer, or pass -params update_every:{max(n_timesteps // 4, 1)}.",
            stacklevel=3,
        )


def check_same_recipe(config_file: str, recipe: dict[str, Any]) -> None:
    """
    Refuse to resume (``--resume``) a run whose hyper-parameters changed since it started (an edited yml, other
    ``-params`` or ``-n``): its checkpoints were made with the recipe in ``config_file``, and going on with another
    would give a run that neither recipe made; a finished one would pass for a run of the new recipe.

    :param config_file: The run's ``<EnvName>/config.yml``
    :param recipe: The hyper-parameters the resumed run would use, as ``config.yml`` records them
    :raises ValueError: When they differ (naming the keys)
    """
    if not os.path.isfile(config_file):
        return  # a run folder from before config.yml was written: nothing to compare
    saved = load_run_yaml(config_file)  # (a damaged file is named)
    now = yaml.safe_load(yaml.safe_dump(recipe))
    changed = sorted(key for key in {*saved, *now} if key not in saved or key not in now or saved[key] != now[key])
    if changed:

        def shown(recipe: dict[str, Any], key: str) -> str:
            return repr(recipe[key]) if key in recipe else "(not set)"

        details = "; ".join(f"{key}: {shown(saved, key)} then, {shown(now, key)} now" for key in changed)
        raise ValueError(
            f"Cannot resume {os.path.dirname(os.path.dirname(config_file))}: its hyper-parameters changed since it started "
            f"({details}). Resume with the recipe in {config_file} (-params / -n / the yml as they were), or start a "
            "new run (another --exp-id, or remove the folder)."
        )


def check_same_noise(args_file: str, args: argparse.Namespace) -> None:
    """
    Refuse to resume a run with other transition noise than it started with (``--transition-noise`` and
    ``--transition-noise-model`` as its ``args.yml`` records them): its envs would change under the model mid-run.

    :param args_file: The run's ``<EnvName>/args.yml``
    :param args: The arguments of the resumed run
    :raises ValueError: When the noise differs
    """
    if not os.path.isfile(args_file):
        return
    saved = load_run_yaml(args_file)
    then = recorded_transition_noise(saved)
    now = (float(args.transition_noise), args.transition_noise_model)
    if then != now:
        raise ValueError(
            f"Cannot resume {os.path.dirname(os.path.dirname(args_file))}: it started with --transition-noise {then[0]:g} "
            f"--transition-noise-model {then[1]}, not {now[0]:g} {now[1]}. Resume with the noise it started with, or "
            "start a new run (another --exp-id)."
        )


def _resume_checkpoint(args: argparse.Namespace, save_path: str, resume_from: str | None) -> str | None:
    """
    With ``--resume``, the checkpoint an unfinished run goes on from (:func:`latest_checkpoint`, set as
    ``args.trained_agent``); without one, the folder is cleared so the run starts afresh in it.
    """
    if not args.resume:
        return None
    if resume_from is None:
        damaged = [os.path.basename(path) for _, path in checkpoints(save_path)]
        if damaged:
            # Each was named by latest_checkpoint's warning: say what becomes of them
            warnings.warn(
                f"No checkpoint of {save_path} can be loaded ({', '.join(damaged)}): the run starts afresh and its folder "
                "is cleared."
            )
        shutil.rmtree(save_path, ignore_errors=True)
        return None
    args.trained_agent = resume_from
    if os.path.isfile(os.path.join(save_path, FAILED_FILE)):
        os.remove(os.path.join(save_path, FAILED_FILE))  # tried again: failed.json comes back only if it fails again
    if args.verbose:
        print(f"Resuming {save_path} from {os.path.basename(resume_from)}")
    return resume_from


def _trim_monitors_to_checkpoint(args: argparse.Namespace, name: str, save_path: str) -> None:
    """
    A run going on from a checkpoint replays the steps after it: its Monitor files (training and evaluation) drop
    the episodes they recorded after the checkpoint, as ``evaluations.npz`` drops its later evaluations. Checkpoints
    of earlier versions recorded no Monitor counts: their runs keep their files as they are.
    """
    if not args.trained_agent:
        return
    counts = training_state_monitor_rows(training_state_path(args.trained_agent, name))
    if counts is None:
        return
    dropped = trim_monitors(save_path, counts)
    if dropped and args.verbose:
        print(f"Monitor files cut back to the checkpoint: {', '.join(f'{k} -{v}' for k, v in dropped.items())} episodes")


def _in_place_folder(args: argparse.Namespace, name: str) -> str | None:
    """
    The run folder ``-i`` continues in: the model's own, when it lies in one of this algorithm and env
    (``.../<algo>/<EnvName>_<N>/`` with its ``<EnvName>/`` parameters folder) and ``--new-folder`` is not given.
    """
    if not args.trained_agent or args.new_folder:
        return None
    folder = os.path.dirname(os.path.normpath(args.trained_agent)) or "."
    stem, _, number = os.path.basename(os.path.abspath(folder)).rpartition("_")
    in_run = stem == name and number.isdigit() and os.path.basename(os.path.dirname(os.path.abspath(folder))) == args.algo
    return folder if in_run and os.path.isdir(os.path.join(folder, name)) else None


def _check_latest_state(trained_agent: str, save_path: str) -> None:
    """
    Refuse to continue ``trained_agent`` in its run folder when the folder went further (a later checkpoint, or a
    finished run with more steps): the continuation would overwrite that run's later files.
    """
    steps = int((load_from_zip_file(trained_agent, device="cpu")[0] or {}).get("num_timesteps", 0))
    later = sorted(
        int(match["steps"])
        for match in map(CHECKPOINT_PATTERN.match, os.listdir(save_path))
        if match and match["prefix"] == "rl_model" and int(match["steps"]) > steps
    )
    finished_file = os.path.join(save_path, FINISHED_FILE)
    if os.path.isfile(finished_file):
        with open(finished_file) as file:
            finished_steps = int(json.load(file).get("num_timesteps", 0))
        if finished_steps > steps:
            later.append(finished_steps)
    if later:
        raise ValueError(
            f"{trained_agent} ({steps} steps) is not the latest state of its run folder {save_path}, which went on to "
            f"{max(later)} steps: pass --new-folder to continue it in a new run folder, or -i the latest checkpoint."
        )


def _continue_monitor_clocks(venv: VecEnv) -> None:
    """
    Appended Monitor files keep their first header, whose ``t_start`` ``load_results`` adds to every row's time:
    start each Monitor's clock there too, so that the rows of the resumed run come after the earlier ones.
    """
    while isinstance(venv, VecEnvWrapper):
        venv = venv.venv
    for env in getattr(venv, "envs", []):
        monitor = unwrap_wrapper(env, Monitor)
        if not isinstance(monitor, Monitor) or monitor.results_writer is None:
            continue
        with open(monitor.results_writer.file_handler.name) as file:
            header = file.readline()
        if header.startswith("#"):
            monitor.t_start = float(json.loads(header[1:]).get("t_start", monitor.t_start))


def _continue_in_place(args: argparse.Namespace, name: str, save_path: str) -> bool:
    """
    Whether ``-i`` continues a model of the run folder ``save_path`` in place (as ``--resume`` does): then the folder
    must not have gone further than the model, and its ``finished.json`` (or ``failed.json``) goes until the
    continuation ends.
    """
    if args.resume or not args.trained_agent or save_path != _in_place_folder(args, name):
        return False
    _check_latest_state(args.trained_agent, save_path)
    for marker in (FINISHED_FILE, FAILED_FILE):
        if os.path.isfile(os.path.join(save_path, marker)):
            os.remove(os.path.join(save_path, marker))
    if args.verbose:
        print(f"Continuing {save_path} from {os.path.basename(args.trained_agent)} in place (--new-folder: in a new one)")
    return True


def _go_on(args: argparse.Namespace, model: BaseAlgorithm, callbacks: list[BaseCallback], name: str, resuming: bool) -> None:
    """
    Before ``learn`` of a run that continues a model: restore the training state saved with it; in the same run
    folder, also the evaluation history and model selection, with the callbacks' step counts where the run was. An
    off-policy model whose buffer is short of ``learning_starts`` gets a
    :class:`~sb3_icrl.zoo.callbacks.ReplayBufferRefill`, put first in ``callbacks``.
    """
    evaluation = _evaluation(callbacks) if resuming else None
    if resuming:
        if evaluation is not None:
            evaluation.resume_history(model.num_timesteps)
        for callback in callbacks:
            # Evaluations (and figures) at the same steps as in an uninterrupted run
            callback.n_calls = model.num_timesteps // model.n_envs
    if args.trained_agent:
        _restore_training_state(model, args.trained_agent, name, evaluation)
        refill = _restore_replay_buffer(model, args.trained_agent, args.verbose)
        if refill is not None:
            callbacks.insert(0, refill)  # first: the checkpoints then save the model's own gradient_steps


def _wall_clock(
    args: argparse.Namespace, callbacks: list[BaseCallback], name: str, resuming: bool, save_path: str
) -> WallClock:
    """
    The run's clock, given to its checkpoints: a resumed run counts on from the wall and CPU times saved with the
    checkpoint it resumed from, so that ``finished.json`` holds the whole run's (``wall_time_total_s``,
    ``cpu_time_total_s``). The attempt is recorded in the run folder (:func:`~sb3_icrl.run_folder.write_attempt`), for
    ``benchmark status`` to tell a running run's training time.
    """
    earlier: float = 0.0
    earlier_cpu: float | None = 0.0
    if resuming and args.trained_agent:
        state = training_state_path(args.trained_agent, name)
        earlier, earlier_cpu = training_state_wall_time(state), training_state_cpu_time(state)
    clock = WallClock(earlier, earlier_cpu)
    write_attempt(save_path, clock.start, clock.offset)
    for callback in callbacks:
        if isinstance(callback, AtomicCheckpointCallback):
            callback.wall_clock = clock
    return clock


def _restore_training_state(
    model: BaseAlgorithm, trained_agent: str, name: str, evaluation: ConstraintEvalCallback | None
) -> None:
    """The training state saved with ``trained_agent`` (ICRL trainer, and model selection when resuming in place)."""
    path = training_state_path(trained_agent, name)
    if os.path.isfile(path):
        load_training_state(model, path, evaluation)  # warns when it belongs to another step count
    elif getattr(model, "icrl_trainer", "absent") != "absent":
        warnings.warn(
            f"No training state with {trained_agent} ({path}): the ICRL trainer's nominal memory, unused trajectories "
            "and update schedule start afresh."
        )


def _restore_replay_buffer(model: BaseAlgorithm, trained_agent: str, verbose: int) -> ReplayBufferRefill | None:
    """
    An off-policy model's replay buffer, saved with ``trained_agent`` (:func:`~sb3_icrl.zoo.callbacks.replay_buffer_path`;
    only a run's newest checkpoint keeps one); without it the model goes on with an empty buffer, with a warning.

    :param model: The model continued from ``trained_agent``
    :param trained_agent: Its zip
    :param verbose: Verbosity level
    :return: The callback that holds back the gradient updates while the buffer holds fewer than ``learning_starts``
        transitions (``None``: no wait)
    """
    if not isinstance(model, OffPolicyAlgorithm):
        return None
    path = replay_buffer_path(trained_agent, model.num_timesteps)
    restored = load_replay_buffer(model, path)  # a damaged file: a ValueError that names it
    refill = ReplayBufferRefill.for_model(model)
    wait = (
        f"its gradient updates wait until it holds learning_starts ({model.learning_starts}) transitions again (after "
        f"step {refill.updates_after})"
        if refill is not None
        else ""
    )
    if restored:
        if verbose and model.replay_buffer is not None:
            # size() counts rows of n_envs transitions each
            stored = model.replay_buffer.size() * model.replay_buffer.n_envs
            print(f"Replay buffer restored from {os.path.basename(path)} ({stored} transitions)")
            if wait:
                print(f"The replay buffer is short of learning_starts: {wait}")
        return refill
    then = f"{wait}, so" if wait else "its first updates sample only the few transitions collected since, so"
    warnings.warn(
        f"No replay buffer with {trained_agent} ({os.path.basename(path)}; only a run's newest checkpoint keeps one): "
        f"the run goes on with an empty replay buffer: {then} it learns differently from an uninterrupted run."
    )
    return refill


def _release_refill(callbacks: list[BaseCallback]) -> None:
    """
    Give the model back the ``gradient_steps`` a :class:`~sb3_icrl.zoo.callbacks.ReplayBufferRefill` holds (a run
    stopped between a rollout and its update): the model is then saved with its own.

    :param callbacks: The run's callbacks
    """
    for callback in callbacks:
        if isinstance(callback, ReplayBufferRefill):
            callback.release()


def _pin_tensorboard(args: argparse.Namespace, model: BaseAlgorithm, params_path: str, name: str, resuming: bool) -> None:
    """
    Give the run one TensorBoard folder, recorded in ``<EnvName>/tensorboard.txt``: a resumed run writes its curves
    there (SB3 would pick the latest folder of the TensorBoard log dir, which may be another run's).
    """
    if not args.tensorboard_log:
        return
    record = os.path.join(params_path, "tensorboard.txt")
    folder = ""
    if resuming and os.path.isfile(record):
        with open(record) as file:
            folder = file.read().strip()
    if not folder:
        root, tb_log_name = os.path.join(args.tensorboard_log, name), f"{args.algo}_{name}"
        folder = os.path.join(root, f"{tb_log_name}_{sb3_latest_run_id(root, tb_log_name) + 1}")
        atomic_write_text(record, folder + "\n")
    model.set_logger(configure_logger(folder, ["stdout", "tensorboard"] if args.verbose >= 1 else ["tensorboard"]))


def _run_folder(args: argparse.Namespace, name: str) -> str:
    """
    ``<folder>/<algo>/<EnvName>_<N>``: N from ``--exp-id``, else the next free one (as rl-zoo); with ``-i``, the run
    folder of the model (see :func:`_in_place_folder`).
    """
    if args.new_folder and not args.trained_agent:
        raise ValueError("--new-folder says where -i continues a model: pass -i MODEL.zip too, or leave it out.")
    in_place = _in_place_folder(args, name)
    if in_place is not None:
        if args.exp_id is not None and os.path.abspath(in_place) != os.path.abspath(
            os.path.join(args.log_folder, args.algo, f"{name}_{args.exp_id}")
        ):
            raise ValueError(
                f"-i continues {args.trained_agent} in its own run folder {in_place}, but --exp-id {args.exp_id} names "
                "another: leave out --exp-id, or pass --new-folder to write the continuation to run N."
            )
        return in_place
    log_path = os.path.join(args.log_folder, args.algo)
    if args.exp_id is None:
        if args.resume:
            raise ValueError("--resume continues the run named by --exp-id: pass --exp-id N as well.")
        return os.path.join(log_path, f"{name}_{get_latest_run_id(log_path, name) + 1}")
    if args.exp_id < 0:
        raise ValueError(f"--exp-id must be >= 0, got {args.exp_id}.")
    save_path = os.path.join(log_path, f"{name}_{args.exp_id}")
    if os.path.exists(save_path) and not args.resume:
        raise ValueError(f"{save_path} exists: pass --resume to continue it, or another --exp-id.")
    return save_path


def _setup(
    args: argparse.Namespace,
    env_id: str,
    params: dict[str, Any],
    kwargs: dict[str, Any],
    save_path: str,
    resuming: bool = False,
) -> tuple[BaseAlgorithm, list[BaseCallback]]:
    """Envs, model and callbacks of a run (``resuming``: its own checkpoint in ``args.trained_agent``)."""
    env_kwargs = args.env_kwargs or {}
    stats_path = _resume_statistics(args.trained_agent, env_id, params) if args.trained_agent else None
    try:
        env, _ = create_env(
            env_id,
            params,
            params["n_envs"],
            args.seed,
            env_kwargs,
            args.transition_noise,
            save_path,
            stats_path=stats_path,
            append_monitor=resuming,
            # PPO-Lagrangian learns from the true cost; the ICRL learners and PPO never read it
            require_cost=args.algo == "ppolag" and kwargs.get("cost_fn") is None,
            transition_noise_model=args.transition_noise_model,
        )
    except TypeError as error:  # an env keyword it does not take, or a wrong type
        raise ValueError(f"Cannot make {env_id} with --env-kwargs {env_kwargs} and the yml's wrappers: {error}") from error
    except ImportError as error:  # a registration whose entry point names a module that is not there
        raise ValueError(
            f"Cannot make {env_id}: its entry point {gym.spec(env_id).entry_point!r} cannot be imported ({error}); fix the "
            "registration, or install what it needs."
        ) from error
    if resuming:
        _continue_monitor_clocks(env)
    demonstrations = _demonstrations(args.algo, env_id, args, env)
    if demonstrations is not None:
        kwargs["demonstrations"] = demonstrations
        if getattr(args, "allow_env_mismatch", False):
            kwargs["allow_env_mismatch"] = True
    algo_class = ALGOS[args.algo]
    tensorboard_log = os.path.join(args.tensorboard_log, env_name(env_id)) if args.tensorboard_log else None
    if args.trained_agent:
        model = _load_trained_agent(args, env, demonstrations, tensorboard_log, warn_overrides=not args.resume)
        return model, _callbacks(args, env_id, params, save_path, resuming)
    try:
        model = algo_class(
            params["policy"],
            env,
            tensorboard_log=tensorboard_log,
            seed=args.seed,
            verbose=args.verbose,
            device=args.device,
            **kwargs,
        )
    except TypeError as error:
        raise HyperparameterError(f"{algo_class.__name__} rejects the hyper-parameters {sorted(kwargs)}: {error}") from error
    return model, _callbacks(args, env_id, params, save_path, resuming)


def _resume_statistics(trained_agent: str, env_id: str, params: dict[str, Any]) -> str | None:
    """The ``VecNormalize`` statistics to resume with (see :func:`~sb3_icrl.run_folder.find_vecnormalize`)."""
    stats_path = find_vecnormalize(trained_agent, env_name(env_id))
    if params["normalize"] and stats_path is None:
        warnings.warn(
            f"No VecNormalize statistics found with {trained_agent} (rl_model_vecnormalize_<steps>_steps.pkl, "
            "<EnvName>/vecnormalize.pkl or vecnormalize.pkl): the normalisation starts afresh."
        )
    if not params["normalize"] and stats_path is not None:
        raise HyperparameterError(
            f"{trained_agent} was trained on normalised observations ({stats_path}), but normalize is off for this "
            "run: pass -params normalize:True."
        )
    return stats_path


def _load_trained_agent(
    args: argparse.Namespace, env: VecEnv, demonstrations: Any, tensorboard_log: str | None, warn_overrides: bool = True
) -> BaseAlgorithm:
    """``args.trained_agent`` on ``env``: everything saved in the zip (multiplier, constraint net, optimisers) goes on."""
    ignored = sorted(key for key in args.hyperparams or {} if key not in ZOO_KEYS)
    if ignored and warn_overrides:
        warnings.warn(f"-i keeps the hyper-parameters saved in {args.trained_agent}: the overrides {ignored} are not used.")
    extra = {"demonstrations": demonstrations} if demonstrations is not None else {}
    try:
        model = ALGOS[args.algo].load(
            args.trained_agent, env=env, device=args.device, tensorboard_log=tensorboard_log, verbose=args.verbose, **extra
        )
    except (ValueError, KeyError, TypeError) as error:
        raise TrainedAgentError(f"Cannot continue {args.trained_agent} as a {args.algo} model on this env: {error}") from error
    model.set_random_seed(args.seed)
    return model


def _callbacks(
    args: argparse.Namespace, env_id: str, params: dict[str, Any], save_path: str, resuming: bool = False
) -> list[BaseCallback]:
    """The yml's callbacks, checkpoints (with the normalisation statistics), the evaluation and constraint-figure callbacks."""
    env_kwargs = args.env_kwargs or {}
    callbacks: list[BaseCallback] = [callback(**cb_kwargs) for callback, cb_kwargs in params["callback"]]
    n_envs = params["n_envs"]
    if args.save_freq > 0:
        callbacks.append(
            AtomicCheckpointCallback(
                args.save_freq,
                save_path,
                name_prefix="rl_model",
                save_replay_buffer=True,  # off-policy models only
                save_vecnormalize=True,
                save_training_state=True,
            )
        )
    if args.eval_freq > 0:
        # As many eval envs as there are training envs (at most one per episode): the policy's forwards are batched
        eval_env, recorder = create_env(
            env_id,
            params,
            min(n_envs, args.eval_episodes),
            args.seed + 1000,
            env_kwargs,
            args.transition_noise,
            os.path.join(save_path, "eval"),
            eval_env=True,
            append_monitor=resuming,
            transition_noise_model=args.transition_noise_model,
        )
        if resuming:
            _continue_monitor_clocks(eval_env)
        callbacks.append(
            ConstraintEvalCallback(
                eval_env,
                recorder=recorder,
                n_eval_episodes=args.eval_episodes,
                eval_freq=max(args.eval_freq // n_envs, 1),
                log_path=save_path,
                best_model_save_path=save_path,
                deterministic=True,
                verbose=args.verbose,
                summary=True,
            )
        )
        if args.algo in ICRL_ALGOS and args.tensorboard_log:
            # The recovered constraint as TensorBoard figures (grid map, or partial dependence on the constrained feature)
            callbacks.append(
                ConstraintFigureCallback(eval_freq=max(args.eval_freq // n_envs, 1), env_id=env_id, env_kwargs=env_kwargs)
            )
    for callback in callbacks:
        if isinstance(callback, AtomicCheckpointCallback):
            callback.evaluation = _evaluation(callbacks)  # checkpoints save its model selection too
    return callbacks


def _evaluation(callbacks: list[BaseCallback]) -> ConstraintEvalCallback | None:
    """The run's evaluation callback, if it has one."""
    return next((callback for callback in callbacks if isinstance(callback, ConstraintEvalCallback)), None)


def _close_envs(model: BaseAlgorithm, callbacks: list[BaseCallback]) -> None:
    """
    Close the run's training and evaluation envs (their monitor files, simulators), as rl-zoo3 closes its training env.

    :param model: The run's model
    :param callbacks: The run's callbacks (the evaluation callback holds the evaluation env)
    """
    evaluation = _evaluation(callbacks)
    for env in (model.get_env(), evaluation.eval_env if evaluation is not None else None):
        if env is not None:
            with contextlib.suppress(EOFError, BrokenPipeError):  # the workers of a SubprocVecEnv that already ended
                env.close()


def _absolute_if_file(path: str | None) -> str | None:
    """
    A demonstrations file as an absolute path, so that args.yml names it for reports and plots run elsewhere; a shipped
    dataset's name as it is.
    """
    if path is not None and os.path.isfile(os.path.expanduser(path)):
        return os.path.abspath(os.path.expanduser(path))
    return path


def _mark_failed(save_path: str, error: Exception, model: BaseAlgorithm) -> None:
    """Write ``failed.json``, unless the disk that stopped the run takes no more (the error itself then says why)."""
    with contextlib.suppress(OSError):
        atomic_write_json(
            os.path.join(save_path, FAILED_FILE),
            {"error": f"{type(error).__name__}: {error}", "num_timesteps": int(model.num_timesteps)},
        )


def train(args: argparse.Namespace, argv: list[str] | None = None) -> str:
    """
    Run one training as described by parsed ``args``; return the run folder.

    :param args: From :func:`get_parser`
    :param argv: The command line, for ``command.txt``
    """
    import_gym_packages(args.gym_packages)
    env_id = resolve_env_id(args.env)
    args.gym_packages = [*args.gym_packages, *([args.env.partition(":")[0]] if ":" in args.env else [])]
    name = env_name(env_id)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)
    if args.device != "auto":
        try:
            th.device(args.device)
        except RuntimeError as error:
            raise ValueError(
                f"--device {args.device!r} is not a torch device ({error}): use auto, cpu, cuda or cuda:N."
            ) from None
    if args.seed is None:
        args.seed = int(np.random.randint(2**31 - 1))
    set_random_seed(args.seed)
    args.demonstrations = _absolute_if_file(args.demonstrations)

    if args.resume and args.trained_agent:
        raise ValueError("--resume continues a run from its own checkpoints: leave out -i/--trained-agent.")
    _check_noise_model_has_noise(args, argv)
    if args.trained_agent:
        check_trained_agent(args.trained_agent, args.algo)
    raw_params, source = load_hyperparams(
        args.algo, env_id, args.hyperparams, conf_file=args.conf_file, forward_recipe=args.forward_recipe
    )
    params = preprocess_hyperparams(raw_params)
    n_timesteps = args.n_timesteps if args.n_timesteps is not None else params["n_timesteps"]
    kwargs = algo_kwargs(params)
    solver = forward_solver(args.algo, params, env_id)
    _warn_without_constraint_updates(args, params, n_timesteps, source)
    check_hyperparameter_types(ALGOS[args.algo], kwargs)
    check_writable_folder(args.log_folder, "-f/--log-folder")
    if args.tensorboard_log:
        check_writable_folder(args.tensorboard_log, "-tb/--tensorboard-log")

    save_path = _run_folder(args, name)
    recipe = {**raw_params, "n_timesteps": n_timesteps}  # what config.yml records
    latest = latest_checkpoint(save_path) if args.resume and not is_finished(save_path) else None
    if args.resume and (is_finished(save_path) or latest is not None):
        # Before anything in the folder changes: a run made with another recipe is neither resumed nor passed as done
        check_same_recipe(os.path.join(save_path, name, "config.yml"), recipe)
        check_same_noise(os.path.join(save_path, name, "args.yml"), args)
    if args.resume and is_finished(save_path):
        if args.verbose:
            print(f"{save_path} has finished: nothing to do")
        return save_path
    resume_from = _resume_checkpoint(args, save_path, latest)
    resuming = resume_from is not None or _continue_in_place(args, name, save_path)
    if resuming:
        remove_temporaries(save_path)  # of writes cut short when the run was killed
        _trim_monitors_to_checkpoint(args, name, save_path)
    params_path = os.path.join(save_path, name)
    os.makedirs(params_path, exist_ok=True)
    if not resuming:
        atomic_write_yaml(os.path.join(params_path, "config.yml"), recipe)
        atomic_write_yaml(os.path.join(params_path, "args.yml"), {**vars(args), "env": env_id, "hyperparams_entry": source})
        atomic_write_yaml(os.path.join(params_path, "versions.yml"), versions())
    command = shlex.join(["python", sys.argv[0], *(argv if argv is not None else sys.argv[1:])])
    atomic_write_text(os.path.join(save_path, "command.txt"), command + "\n", append=resuming)

    try:
        model, callbacks = _setup(args, env_id, params, kwargs, save_path, resuming=resuming)
    except Exception:
        if not resuming:
            shutil.rmtree(save_path, ignore_errors=True)  # no half-made run folder for a run that never started
        raise
    if resume_from is not None:
        # The same total as the interrupted run: only the steps it had left
        n_timesteps = max(n_timesteps - model.num_timesteps, 0)
    try:
        evaluation = _evaluation(callbacks)
        _go_on(args, model, callbacks, name, resuming)
        _pin_tensorboard(args, model, params_path, name, resuming)
        clock = _wall_clock(args, callbacks, name, resuming, save_path)
        finished = False
        try:
            learn_function(model, solver, params.get("planner_kwargs"))(
                n_timesteps,
                callback=callbacks,
                tb_log_name=f"{args.algo}_{name}",
                progress_bar=args.progress or show_progress_bar(args.verbose),
                reset_num_timesteps=not args.trained_agent,
            )
            finished = True
        except KeyboardInterrupt:
            print("Interrupted: saving the model")
            _release_refill(callbacks)
        except Exception as error:
            # No final model: enjoy and compare would take it for a trained one; the checkpoints stay for --resume
            _mark_failed(save_path, error, model)
            raise
        final_model = os.path.join(save_path, f"{name}.zip")
        # Before the model it goes with
        save_training_state(
            model,
            training_state_path(final_model, name),
            evaluation,
            wall_time_s=clock.elapsed(),
            cpu_time_s=clock.cpu_elapsed(),
        )
        atomic_save_model(model, final_model)
        vec_normalize = model.get_vec_normalize_env()
        if vec_normalize is not None:
            atomic_save_pickle(vec_normalize, os.path.join(params_path, "vecnormalize.pkl"))
        if finished:
            atomic_write_json(
                os.path.join(save_path, FINISHED_FILE),
                {
                    "num_timesteps": int(model.num_timesteps),
                    "wall_time_s": clock.segment_elapsed(),
                    "wall_time_total_s": clock.elapsed(),
                    # CPU time of this process's training (this segment of a resumed run): the machine's load does not
                    # stretch it as it stretches wall time
                    "cpu_time_s": clock.segment_cpu_elapsed(),
                    # The whole run's, earlier segments included (null when a checkpoint resumed from did not record it)
                    "cpu_time_total_s": clock.cpu_elapsed(),
                    **({"evaluation_cpu_time_s": evaluation.eval_seconds} if evaluation is not None else {}),
                    "resumed_from": args.trained_agent if resuming else None,
                },
            )
        print_recovered_constraint(model, env_id, args.env_kwargs)
        # The seed is drawn at random when not given: printed, a run that surprises can be trained again
        print(f"Saved {save_path} ({clock.segment_elapsed():.1f} s, seed {args.seed})")
        return save_path
    finally:
        _close_envs(model, callbacks)  # a run trained inside a longer process leaves no file or simulator open


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """
    Command-line entry point (``train.py`` and ``sb3-icrl train``).

    :param argv: Arguments (default: ``sys.argv[1:]``)
    :param prog: Program name in the usage line
    :return: Exit status: 0, or 2 after a clear error
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_after_packages(get_parser, argv, prog)
    if args is None:
        return 2
    try:
        with sigterm_interrupts():
            train(args, argv)
    except (ValueError, HyperparameterError) as error:
        ours = [key.split("/", 1)[1] for key in gym.registry if key.startswith("sb3_icrl/")]
        hint = did_you_mean(args.env, ours) if "Unknown env" in str(error) else ""
        print(f"error: {error}{hint}", file=sys.stderr)
        return 2
    except OSError as error:
        message = write_error_message(error)
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)  # a full disk or a folder turned read-only mid-run
        return 1
    return 0


def cli(argv: list[str] | None = None) -> int:
    """
    ``sb3-icrl <command>``: ``train`` (this module), ``enjoy`` (:mod:`sb3_icrl.zoo.enjoy`), ``compare``
    (:mod:`sb3_icrl.zoo.compare`), ``benchmark`` (:mod:`sb3_icrl.benchmark.cli`) or ``transfer``
    (:mod:`sb3_icrl.metrics.transfer`).

    :param argv: Arguments, the command first (default: ``sys.argv[1:]``)
    :return: Exit status
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    # Imported here: ``python -m sb3_icrl.zoo.compare`` (or ``.enjoy``) must not find its module imported already
    from sb3_icrl.zoo import compare, enjoy

    if argv and argv[0] == "train":
        return main(argv[1:], prog="sb3-icrl train")
    if argv and argv[0] == "enjoy":
        return enjoy.main(argv[1:], prog="sb3-icrl enjoy")
    if argv and argv[0] == "compare":
        return compare.main(argv[1:], prog="sb3-icrl compare")
    if argv and argv[0] == "benchmark":
        return benchmark_cli.main(argv[1:], prog="sb3-icrl benchmark")
    if argv and argv[0] == "transfer":
        return transfer.main(argv[1:], prog="sb3-icrl transfer")
    print(
        "usage: sb3-icrl train --algo ALGO --env ENV [options] (see sb3-icrl train --help)\n"
        "       sb3-icrl enjoy --algo ALGO --env ENV [options] (see sb3-icrl enjoy --help)\n"
        "       sb3-icrl compare RUN [RUN ...] [options] (see sb3-icrl compare --help)\n"
        "       sb3-icrl benchmark run|status|report|list SUITE [options] (see sb3-icrl benchmark --help)\n"
        "       sb3-icrl transfer RUN --task same|reward|dynamics [options] (see sb3-icrl transfer --help)",
        file=sys.stderr,
    )
    return 2


if __name__ == "__main__":
    sys.exit(main())
