"""
The layout of a run folder: which algorithm a zip holds, and the ``VecNormalize`` statistics that go with it.

A run folder ``<folder>/<algo>/<EnvName>_<N>/`` holds ``<EnvName>.zip`` (final), ``best_model.zip``,
``rl_model_<steps>_steps.zip`` checkpoints with their ``rl_model_vecnormalize_<steps>_steps.pkl`` statistics and
``rl_model_training_state_<steps>_steps.pkl`` training state (and for an off-policy algorithm, the newest one's
``rl_model_replay_buffer_<steps>_steps.pkl``), and ``<EnvName>/vecnormalize.pkl`` and ``<EnvName>/training_state.pkl``
(those of the final model).
"""

import dataclasses
import glob
import json
import math
import os
import pathlib
import pickle
import re
import time
import warnings
from collections.abc import Sequence
from typing import Any, TypeGuard

import yaml
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_icrl.common.saved import first_sentence, model_damage
from sb3_icrl.common.utils import atomic_write_json, atomic_write_text
from sb3_icrl.hyperparams import preprocess_hyperparams
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id

#: ``rl_model_<steps>_steps.zip``, as SB3's ``CheckpointCallback`` names its models
CHECKPOINT_PATTERN = re.compile(r"^(?P<prefix>.+)_(?P<steps>\d+)_steps\.zip$")


class TrainedAgentError(ValueError):
    """A saved model that cannot be used as asked (missing, not a model zip, another algorithm's)."""


def saved_algo(data: dict[str, Any]) -> str | None:
    """
    The command-line name of the algorithm that saved ``data`` (a zip's ``data``), told by what each class saves.

    ICRL models save their constraint net and their trainer class (the algorithm whose default trainer is the
    closest base of it), PPO-Lagrangian its multiplier; a plain PPO model neither.

    :param data: The ``data`` part of an SB3 zip (``load_from_zip_file``)
    :return: ``"ppo"``, ``"ppolag"``, an ICRL name, or ``None`` when it cannot be told
    """
    if "constraint_net_spec_" in data:
        trainer = data.get("trainer_class")
        return _icrl_algo_of_trainer(trainer) if isinstance(trainer, type) else None
    if "lagrange_multiplier" in data:
        return "ppolag"
    if "policy_class" in data:
        return "ppo"
    return None


def _icrl_algo_of_trainer(trainer: type) -> str | None:
    """The ICRL algorithm whose default trainer is the closest base of ``trainer``; on a tie, the first registered (a
    user's method that keeps its base's trainer saves what its base saves)."""
    mro = trainer.__mro__
    candidates = []
    for order, name in enumerate(ICRL_ALGOS):
        default = getattr(ALGOS[name], "default_trainer_class", None)
        if isinstance(default, type) and default in mro:
            candidates.append((mro.index(default), order, name))
    return min(candidates)[2] if candidates else None


def saved_as(algo: str) -> str | None:
    """
    :param algo: A registered command-line name
    :return: What :func:`saved_algo` tells the models of ``algo`` by: ``algo`` itself for ours, the name of its base for
        a user's method derived from one of ours, ``"ppo"`` for other algorithms (they save neither a constraint nor
        a multiplier)
    """
    algo_class = ALGOS[algo]
    trainer = getattr(algo_class, "default_trainer_class", None)
    if isinstance(trainer, type):
        return _icrl_algo_of_trainer(trainer)
    return "ppolag" if issubclass(algo_class, ALGOS["ppolag"]) else "ppo"


def check_trained_agent(path: str, algo: str) -> None:
    """
    Fail clearly unless ``path`` is an SB3 zip saved by ``algo``.

    :param path: The ``-i/--trained-agent`` (or enjoy's) model path
    :param algo: Command-line algorithm name
    :raises TrainedAgentError: When the file is missing, not a zip, damaged, not an SB3 model or another algorithm's
    """
    if os.path.isdir(path):
        models = sorted(entry for entry in os.listdir(path) if entry.endswith(".zip"))
        inside = f" (models in it: {', '.join(models)})" if models else ""
        raise TrainedAgentError(
            f"The trained agent {path!r} is a folder{inside}: expected a model .zip file saved by stable-baselines3, "
            "such as a run's <EnvName>.zip or one of its rl_model_<N>_steps.zip checkpoints."
        )
    if not os.path.isfile(path):
        raise TrainedAgentError(f"The trained agent {path!r} does not exist.")
    if not path.endswith(".zip"):
        raise TrainedAgentError(f"The trained agent {path!r} is not a .zip saved by stable-baselines3.")
    damage = model_damage(path, load=False)
    if damage is not None:
        raise TrainedAgentError(
            f"The trained agent {path!r} {damage}: it cannot be loaded; train it again, or use another model of its run "
            "(best_model.zip, a checkpoint)."
        )
    try:
        data, _, _ = load_from_zip_file(path, device="cpu")
    except Exception as error:
        raise TrainedAgentError(
            f"The trained agent {path!r} is damaged ({first_sentence(error)}): it cannot be loaded; train it again, or "
            "use another model of its run (best_model.zip, a checkpoint)."
        ) from error
    if not data:
        raise TrainedAgentError(f"The trained agent {path!r} holds no stable-baselines3 model data.")
    found = saved_algo(data)
    if found is None:
        raise TrainedAgentError(f"Cannot tell which algorithm saved {path!r}; expected a {algo} model.")
    if found not in (algo, saved_as(algo)):
        raise TrainedAgentError(f"{path!r} holds a {found} model, not a {algo} one: use --algo {found}.")


def get_latest_run_id(log_path: str, name: str) -> int:
    """Highest ``N`` of the ``<name>_<N>`` folders in ``log_path`` (0 when none), as rl-zoo."""
    run_id = 0
    if os.path.isdir(log_path):
        for entry in os.listdir(log_path):
            stem, _, suffix = entry.rpartition("_")
            if stem == name and suffix.isdigit():
                run_id = max(run_id, int(suffix))
    return run_id


def model_path(run: str, name: str, load_best: bool, checkpoint: int | None, last_checkpoint: bool) -> str:
    """
    The zip to load from ``run``: the final model, ``best_model.zip`` or a checkpoint.

    :param run: The run folder
    :param name: The env's folder name (the final model is ``<name>.zip``)
    :param load_best: ``best_model.zip``
    :param checkpoint: The checkpoint of this many steps
    :param last_checkpoint: The checkpoint of the most steps
    :return: The path
    :raises FileNotFoundError: When it does not exist (the message lists the run's models)
    """
    saved = {}
    for entry in os.listdir(run):
        match = CHECKPOINT_PATTERN.match(entry)
        if match and match["prefix"] == "rl_model":
            saved[int(match["steps"])] = entry
    if load_best:
        filename = "best_model.zip"
    elif checkpoint is not None:
        filename = f"rl_model_{checkpoint}_steps.zip"
    elif last_checkpoint:
        if not saved:
            raise FileNotFoundError(f"No checkpoint in {run} (train with --save-freq).")
        filename = saved[max(saved)]
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


#: The ``VecNormalize`` statistics saved with ``best_model.zip``, as they were when it was chosen
BEST_VECNORMALIZE_FILE = "best_model_vecnormalize.pkl"


def find_vecnormalize(model_path: str, name: str, warn: bool = True) -> str | None:
    """
    The ``VecNormalize`` statistics saved with a model: a checkpoint's own (``<prefix>_vecnormalize_<steps>_steps.pkl``)
    or the best model's own (:data:`BEST_VECNORMALIZE_FILE`), else the run's ``<EnvName>/vecnormalize.pkl`` (the final
    model's; for a best model saved before its own were, with a warning), else a ``vecnormalize.pkl`` beside the zip.

    :param model_path: The model zip
    :param name: The env name (folder name of the run's parameters)
    :param warn: Warn when a best model would run on the final model's statistics (callers that leave such a model
        out check :func:`lacks_own_statistics` themselves)
    :return: The path, or ``None`` when there is none
    """
    folder = os.path.dirname(os.path.abspath(model_path))
    candidates = []
    match = CHECKPOINT_PATTERN.match(os.path.basename(model_path))
    if match:
        candidates.append(os.path.join(folder, f"{match['prefix']}_vecnormalize_{match['steps']}_steps.pkl"))
    best = os.path.basename(model_path) == "best_model.zip"
    if best:
        candidates.append(os.path.join(folder, BEST_VECNORMALIZE_FILE))
    candidates += [os.path.join(folder, name, "vecnormalize.pkl"), os.path.join(folder, "vecnormalize.pkl")]
    found = next((path for path in candidates if os.path.isfile(path)), None)
    if best and warn and lacks_own_statistics(model_path, found):
        warnings.warn(
            f"{model_path} has no normalisation statistics of its own ({BEST_VECNORMALIZE_FILE}: runs save them with "
            f"the best model since they were added); running it with {found}, the final model's.",
            stacklevel=2,
        )
    return found


def lacks_own_statistics(model_path: str, stats_path: str | None) -> bool:
    """
    Whether a best model would run on statistics that are not its own: :func:`find_vecnormalize` found some, but not
    :data:`BEST_VECNORMALIZE_FILE` (a best model saved before runs saved its statistics with it). Such a model runs on
    the final model's statistics, i.e. not as it was when it was chosen.

    :param model_path: The best model's zip
    :param stats_path: What :func:`find_vecnormalize` found for it
    """
    own = os.path.join(os.path.dirname(os.path.abspath(model_path)), BEST_VECNORMALIZE_FILE)
    return stats_path is not None and os.path.abspath(stats_path) != own


def run_vecnormalize(run: str, model_path: str, name: str) -> str | None:
    """
    The ``VecNormalize`` statistics that go with a model of a run folder, when the run normalised (its
    ``<EnvName>/config.yml``): a model of a normalising run must never run without them.

    :param run: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :param model_path: The model zip (final, best or a checkpoint)
    :param name: The env's folder name (:func:`~sb3_icrl.registry.env_name`)
    :return: The statistics, or ``None`` when the run did not normalise
    :raises FileNotFoundError: When the run normalised and the statistics are missing
    """
    stats_path = find_vecnormalize(model_path, name)
    config = os.path.join(run, name, "config.yml")
    if not os.path.isfile(config):
        if stats_path is None:
            warnings.warn(
                f"No {config}: cannot tell whether {run} trained with VecNormalize; running its model without "
                "normalisation statistics.",
                stacklevel=2,
            )
        return stats_path
    normalize = preprocess_hyperparams(load_run_yaml(config))["normalize"]
    if not normalize:
        return None
    if stats_path is None:
        raise FileNotFoundError(
            f"{run} was trained with VecNormalize, but the statistics of {os.path.basename(model_path)} are missing "
            f"(looked for a checkpoint's own, {os.path.join(name, 'vecnormalize.pkl')} and vecnormalize.pkl)."
        )
    return stats_path


#: Written (atomically) into a run folder once its training has run to the end; a run folder without it is unfinished
FINISHED_FILE = "finished.json"
#: Keys of ``finished.json`` holding a run's training time in seconds, the first present wins: a resumed run's
#: ``wall_time_s`` may cover only its last segment, ``wall_time_total_s`` the whole run
WALL_TIME_KEYS = ("wall_time_total_s", "wall_time_s")
#: Keys of ``finished.json`` holding the CPU time the run's process spent training, in seconds, the first present wins
#: (as :data:`WALL_TIME_KEYS`); on a shared machine it is the fairer measure of the compute a run took
CPU_TIME_KEYS = ("cpu_time_total_s", "cpu_time_s")


#: Written (atomically) into a run folder whose training raised an error; such a run has no final model
FAILED_FILE = "failed.json"


def failure(run: str) -> str | None:
    """
    :param run: A run folder
    :return: The error its training stopped on (``failed.json``), or ``None`` when it did not fail
    """
    path = os.path.join(run, FAILED_FILE)
    if not os.path.isfile(path):
        return None
    record = _read_json_mapping(path)
    return "unknown error (unreadable failed.json)" if record is None else str(record.get("error", "unknown error"))


def is_finished(run: str) -> bool:
    """
    :param run: A run folder ``<folder>/<algo>/<EnvName>_<N>``
    :return: Whether its training ran to the end (``finished.json`` is there, a JSON mapping: a file cut short or
        overwritten with something else does not count, so that the run is trained again from its last checkpoint)
    """
    return read_finished(run) is not None


def read_finished(run: str | os.PathLike) -> dict[str, Any] | None:
    """
    :param run: A run folder
    :return: Its ``finished.json`` (step count, wall times), or ``None`` when it is missing, unreadable or not a mapping
    """
    return _read_json_mapping(os.path.join(run, FINISHED_FILE))


def _read_json_mapping(path: str) -> dict[str, Any] | None:
    """A JSON file's mapping; ``None`` when the file is missing, unreadable, cut short or holds something else."""
    try:
        with open(path) as file:
            content = json.load(file)
    except (OSError, ValueError):
        return None
    return content if isinstance(content, dict) else None


def unreadable_finished(run: str | os.PathLike) -> str | None:
    """
    :param run: A run folder
    :return: Why its ``finished.json`` does not count (present, but cut short or not a JSON mapping), naming the file;
        ``None`` when it is missing or reads
    """
    path = os.path.join(run, FINISHED_FILE)
    if not os.path.isfile(path) or read_finished(run) is not None:
        return None
    return f"{path} is not a JSON mapping (cut short or overwritten), so the run counts as not finished"


def run_wall_time(folder: str | os.PathLike) -> float | None:
    """
    The training time of a finished run, from its ``finished.json`` (see :data:`WALL_TIME_KEYS`).

    :param folder: The run folder
    :return: Seconds; ``None`` when the run is not finished or its ``finished.json`` records no time
    """
    return finished_wall_time(read_finished(folder))


def run_cpu_time(folder: str | os.PathLike) -> float | None:
    """
    The CPU time a finished run's process spent training, from its ``finished.json`` (see :data:`CPU_TIME_KEYS`).

    :param folder: The run folder
    :return: Seconds; ``None`` when the run is not finished or its ``finished.json`` records no CPU time
    """
    return finished_cpu_time(read_finished(folder))


def finished_cpu_time(finished: dict[str, Any] | None) -> float | None:
    """
    :param finished: A run's ``finished.json`` (:func:`read_finished`)
    :return: The CPU time its training process spent, in seconds (see :data:`CPU_TIME_KEYS`), ``None`` when it records
        none
    """
    return _finished_seconds(finished, CPU_TIME_KEYS)


def finished_wall_time(finished: dict[str, Any] | None) -> float | None:
    """
    :param finished: A run's ``finished.json`` (:func:`read_finished`)
    :return: Its training time in seconds (see :data:`WALL_TIME_KEYS`), ``None`` when it records none
    """
    return _finished_seconds(finished, WALL_TIME_KEYS)


def _finished_seconds(finished: dict[str, Any] | None, keys: Sequence[str]) -> float | None:
    """The first of ``keys`` that ``finished`` (a ``finished.json``) holds as a time in seconds; ``None`` if none."""
    for key in keys:
        value = finished.get(key) if finished is not None else None
        if _is_seconds(value):
            return float(value)
    return None


def _is_seconds(value: Any) -> TypeGuard[int | float]:
    """Whether ``value`` is a time in seconds (a finite number >= 0)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0


def unusable_wall_time(run: str | os.PathLike) -> str | None:
    """
    :param run: A run folder
    :return: Why a training time its ``finished.json`` records is not read (a key of :data:`WALL_TIME_KEYS` that holds
        text, say), naming the file and the key; ``None`` when each recorded time reads, or none is recorded
    """
    finished = read_finished(run)
    for key in WALL_TIME_KEYS:
        if finished is not None and key in finished and not _is_seconds(finished[key]):
            return f"{os.path.join(run, FINISHED_FILE)} records {key} as {finished[key]!r}, not a number of seconds"
    return None


def checkpoints(run: str) -> list[tuple[int, str]]:
    """
    :param run: A run folder
    :return: ``(steps, path)`` of each ``rl_model_<steps>_steps.zip`` in it, the most steps first (unchecked: see
        :func:`latest_checkpoint`); empty when the folder does not exist
    """
    if not os.path.isdir(run):
        return []
    found = []
    for entry in os.listdir(run):
        match = CHECKPOINT_PATTERN.match(entry)
        if match and match["prefix"] == "rl_model":
            found.append((int(match["steps"]), os.path.join(run, entry)))
    return sorted(found, reverse=True)


def latest_checkpoint(run: str, warn: bool = True) -> str | None:
    """
    The checkpoint to resume an unfinished run from: the ``rl_model_<steps>_steps.zip`` with the most steps that loads,
    with its statistics and training state (checkpoints are written atomically, but a folder may come from elsewhere).

    :param run: A run folder
    :param warn: Warn of each damaged checkpoint passed over, naming its file
    :return: The path, or ``None`` when the folder holds no usable checkpoint
    """
    saved = checkpoints(run)
    for index, (steps, path) in enumerate(saved):
        damage = model_damage(path)
        broken = f"{path} {damage}" if damage is not None else _broken_companion(run, steps)
        if broken is None:
            return path
        if warn:
            then = "resuming from an earlier checkpoint" if index + 1 < len(saved) else "no earlier checkpoint to resume from"
            warnings.warn(f"{broken}: {then} than {os.path.basename(path)}.")
    return None


def _broken_companion(run: str, steps: int) -> str | None:
    """The normalisation statistics or training state saved with a checkpoint, if one of them cannot be unpickled."""
    for kind in ("vecnormalize", "training_state"):
        path = os.path.join(run, f"rl_model_{kind}_{steps}_steps.pkl")
        if not os.path.isfile(path):
            continue
        try:
            with open(path, "rb") as file:
                pickle.load(file)  # the run's own files, written by this library
        except Exception:  # truncated, or not a pickle at all
            return f"{path} cannot be read"
    return None


#: Suffix of SB3's Monitor files: ``<i>.monitor.csv`` in the run folder (training envs) and in ``eval/`` (evaluation)
MONITOR_SUFFIX = ".monitor.csv"
#: Lines at the top of a Monitor file that are not episodes: its JSON header and the column names
MONITOR_HEADER_LINES = 2


def monitor_files(run: str | os.PathLike) -> list[str]:
    """The Monitor files of a run folder, relative to it (training envs' first, then the evaluation envs')."""
    found = []
    for folder in ("", "eval"):
        directory = os.path.join(run, folder)
        if os.path.isdir(directory):
            found += sorted(os.path.join(folder, entry) for entry in os.listdir(directory) if entry.endswith(MONITOR_SUFFIX))
    return found


def training_monitor_files(run: str | os.PathLike) -> list[str]:
    """The training envs' Monitor files of a run folder, relative to it (:func:`monitor_files` less ``eval/``)."""
    return [name for name in monitor_files(run) if not os.path.dirname(name)]


def _monitor_table(path: str | os.PathLike) -> tuple[list[str], list[list[str]]] | None:
    """
    A Monitor file's column names and its episodes' fields, one list per episode; ``None`` when it holds no column
    line (only its JSON header, or nothing).
    """
    with open(path) as file:
        lines = [line for line in file.read().splitlines() if line.strip()][1:]  # the JSON header first
    if not lines:
        return None
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


#: Training episodes the paper's protocol averages over, at the end of a run
LAST_TRAINING_EPISODES = 100


def last_training_episodes(run: str | os.PathLike, n_episodes: int = LAST_TRAINING_EPISODES) -> dict[str, float] | None:
    """
    The paper's way of reporting a run: over its last ``n_episodes`` training episodes (the stochastic policy, as it
    trained), the share that broke the true constraint and the mean feasible reward, read from the training envs'
    Monitor files (their ``true_violation`` and ``true_feasible_reward`` columns). The envs step together, so an
    episode's end is ordered by the steps its env had taken; a resumed run's files hold no replayed episode (they are
    trimmed to the checkpoint on resume).

    :param run: The run folder
    :param n_episodes: How many of the last episodes
    :return: ``{"violation_rate", "feasible_reward", "n_episodes"}``, or ``None`` when the files lack the columns
        (runs trained before they were written) or hold no episode
    """
    ends = []  # (env steps at the episode's end, env index, violated, feasible reward)
    for name in training_monitor_files(run):
        table = _monitor_table(os.path.join(run, name))
        if table is None:
            continue
        header, rows = table
        if "true_violation" not in header or "true_feasible_reward" not in header:
            return None
        length, violated, feasible = header.index("l"), header.index("true_violation"), header.index("true_feasible_reward")
        env_index = int(os.path.basename(name).split(".")[0]) if os.path.basename(name).split(".")[0].isdigit() else 0
        steps = 0
        for fields in rows:
            steps += int(float(fields[length]))
            ends.append((steps, env_index, float(fields[violated]), float(fields[feasible])))
    if not ends:
        return None
    last = sorted(ends)[-n_episodes:]
    return {
        "violation_rate": float(sum(row[2] for row in last) / len(last)),
        "feasible_reward": float(sum(row[3] for row in last) / len(last)),
        "n_episodes": float(len(last)),
    }


def training_progress(run: str | os.PathLike, now: float | None = None) -> tuple[int, float] | None:
    """
    How far a run still training has come, read from its training envs' Monitor files (as the files are written, at
    each episode's end): the env steps of the episodes they hold, and its training time so far.

    A Monitor records each episode's end as seconds since it was made. Where a resumed run's file holds one stretch per
    attempt (times that start again from zero, as SB3's own appended Monitors write them; the episodes after the
    checkpoint it resumed from were trimmed), the training time is the sum of each stretch's last time, plus the time
    since the file was last written: it leaves out each attempt's start before its first episode ended (seconds), and
    counts a stopped run's idle time since then. This library's resumed runs carry their first attempt's clock on, so
    their times hold the idle time between attempts too: :func:`training_time_so_far` tells those runs' time from their
    attempt record.

    :param run: The run folder
    :param now: The time to count to (default: now)
    :return: ``(env steps, seconds)``, or ``None`` when the run has no training Monitor file or no episode in one
    """
    now = time.time() if now is None else now
    steps, seconds = 0, None
    for name in training_monitor_files(run):
        path = os.path.join(run, name)
        try:
            table = _monitor_table(path)
            written = os.path.getmtime(path)
        except OSError:  # a file that went away between listing and reading
            continue
        if table is None or not table[1] or "l" not in table[0] or "t" not in table[0]:
            continue
        header, rows = table
        length, end = header.index("l"), header.index("t")
        file_seconds, stretch_end = 0.0, 0.0
        for fields in rows:
            try:
                episode_steps, episode_end = int(float(fields[length])), float(fields[end])
            except (IndexError, ValueError):  # a line cut short while it was written
                continue
            if episode_end < stretch_end:  # a new attempt: its Monitor counts from zero again
                file_seconds += stretch_end
            steps += episode_steps
            stretch_end = episode_end
        file_seconds += stretch_end + max(now - written, 0.0)
        seconds = file_seconds if seconds is None else max(seconds, file_seconds)  # the envs step together
    if seconds is None or steps == 0:
        return None
    return steps, seconds


#: A run's record of its current attempt, written as the attempt's training clock starts: when, and the training time
#: the run had then (0 for a fresh run; the time saved with the checkpoint a resumed run goes on from)
ATTEMPT_FILE = "attempt.json"


def write_attempt(run: str, started: float, resumed_wall_time_s: float) -> None:
    """
    Record the current attempt of a run (:data:`ATTEMPT_FILE`), for :func:`training_time_so_far`.

    :param run: The run folder
    :param started: When the attempt's training clock started (seconds since the epoch)
    :param resumed_wall_time_s: The training time the run had at that moment
    """
    atomic_write_json(os.path.join(run, ATTEMPT_FILE), {"started": started, "resumed_wall_time_s": resumed_wall_time_s})


def training_time_so_far(run: str, now: float | None = None, not_before: float | None = None) -> float | None:
    """
    The training time so far of a run that trains now, over all its attempts and without the time it lay stopped
    between them (a resumed run's Monitor clock runs on through that time): from its attempt record
    (:data:`ATTEMPT_FILE`), the training time it had when the current attempt's clock started plus the time since.

    :param run: The run folder
    :param now: The time to count to (default: now)
    :param not_before: When the current attempt began at the latest (its lock taken): a record from before is the
        previous attempt's, the current one still setting up
    :return: Seconds, or ``None`` without a current record (a run of an earlier version, or an attempt still setting
        up: :func:`training_progress` tells the time of a run that never stopped)
    """
    now = time.time() if now is None else now
    record = _read_json_mapping(os.path.join(run, ATTEMPT_FILE)) or {}
    started, resumed = record.get("started"), record.get("resumed_wall_time_s")
    if not (_is_seconds(started) and _is_seconds(resumed)) or (not_before is not None and started < not_before):
        return None
    return float(resumed) + max(now - float(started), 0.0)


def monitor_row_counts(run: str | os.PathLike) -> dict[str, int]:
    """
    The episodes each Monitor file of a run holds now (its lines less the header), by path relative to the run: what
    a checkpoint records, so that a run resumed from it can drop the episodes recorded after it.

    :param run: The run folder
    """
    counts = {}
    for name in monitor_files(run):
        with open(os.path.join(run, name), "rb") as file:
            lines = sum(1 for line in file if line.strip())
        counts[name] = max(lines - MONITOR_HEADER_LINES, 0)
    return counts


def trim_monitors(run: str | os.PathLike, counts: dict[str, int]) -> dict[str, int]:
    """
    Cut every Monitor file of a run back to the episodes it held at a checkpoint (``counts``, from
    :func:`monitor_row_counts`); a file the checkpoint did not know keeps its header only. Each file is rewritten
    atomically. A resumed run replays the steps after its checkpoint: without this, the episodes of those steps would
    be counted twice.

    :param run: The run folder
    :param counts: Episodes per Monitor file at the checkpoint
    :return: Episodes dropped per file (files that lost none are left out)
    """
    dropped = {}
    for name in monitor_files(run):
        path = os.path.join(run, name)
        with open(path) as file:
            lines = [line for line in file.read().splitlines() if line.strip()]
        keep = MONITOR_HEADER_LINES + counts.get(name, 0)
        if len(lines) > keep:
            dropped[name] = len(lines) - keep
            atomic_write_text(path, "\n".join(lines[:keep]) + "\n")
    return dropped


#: The tag PyYAML writes for an ``OrderedDict``, as rl_zoo3 saves its run's ``args.yml`` and ``config.yml``
ORDERED_DICT_TAG = "tag:yaml.org,2002:python/object/apply:collections.OrderedDict"


class RunYamlLoader(yaml.SafeLoader):
    """A safe YAML loader that also reads the ``OrderedDict`` tag of rl_zoo3's run files (as a plain dict)."""


def _ordered_dict(loader: yaml.SafeLoader, node: yaml.Node) -> dict[Any, Any]:
    # Written as OrderedDict(pairs): a sequence holding one argument, the list of [key, value] pairs
    arguments = loader.construct_sequence(node, deep=True)  # type: ignore[arg-type]
    return dict(arguments[0]) if arguments else {}


RunYamlLoader.add_constructor(ORDERED_DICT_TAG, _ordered_dict)


def load_run_yaml(path: str | os.PathLike) -> dict[str, Any]:
    """
    A run's ``args.yml`` or ``config.yml``, written by ``train.py`` or by rl_zoo3 (whose ``OrderedDict`` tags a plain
    ``yaml.safe_load`` refuses); nothing else that a YAML file could ask to build is built.

    :param path: The file
    :return: Its mapping
    :raises ValueError: When it is empty, not YAML, or not a mapping (naming the file)
    """
    try:
        with open(path) as file:
            content = yaml.load(file, Loader=RunYamlLoader)  # (a safe loader with one constructor added)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"{getattr(error, 'problem', None) or 'not YAML'}, line {mark.line + 1}" if mark else str(error)
        raise ValueError(
            f"{path} is not valid YAML ({where}): the run folder is damaged; restore the file from a copy, or train the "
            "run again."
        ) from error
    if content is None:  # train.py and rl_zoo3 never write an empty one: it was cut short or emptied
        raise ValueError(f"{path} is empty: the run folder is damaged; restore the file from a copy, or train the run again.")
    if not isinstance(content, dict):
        raise ValueError(f"{path} holds a {type(content).__name__}, not a mapping: the run folder is damaged.")
    return content


@dataclasses.dataclass(frozen=True)
class RunRecord:
    """
    What a run folder was trained on, as its ``<EnvName>/args.yml`` records it.

    :param env: The env's registered id (``sb3_icrl/BiasedPendulum-v0``)
    :param algo: The algorithm (``--algo``)
    :param env_kwargs: The env's keyword arguments
    :param gym_packages: The modules that register the env (imported by :func:`read_run_record`)
    """

    env: str
    algo: str | None
    env_kwargs: dict[str, Any]
    gym_packages: list[str]


def load_run_args(run: str | os.PathLike) -> tuple[pathlib.Path, dict[str, Any]]:
    """
    The arguments a ``train.py`` (or rl_zoo3) run folder was started with, from its ``<EnvName>/args.yml``.

    :param run: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :return: The ``args.yml`` file and its content
    :raises FileNotFoundError: When the folder or its ``args.yml`` is missing
    :raises ValueError: When the ``args.yml`` is empty or damaged (the file is named)
    """
    if not os.path.isdir(run):
        raise FileNotFoundError(f"No run folder {run}.")
    found = sorted(glob.glob(os.path.join(glob.escape(str(run)), "*", "args.yml")))
    if not found:
        raise FileNotFoundError(f"{run} is not a train.py run folder: no <EnvName>/args.yml in it.")
    return pathlib.Path(found[0]), load_run_yaml(found[0])


def read_run_record(run: str) -> RunRecord:
    """
    The env and algorithm a ``train.py`` (or rl_zoo3) run folder trained with, from its ``<EnvName>/args.yml``; the
    modules that register the env are imported, so that the id resolves.

    :param run: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :return: What it trained on
    :raises FileNotFoundError: When the folder or its ``args.yml`` is missing
    :raises ValueError: When the ``args.yml`` is damaged or names no env, or the env is not registered
    """
    path, run_args = load_run_args(run)
    if not run_args.get("env"):
        raise ValueError(f"{path} names no env: the run folder is damaged; restore the file from a copy.")
    gym_packages = list(run_args.get("gym_packages") or [])
    import_gym_packages(gym_packages)  # a user's env registers itself on import
    return RunRecord(
        env=resolve_env_id(str(run_args["env"])),
        algo=run_args.get("algo"),
        env_kwargs=dict(run_args.get("env_kwargs") or {}),
        gym_packages=gym_packages,
    )


def rl_zoo3_env_name(env_id: str) -> str:
    """The folder name rl_zoo3 gives an env (its ``EnvironmentName``): the id with ``/`` turned into ``-``."""
    return env_id.replace("/", "-")


def run_env_name(run: str, env_id: str) -> str:
    """
    The name of a run's ``<EnvName>.zip`` and ``<EnvName>/`` folder: ours (:func:`~sb3_icrl.registry.env_name`,
    ``GridWorldWall-v0``), or rl_zoo3's (:func:`rl_zoo3_env_name`, ``sb3_icrl-GridWorldWall-v0``) for a run it made.

    :param run: The run folder
    :param env_id: The env it trained on
    """
    ours = env_name(env_id)
    theirs = rl_zoo3_env_name(env_id)
    return theirs if not os.path.isdir(os.path.join(run, ours)) and os.path.isdir(os.path.join(run, theirs)) else ours


def made_by_rl_zoo3(run: str, name: str) -> bool:
    """Whether rl_zoo3 wrote the run folder (its ``args.yml`` is an ``OrderedDict``; ``train.py`` writes plain maps)."""
    path = os.path.join(run, name, "args.yml")
    if not os.path.isfile(path):
        return False
    with open(path) as file:
        return file.readline().startswith("!!python/object/apply:collections.OrderedDict")
