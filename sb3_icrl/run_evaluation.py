"""
Held-out evaluation of finished runs: a run's model stepped on env seeds it did not train on, one result per run, and
runs compared over seeds (what ``enjoy.py``, ``compare`` and the benchmark's tables report).
"""

import csv
import os
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_icrl.common.evaluation import OUTCOME_RATE_KEYS, ConstraintEvaluation, EpisodeAccumulator
from sb3_icrl.common.statistics import sample_std, wilcoxon_p
from sb3_icrl.envs.wrappers import recorded_transition_noise
from sb3_icrl.hyperparams import preprocess_hyperparams
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id, unknown_algo_message
from sb3_icrl.run_env import create_env
from sb3_icrl.run_folder import (
    check_trained_agent,
    find_vecnormalize,
    load_run_yaml,
    model_path,
    rl_zoo3_env_name,
    run_env_name,
    run_wall_time,
    unusable_wall_time,
)


class FrameSink(Protocol):
    """Where :func:`run_episodes` writes rendered frames (``enjoy.py --record``'s writer)."""

    def append(self, frame: Any) -> None:
        """Add a frame to the episode being written."""

    def end_episode(self) -> None:
        """Close the episode being written: the next frame starts another."""


def saved_settings(
    run: str, name: str, path: str, env_kwargs: dict[str, Any] | None = None
) -> tuple[dict[str, Any], dict[str, Any], str | None, float, str]:
    """
    What a run trained with and its model needs to run again: its recipe, env keyword arguments, ``VecNormalize``
    statistics and transition noise (its level and model).

    :param run: The run folder
    :param name: The env's folder name (:func:`~sb3_icrl.registry.env_name`)
    :param path: The model zip to run
    :param env_kwargs: Env keyword arguments over the run's own
    :return: ``(params, env_kwargs, stats_path, transition_noise, transition_noise_model)``, ``params`` preprocessed
    :raises FileNotFoundError: When the run normalised and the statistics are missing
    """
    params_path = os.path.join(run, name)
    params = preprocess_hyperparams(load_run_yaml(os.path.join(params_path, "config.yml")))
    saved_args: dict[str, Any] = {}
    if os.path.isfile(os.path.join(params_path, "args.yml")):
        saved_args = load_run_yaml(os.path.join(params_path, "args.yml"))
    merged_kwargs = {**(saved_args.get("env_kwargs") or {}), **(env_kwargs or {})}
    stats_path = find_vecnormalize(path, name) if params["normalize"] else None
    if params["normalize"] and stats_path is None:
        raise FileNotFoundError(f"{run} was trained with VecNormalize, but its statistics (vecnormalize.pkl) are missing.")
    return (params, merged_kwargs, stats_path, *recorded_transition_noise(saved_args))


def load_run_model(algo: str, path: str, device: str, seed: int) -> BaseAlgorithm:
    """
    :param algo: The registered name of the algorithm that saved ``path``
    :param path: The model zip
    :param device: torch device
    :param seed: Seed of the policy
    :return: The model, without env (an ICRL model would wrap it with its learned cost) or demonstrations (they only
        serve training)
    """
    extra: dict[str, Any] = {"demonstrations_source": None} if algo in ICRL_ALGOS else {}
    model = ALGOS[algo].load(path, device=device, **extra)
    model.set_random_seed(seed)
    return model


def run_episodes(
    model: Any,
    env: VecEnv,
    n_timesteps: int,
    deterministic: bool,
    verbose: int,
    writer: FrameSink | None = None,
    n_episodes: int | None = None,
) -> ConstraintEvaluation:
    """
    Step the single env ``n_timesteps`` times, or until ``n_episodes`` episodes have ended; per episode the same metrics
    as :func:`~sb3_icrl.common.evaluation.evaluate_constraint`. With a ``writer``, each rendered frame is written as it
    comes, one file per episode. Both ways seed and step the env alike: the first ``n_episodes`` episodes of a run by
    steps are the episodes of a run by episodes.

    :param model: The policy
    :param env: A single env (``VecNormalize`` on top, if any: the rewards reported are the raw ones)
    :param n_timesteps: Steps to run; with ``n_episodes``, the most steps to run (a policy whose episodes do not end
        stops there, with fewer episodes)
    :param deterministic: Deterministic actions
    :param verbose: 1: a line per episode
    :param writer: Where the rendered frames go (``None``: not rendered)
    :param n_episodes: Stop once this many episodes have ended (``None``: run every one of the ``n_timesteps`` steps)
    :return: The finished episodes
    """
    if n_episodes is not None and n_episodes < 1:
        raise ValueError(f"n_episodes must be at least 1, got {n_episodes}.")
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
            if n_episodes is not None and len(episodes.results["violations"]) >= n_episodes:
                break
        episode_start = dones
    evaluation = episodes.evaluation()
    finished = len(evaluation.violations)
    if finished:
        print(
            f"{finished} episodes: violation rate {evaluation.violation_rate:.2f}, feasible reward "
            f"{evaluation.mean_feasible_reward:.2f}, reward {evaluation.mean_reward:.2f}, true cost {evaluation.mean_cost:.2f}"
        )
    else:
        print(f"No episode finished in {n_timesteps} steps (use more -n).")
    return evaluation


class RunFolderError(ValueError):
    """A path that is not a finished ``train.py`` run folder, or runs that cannot be compared as asked."""


#: Steps per held-out episode when the env declares no time limit
DEFAULT_EPISODE_STEPS = 1000
#: An evaluation by episodes stops after this many times the steps of as many full-length episodes: no episode
#: outlasts its env's time limit, so only the policy of an env without one (its episodes counted as
#: :data:`DEFAULT_EPISODE_STEPS` long) or with a longer one than registered reaches it
EPISODE_STEP_CAP = 2


def heldout_steps(env_id: str, episodes: int) -> int:
    """Evaluation steps for ``episodes`` held-out episodes (episodes that end early leave room for more)."""
    limit = gym.spec(env_id).max_episode_steps or DEFAULT_EPISODE_STEPS
    return episodes * limit


def episode_step_cap(env_id: str, episodes: int) -> int:
    """The most steps an evaluation of exactly ``episodes`` episodes may take: :data:`EPISODE_STEP_CAP` times theirs."""
    return EPISODE_STEP_CAP * heldout_steps(env_id, episodes)


class UnfinishedEpisodesError(RunFolderError):
    """Fewer evaluation episodes ended than were asked for within the step cap: the run's policy, not its files."""


@dataclass
class RunResult:
    """
    One run's held-out evaluation.

    :param run: The run folder
    :param algo: Command-line algorithm name
    :param env: Env id the run trained on
    :param seed: Training seed
    :param timesteps: Steps the evaluated model had trained
    :param wall_time_min: Training wall time in minutes (the training monitor's last episode end), ``nan`` if unknown
    :param violation_rate: Share of held-out episodes with a true violation
    :param feasible_reward: Mean reward summed until the first true violation
    :param reward: Mean episode reward
    :param n_episodes: Held-out episodes run
    :param label: Row label when it is not the algorithm (a variant: see :func:`run_labels`)
    :param episode_length: Mean length of the held-out episodes (a learner that ends its episodes early shows here);
        ``nan`` when unknown (results saved before it was recorded)
    :param outcome_rates: For envs that flag how an episode ended (driving): ``{"collision_rate": share of held-out
        episodes, ...}`` for each of :data:`~sb3_icrl.common.evaluation.OUTCOME_KEYS`; empty for the other envs
    :param constraint_violation_rates: For envs that report each constraint's cost apart (several constraints):
        ``{"violation_rate_<name>": share of held-out episodes that broke it}``; empty for the other envs
    """

    run: str
    algo: str
    env: str
    seed: int
    timesteps: int
    wall_time_min: float
    violation_rate: float
    feasible_reward: float
    reward: float
    n_episodes: int
    label: str = ""
    episode_length: float = float("nan")
    outcome_rates: dict[str, float] = field(default_factory=dict)
    constraint_violation_rates: dict[str, float] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The row label: :attr:`label`, else the algorithm."""
        return self.label or self.algo


def describe_run(run: str) -> tuple[str, str, int, str]:
    """
    Algorithm, env id, training seed and exp id of a run folder ``<folder>/<algo>/<EnvName>_<N>``.

    :param run: The run folder
    :return: ``(algo, env_id, seed, folder)`` where ``folder`` is train.py's ``-f``
    """
    run = os.path.normpath(run)
    base, exp = os.path.split(run)
    folder, algo = os.path.split(base)
    name, _, exp_id = exp.rpartition("_")
    args_path = os.path.join(run, name, "args.yml")
    if not exp_id.isdigit() or not os.path.isfile(args_path):
        raise RunFolderError(
            f"{run} is not a train.py run folder: expected <folder>/<algo>/<EnvName>_<N> with <EnvName>/args.yml inside "
            "(rl_zoo3's run folders have the same layout)."
        )
    args = load_run_yaml(args_path)
    import_gym_packages(args.get("gym_packages"))  # a user's env, or algorithm, registers itself on import
    if algo not in ALGOS:
        raise RunFolderError(f"{run} is not a train.py run folder: {unknown_algo_message(algo)}")
    if name not in (env_name(args["env"]), rl_zoo3_env_name(args["env"])):
        raise RunFolderError(f"{run}: args.yml names env {args['env']!r}, but the folder is named after {name!r}.")
    if args.get("seed") is None:
        raise RunFolderError(f"{run} trained without a fixed --seed: it cannot be paired or reported per seed.")
    return algo, args["env"], int(args["seed"]), folder


def training_wall_time(run: str) -> float:
    """
    Minutes of training: the run's own record in ``finished.json`` (:func:`~sb3_icrl.run_folder.run_wall_time`, the
    time spent training, whole across resumes), else the training monitor's time from its start to its last finished
    episode (which also counts the time a resumed run was stopped), ``nan`` with neither.
    """
    return read_training_wall_time(run)[0]


def wall_time_notes(run: str) -> list[str]:
    """
    :param run: A run folder
    :return: What keeps :func:`training_wall_time` from the run's own record (a ``finished.json`` time that is not a
        number, a monitor file that does not read), one sentence each, naming the file
    """
    return read_training_wall_time(run)[1]


def read_training_wall_time(run: str) -> tuple[float, list[str]]:
    """
    :func:`training_wall_time` and :func:`wall_time_notes` from one read of the run's files (a caller that wants both
    need not read a long monitor file twice).

    :param run: A run folder
    :return: ``(minutes, notes)``
    """
    seconds = run_wall_time(run)
    if seconds is not None:
        return seconds / 60.0, []
    unusable = unusable_wall_time(run)
    notes = [f"{unusable}: the wall time comes from the training monitor instead"] if unusable else []
    path = os.path.join(run, "0.monitor.csv")
    if not os.path.isfile(path):
        return float("nan"), notes
    problem = None
    try:
        with open(path) as file:
            reader = csv.DictReader(line for line in file if not line.startswith("#"))
            rows = list(reader)
        fields = list(reader.fieldnames or [])
        if "t" not in fields:
            problem = f"has no 't' column (header {','.join(fields)!r})" if fields else "is empty"
    except (csv.Error, UnicodeDecodeError) as error:  # binary garbage
        problem = f"cannot be read ({type(error).__name__}: {error})"
    if problem is not None:
        return float("nan"), [*notes, f"{path} {problem}: it is not an SB3 Monitor file, so the wall time shows as nan"]
    try:
        return (float(rows[-1]["t"]) / 60.0 if rows else float("nan")), notes
    except (TypeError, ValueError):
        problem = f"its last row's time {rows[-1]['t']!r} is not a number (cut short or overwritten)"
        return float("nan"), [*notes, f"{path}: {problem}, so the wall time shows as nan"]


def evaluate_run(
    run: str,
    n_timesteps: int,
    eval_seed: int,
    load_best: bool = False,
    env_kwargs: dict[str, Any] | None = None,
    wall_time_min: float | None = None,
    n_episodes: int | None = None,
) -> RunResult:
    """
    Run a run's final (or best) model on held-out env seeds, as ``enjoy.py --no-render --verbose 0`` does.

    :param run: The run folder
    :param n_timesteps: Evaluation steps (episodes = steps / episode length); with ``n_episodes``, the step cap
    :param eval_seed: Seed of the evaluation env and policy (pick one the run did not train on)
    :param load_best: Evaluate ``best_model.zip`` instead of the final model
    :param env_kwargs: Env keyword arguments over the run's own (e.g. the driving envs' test recordings,
        :func:`sb3_icrl.envs.heldout_env_kwargs`)
    :param wall_time_min: The run's :func:`training_wall_time` when the caller has read it already (``None``: read it
        here)
    :param n_episodes: Evaluate exactly this many complete episodes, the first ones the steps would give (``None``:
        every episode that ends within ``n_timesteps`` steps)
    :raises UnfinishedEpisodesError: With ``n_episodes``, when fewer episodes end within the ``n_timesteps`` steps (an
        env without a time limit whose policy's episodes do not end)
    """
    algo, env_id, seed, _ = describe_run(run)
    env_id = resolve_env_id(env_id)
    name = run_env_name(run, env_id)  # (rl_zoo3 names its files after the whole id)
    th.set_num_threads(1)  # enjoy.py's default: the evaluation does not depend on the machine's threads
    path = model_path(run, name, load_best, None, False)
    check_trained_agent(path, algo)
    params, run_env_kwargs, stats_path, transition_noise, noise_model = saved_settings(run, name, path, env_kwargs)
    env, _ = create_env(
        env_id,
        params,
        1,
        eval_seed,
        run_env_kwargs,
        transition_noise,
        None,
        eval_env=True,
        stats_path=stats_path,
        transition_noise_model=noise_model,
    )
    model = load_run_model(algo, path, "auto", eval_seed)
    try:
        evaluation = run_episodes(model, env, n_timesteps, deterministic=True, verbose=0, n_episodes=n_episodes)
    finally:
        env.close()
    finished = len(evaluation.violations)
    if n_episodes is not None and finished < n_episodes:
        limit = gym.spec(env_id).max_episode_steps
        raise UnfinishedEpisodesError(
            f"{run}: only {finished} of its {n_episodes} evaluation episodes ended within {n_timesteps} steps, the cap"
            + (
                f": {env_id} has no time limit, and its policy's episodes do not end."
                if limit is None
                else f" ({env_id}'s time limit: {limit} steps an episode)."
            )
        )
    if finished == 0:
        raise RunFolderError(f"No evaluation episode of {run} finished in {n_timesteps} steps: raise -n.")
    return RunResult(
        run=run,
        algo=algo,
        env=env_id,
        seed=seed,
        timesteps=int(model.num_timesteps),
        wall_time_min=training_wall_time(run) if wall_time_min is None else wall_time_min,
        violation_rate=evaluation.violation_rate,
        feasible_reward=evaluation.mean_feasible_reward,
        reward=evaluation.mean_reward,
        n_episodes=len(evaluation.violations),
        episode_length=float(np.mean(evaluation.episode_lengths)),
        outcome_rates=evaluation.outcome_rates,
        constraint_violation_rates=evaluation.constraint_violation_rates,
    )


def summarise(results: list[RunResult], reference: str | None = None) -> dict[str, dict[str, Any]]:
    """
    Per algorithm: the seeds, mean and sample std (``ddof=1``; ``nan`` for one seed) of violation rate and feasible
    reward over its runs, and the Wilcoxon signed-rank test of its per-seed feasible rewards against ``reference`` on the
    seeds both ran (see :func:`wilcoxon_warnings` for what too few pairs mean).

    :param results: One entry per run; at most one run per (algorithm, seed)
    :param reference: Algorithm to test the others against (``None``: no test)
    """
    by_algo: dict[str, dict[int, RunResult]] = {}
    for result in results:
        runs = by_algo.setdefault(result.name, {})
        if result.seed in runs:
            raise same_seed_error(result.name, result.seed, runs[result.seed].run, result.run)
        runs[result.seed] = result
    if reference is not None and reference not in by_algo:
        raise RunFolderError(f"--reference {reference!r} has no run among the runs given ({sorted(by_algo)}).")
    summary: dict[str, dict[str, Any]] = {}
    for algo, runs in by_algo.items():
        violations = np.array([run.violation_rate for run in runs.values()])
        feasible = np.array([run.feasible_reward for run in runs.values()])
        entry: dict[str, Any] = {
            "seeds": sorted(runs),
            "violation_rate_mean": float(violations.mean()),
            "violation_rate_std": sample_std(violations),
            "feasible_reward_mean": float(feasible.mean()),
            "feasible_reward_std": sample_std(feasible),
        }
        outcomes = outcome_rate_means(list(runs.values()))
        if outcomes:
            entry["outcome_rates_mean"] = outcomes
        per_constraint = rate_means([run.constraint_violation_rates for run in runs.values()])
        if per_constraint:
            entry["constraint_violation_rates_mean"] = per_constraint
        if reference is not None and algo != reference:
            paired = sorted(set(runs) & set(by_algo[reference]))
            differences = [runs[s].feasible_reward - by_algo[reference][s].feasible_reward for s in paired]
            entry["wilcoxon_pairs"] = len(paired)
            # The pairs the signed-rank test ranks: a seed with no difference carries no sign (Wilcoxon's zero method)
            entry["wilcoxon_ranked_pairs"] = sum(difference != 0 for difference in differences)
            entry["wilcoxon_p"] = wilcoxon_p(differences)
        summary[algo] = entry
    return summary


def outcome_rate_means(results: list[RunResult]) -> dict[str, float]:
    """
    The mean over runs of each driving outcome rate that every run has (empty when some run has none).

    :param results: Runs of one algorithm
    :return: ``{"collision_rate": mean, ...}`` in :data:`~sb3_icrl.common.evaluation.OUTCOME_KEYS` order
    """
    means = rate_means([result.outcome_rates for result in results])
    return {key: means[key] for key in OUTCOME_RATE_KEYS.values() if key in means}


def rate_means(rates: list[dict[str, float]]) -> dict[str, float]:
    """
    :param rates: One ``{key: rate}`` per run
    :return: The mean over runs of each key that every run has, in the first run's order (empty without runs)
    """
    if not rates:
        return {}
    return {key: float(np.mean([run[key] for run in rates])) for key in rates[0] if all(key in run for run in rates)}


def same_seed_error(algo: str, seed: int, first: str, second: str) -> RunFolderError:
    return RunFolderError(
        f"Two {algo} runs trained with seed {seed} ({first} and {second}): pass one per algorithm and seed, or variants "
        "from different folders (train.py -f), which are labelled by folder."
    )


#: Column titles of the driving outcome rates
OUTCOME_TITLES = {"collision": "collision", "off_road": "off road", "time_out": "time out", "goal_reached": "goal reached"}


def format_outcome_rate(rate: float | None) -> str:
    """An outcome rate in whole percents, ``-`` where a run has none."""
    return "-" if rate is None else f"{100 * rate:.0f}%"
