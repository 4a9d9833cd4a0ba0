"""
The report of a suite: every finished run's final model on held-out episodes (as ``sb3-icrl compare`` evaluates
it; on the driving envs, on their test recordings, which no run trains on), then per cell the per-seed values, mean
and std, the interquartile mean (IQM) with a 95% bootstrap confidence
interval, the Wilcoxon signed-rank test against a reference algorithm, the paper's number and other published
re-runs, the feasible reward as a fraction of our expert's return, and the compute the runs took, written as Markdown,
CSV, LaTeX and JSON, with figures.

IQM, optimality gap, probability of improvement and the stratified bootstrap follow rliable (Agarwal et al. 2021; see
:mod:`sb3_icrl.common.statistics`). Each statistic is labelled for what it is at its sample size: under
:data:`~sb3_icrl.common.statistics.MIN_SEEDS_FOR_INTERVAL` seeds a cell shows its mean and [min, max], not an IQM with
an interval, and under :data:`~sb3_icrl.common.statistics.MIN_PAIRS_FOR_WILCOXON` pairs no Wilcoxon p-value.

With the reference rows in a suite (``ppo``, unconstrained, and ``ppolag`` on the true cost, the oracle), each run's
feasible reward is also normalised, ``(F - F_ppo) / (F_oracle - F_ppo)`` with the two rows' means on the same env and
variant, and the suite's ``success`` rule (a violation rate at most ``max_violation_rate`` and a normalised score at
least ``min_normalised_score``) gives each cell a success probability with its Wilson 95% interval.
"""

import csv
import io
import json
import math
import os
import pathlib
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, fields
from typing import Any

import numpy as np
import yaml
from matplotlib.lines import Line2D

from sb3_icrl.benchmark.suite import BEATS_COLUMNS, RunSpec, Suite, result_current
from sb3_icrl.common.evaluation import CONSTRAINT_VIOLATION_PREFIX, OUTCOME_KEYS, OUTCOME_RATE_KEYS
from sb3_icrl.common.statistics import (
    MIN_PAIRS_FOR_WILCOXON,
    MIN_SEEDS_FOR_INTERVAL,
    iqm,
    mean_of_task_means,
    normalised_score,
    optimality_gap,
    performance_profile,
    performance_profile_ci,
    probability_of_improvement,
    probability_of_improvement_ci,
    stratified_bootstrap_ci,
    stratified_bootstrap_ci_of_task_means,
    wilson_interval,
)
from sb3_icrl.common.utils import atomic_write_bytes, atomic_write_json
from sb3_icrl.data import load_demonstrations
from sb3_icrl.envs import heldout_env_kwargs
from sb3_icrl.envs.constraint_spec import get_constraint_spec
from sb3_icrl.metrics.identification import (
    headline,
    identification_cached,
    identification_file,
    identify_run,
    learned_cost_curves,
    learned_cost_figure,
)
from sb3_icrl.metrics.transfer import read_transfers, transfer_file
from sb3_icrl.plots.figures import load_evaluations, new_figure, save_figure, training_curves_figure
from sb3_icrl.registry import ICRL_ALGOS, env_name
from sb3_icrl.run_evaluation import (
    OUTCOME_TITLES,
    RunResult,
    UnfinishedEpisodesError,
    episode_step_cap,
    evaluate_run,
    format_outcome_rate,
    heldout_steps,
    summarise,
)
from sb3_icrl.run_folder import (
    LAST_TRAINING_EPISODES,
    find_vecnormalize,
    is_finished,
    lacks_own_statistics,
    last_training_episodes,
    run_wall_time,
    unreadable_finished,
)

#: Held-out evaluation cached in each run folder
HELDOUT_FILE = "heldout.json"
#: The same for ``best_model.zip`` (``model="best"``)
HELDOUT_BEST_FILE = "heldout_best.json"
#: The per-seed identification columns of ``runs.csv`` (:func:`~sb3_icrl.metrics.identification.headline`)
IDENTIFICATION_COLUMNS = (
    "identification_auroc",
    "threshold_error",
    "threshold_crossing",
    "learner_cost",
    "cost_budget",
    "untrained_auroc",
    "untrained_auroc_low",
    "untrained_auroc_high",
)
#: What a report can evaluate: each run's final model, or the best model its training chose on learned quantities
REPORT_MODELS = ("final", "best")


def heldout_settings(suite: Suite, env_id: str, model: str = "final") -> dict[str, Any]:
    """
    What a run's held-out evaluation depends on: its cache is used only when they are the same. An evaluation by steps
    records its steps (``n_timesteps``, as before the suite key ``eval_budget`` was read: those caches stay valid), one
    by episodes its episodes (``n_episodes``): the two never share a cache.

    :param suite: The suite (evaluation budget, episodes and seed)
    :param env_id: The run's env id
    :param model: ``"final"`` or ``"best"``
    :return: The settings, as ``heldout.json`` records them
    """
    budget: dict[str, int] = (
        {"n_timesteps": heldout_steps(env_id, suite.eval_episodes)}
        if suite.eval_budget == "steps"
        else {"n_episodes": suite.eval_episodes}
    )
    settings: dict[str, Any] = {"eval_seed": suite.eval_seed, **budget, **({"model": model} if model == "best" else {})}
    env_kwargs = heldout_env_kwargs(env_id)  # the driving envs: their test recordings
    if env_kwargs:
        settings["env_kwargs"] = env_kwargs  # a cache made on other recordings is evaluated again
    return settings


def evaluate_finished(
    runs: Sequence[RunSpec], root: str, suite: Suite, log: Callable[[str], None] = print, model: str = "final"
) -> list[tuple[RunSpec, RunResult]]:
    """
    Held-out evaluation of every finished run (cached in the run folder as ``heldout.json``, ``heldout_best.json``
    for the best model, keyed by the evaluation settings, :func:`heldout_settings`, so a report is cheap to make again;
    a cache whose fields are not those of :class:`RunResult`, written by another version, is evaluated again).

    The suite's ``eval_budget`` says what is run: ``episodes``, exactly ``eval_episodes`` complete episodes from
    ``eval_seed`` (a run whose policy has not ended them within
    :func:`~sb3_icrl.run_evaluation.episode_step_cap` steps is left out, and said so); ``steps``, the steps of
    ``eval_episodes`` full-length episodes, every episode that ends in them counted (more of them where episodes end
    early).

    :param runs: The suite's runs
    :param root: The log root
    :param suite: The suite (evaluation budget, episodes and seed)
    :param log: Where progress lines go
    :param model: ``"final"``: each run's final model; ``"best"``: the ``best_model.zip`` its training chose by its
        algorithm's selection score (ICRL methods: learned quantities only), run with the normalisation statistics
        saved with it (a run without either is left out, and said so)
    :return: ``(run, result)`` for each finished run
    """
    if model not in REPORT_MODELS:
        raise ValueError(f"`model` must be one of {', '.join(REPORT_MODELS)}, got {model!r}.")
    best = model == "best"
    results = []
    for run in runs:
        folder = run.run_folder(root)
        if not is_finished(folder):
            unreadable = unreadable_finished(folder)
            if unreadable is not None:  # listed as not finished below: say why, and what brings it back
                log(f"{run.name}: {unreadable}: `benchmark run` trains it again from its last checkpoint")
            continue
        best_path = os.path.join(folder, "best_model.zip")
        if best and not os.path.isfile(best_path):
            log(f"{run.name} has no best_model.zip (trained without evaluations?): left out of the best models' report")
            continue
        if best and lacks_own_statistics(best_path, find_vecnormalize(best_path, env_name(run.env_id), warn=False)):
            # It would run on the final model's normalisation statistics: not the model that was chosen
            log(
                f"{run.name}: its best_model.zip has no normalisation statistics of its own (trained before they were "
                "saved with it): left out of the best models' report"
            )
            continue
        steps = heldout_steps(run.env_id, suite.eval_episodes)
        cache = os.path.join(folder, HELDOUT_BEST_FILE if best else HELDOUT_FILE)
        settings = heldout_settings(suite, run.env_id, model)
        env_kwargs = dict(settings.get("env_kwargs", {}))  # the env's held-out data, read once with the settings
        cached = None
        saved: dict[str, Any] = {}
        if os.path.isfile(cache):
            try:
                with open(cache) as file:
                    saved = json.load(file)
            except (OSError, ValueError):  # a cache cut short: evaluated again
                saved = {}
            if (
                isinstance(saved, dict)
                and saved.get("settings") == settings
                and _cache_fields_fit(saved.get("result", {}), run.env_id, env_kwargs)
                and os.path.getmtime(cache) >= os.path.getmtime(os.path.join(folder, "finished.json"))
            ):
                cached = RunResult(**saved["result"])
        if cached is None:
            if suite.eval_budget == "steps":
                log(
                    f"evaluating {run.name}{' (best model)' if best else ''} on {steps} held-out steps "
                    f"({suite.eval_episodes} full-length episodes)"
                )
                budget: dict[str, Any] = {}
            else:
                log(f"evaluating {run.name}{' (best model)' if best else ''} on {suite.eval_episodes} held-out episodes")
                steps = episode_step_cap(run.env_id, suite.eval_episodes)  # a policy whose episodes never end stops
                budget = {"n_episodes": suite.eval_episodes}
            try:
                cached = evaluate_run(folder, steps, suite.eval_seed, load_best=best, env_kwargs=env_kwargs, **budget)
            except UnfinishedEpisodesError as error:  # its policy, not its files: training it again would not help
                log(f"{run.name}: left out of the report, {error}")
                continue
            except Exception as error:  # one broken run leaves its cell short by a seed, not the report unwritten
                log(
                    f"{run.name}: left out of the report, its model in {folder} could not be evaluated "
                    f"({type(error).__name__}: {error}); train it again (delete its finished.json) or restore the file"
                )
                continue
            atomic_write_json(cache, {"settings": settings, "result": asdict(cached)}, indent=2)
        cached.run = os.path.relpath(folder, root)
        results.append((run, cached))
    return results


def declares_several_constraints(env_id: str, env_kwargs: dict[str, Any] | None = None) -> bool:
    """
    :param env_id: A registered env id
    :param env_kwargs: The keyword arguments it is made with
    :return: Whether the env declares several constraints (its evaluations report each one's violation rate);
        ``True`` when the declaration cannot be read, so that a result without those rates is not taken as complete
    """
    try:
        spec = get_constraint_spec(env_id, env_kwargs)
    except Exception:  # an env that cannot be made here: its result is evaluated again, which says why
        return True
    return spec is not None and len(spec.features) > 1


def _cache_fields_fit(result: Any, env_id: str, env_kwargs: dict[str, Any]) -> bool:
    """
    Whether a cached held-out result has the fields of :class:`RunResult`; one saved before the per-constraint
    violation rates were kept fits too (as none) on an env with one constraint, which has none to keep.
    """
    if not isinstance(result, dict):
        return False
    expected = {entry.name for entry in fields(RunResult)}
    if set(result) == expected:
        return True
    return set(result) == expected - {"constraint_violation_rates"} and not declares_several_constraints(env_id, env_kwargs)


def constraint_metrics(
    results: Sequence[tuple[RunSpec, RunResult]], root: str, log: Callable[[str], None] = print, model: str = "final"
) -> dict[str, dict[str, Any]]:
    """
    Per finished run, how well its learned constraint identifies the true one (ICRL runs: AUROC, and the threshold
    error at ``t = 0.5`` where the constraint is a feature threshold; cached in the run folder as
    ``identification.json``), how it transfers (the ``transfer_<task>.json`` that ``sb3-icrl transfer`` wrote, if
    any: the learner's true violation rate and its feasible reward as a share of the oracle's), and its training time
    and expert's return (:func:`run_facts`).

    :param results: ``(run, held-out result)`` of the finished runs (:func:`evaluate_finished`)
    :param root: The log root
    :param log: Where progress lines and skipped runs go
    :param model: ``"final"`` or ``"best"``: whose learned constraint is scored (cached in ``identification.json``
        or ``identification_best.json``); transfer results, which ``sb3-icrl transfer`` computes for the final model,
        are added to the final model's report only
    :return: ``{result.run: {column: value}}``
    """
    metrics = run_facts(results, root)
    for run, result in results:
        folder = os.path.join(root, result.run)
        entry = metrics.setdefault(result.run, {})
        if run.algo in ICRL_ALGOS:
            if not identification_cached(folder, model):
                log(f"scoring the learned constraint of {run.name} against the true one")
            try:
                entry.update(headline(identify_run(folder, model=model)["scores"]))
            except Exception as error:  # a run that cannot be scored leaves its columns empty, not the report unwritten
                log(f"no identification scores for {run.name}: {type(error).__name__}: {error}")
        for task, transfer in (read_transfers(folder) if model == "final" else {}).items():
            if not result_current(folder, transfer_file(task)):
                log(
                    f"{run.name}: its {transfer_file(task)} predates its final model (trained again since): left out; "
                    "`benchmark run` runs the transfer again"
                )
                continue
            entry[f"transfer_{task}_violation_rate"] = float(transfer["violation_rate"])
            entry[f"transfer_{task}_feasible_ratio"] = float(transfer["feasible_reward_ratio"])
    return metrics


def run_facts(results: Sequence[tuple[RunSpec, RunResult]], root: str) -> dict[str, dict[str, Any]]:
    """
    Per finished run, its training time (``wall_time_s``, from ``finished.json``, see :func:`run_wall_time`), the
    mean return of the demonstrations it learned from (``expert_return``, see :func:`demonstrations_source`; NaN when
    there are none, e.g. an env without a shipped dataset), its recipe version, its :func:`training_provenance` and
    its last training episodes.

    :param results: ``(run, held-out result)`` of the finished runs (:func:`evaluate_finished`)
    :param root: The log root
    :return: ``{result.run: {column: value}}``
    """
    returns: dict[tuple[str, float | None], float | None] = {}  # one load per dataset, however many runs share it
    facts: dict[str, dict[str, Any]] = {}
    for run, result in results:
        folder = os.path.join(root, result.run)
        entry: dict[str, Any] = {}
        seconds = run_wall_time(folder)
        if seconds is not None:
            entry["wall_time_s"] = seconds
        entry["expert_return"] = _expert_return_once(demonstrations_source(run, folder), returns)
        version = recorded_recipe_version(folder)
        if version is not None:
            entry["recipe_version"] = version
        entry.update(training_provenance(folder))
        last = last_training_episodes(folder)
        if last is not None:  # the paper's protocol: the last training episodes of the stochastic policy
            entry["last_training_violation_rate"] = last["violation_rate"]
            entry["last_training_feasible_reward"] = last["feasible_reward"]
        facts[result.run] = entry
    return facts


#: The per-seed entries of a summary that are the held-out result itself; the others are the run's metrics
_RESULT_KEYS = ("seed", "feasible_reward", "violation_rate", "reward", "timesteps", "n_episodes", "episode_length")


def previous_results(
    summary: dict[str, Any], suite: Suite, root: str
) -> tuple[list[tuple[RunSpec, RunResult]], dict[str, dict[str, Any]], list[RunSpec]]:
    """
    An earlier report's runs, read back from its ``summary.json``: what ``sb3-icrl benchmark report --update`` keeps
    of the cells that its fresh runs do not replace (their run folders may be gone; what their figures draw is in the
    report's :data:`FIGURE_DATA_FILE`).

    :param summary: The earlier report's summary
    :param suite: The suite it reported (its name must match)
    :param root: The log root of the fresh runs (the earlier runs are keyed as if their folders were there)
    :return: ``(run, held-out result)`` per earlier run, their metrics keyed by ``result.run`` (as
        :func:`constraint_metrics` keys them), and the runs the earlier report listed as not finished
    """
    if summary.get("suite") != suite.name:
        raise ValueError(
            f"The report to update is of suite {summary.get('suite')!r}, not {suite.name!r}: pass the suite it reports, "
            "or another -o folder."
        )
    by_name = {run.name: run for run in suite.runs()}
    by_cell_and_seed = {(*run.cell, run.seed): run for run in suite.runs()}
    results: list[tuple[RunSpec, RunResult]] = []
    metrics: dict[str, dict[str, Any]] = {}
    for cell in summary.get("cells", []):
        for seed in cell["per_seed"]:
            run = by_cell_and_seed.get((cell["env"], cell["variant"], cell["algo"], int(seed["seed"])))
            if run is None:
                gone = summary_run(suite, cell, seed)
                raise ValueError(
                    f"The report to update holds run {gone.name!r}, which suite {suite.name!r} no longer has: report "
                    "into another -o folder (or without --update)."
                )
            key = os.path.relpath(run.run_folder(root), root)
            rates = {column: seed[column] for column in OUTCOME_RATE_KEYS.values() if column in seed}
            per_constraint = {column: seed[column] for column in seed if column.startswith(CONSTRAINT_VIOLATION_PREFIX)}
            result = RunResult(
                key,
                run.algo,
                run.env_id,
                run.seed,
                int(seed["timesteps"]),
                _float(seed.get("wall_time_s")) / 60,
                _float(seed["violation_rate"]),
                _float(seed["feasible_reward"]),
                _float(seed["reward"]),
                int(seed["n_episodes"]),
                episode_length=_float(seed.get("episode_length")),
                outcome_rates=rates,
                constraint_violation_rates=per_constraint,
            )
            results.append((run, result))
            kept = (*_RESULT_KEYS, *rates, *per_constraint)
            metrics[key] = {column: value for column, value in seed.items() if column not in kept}
    missing = [by_name[name] for name in summary.get("runs_missing", []) if name in by_name]
    return results, metrics, missing


def _float(value: float | None) -> float:
    """A number of a strict-JSON summary: ``null`` was a non-finite float."""
    return float("nan") if value is None else float(value)


def _mean_of(values: Sequence[float | None]) -> float | None:
    """Mean of the finite values given (``None`` when there is none)."""
    finite = [float(value) for value in values if value is not None and math.isfinite(value)]
    return float(np.mean(finite)) if finite else None


#: The paper's protocol per seed: the last training episodes' feasible reward and violation rate (Monitor files)
LAST_TRAINING_COLUMNS = ("last_training_feasible_reward", "last_training_violation_rate")

#: Transfer columns of the per-seed values, in table order
TRANSFER_COLUMNS = tuple(
    f"transfer_{task}_{metric}" for task in ("same", "reward", "dynamics") for metric in ("violation_rate", "feasible_ratio")
)


def _identification_text(seed: dict[str, Any]) -> str:
    """
    ``AUROC / threshold error`` of one seed: ``-`` where the learned cost never reaches 0.5 (or there is no
    threshold), ``everywhere`` where it stays at or above 0.5 up to the safe end of the feature's range. Beside the
    AUROC, untrained nets' median and range (``one draw`` for a run scored when the baseline was a single net).
    """
    if "identification_auroc" not in seed:
        return "-"
    error = seed.get("threshold_error")
    # (a summary read back from JSON has null for both non-finite errors: its crossing tells them apart)
    everywhere = seed.get("threshold_crossing") == "everywhere" or (error is not None and math.isinf(error))
    error_text = "everywhere" if everywhere else _fmt(error, 2) if error is not None and math.isfinite(error) else "-"
    untrained, low, high = (seed.get(key) for key in ("untrained_auroc", "untrained_auroc_low", "untrained_auroc_high"))
    if untrained is None or (isinstance(untrained, float) and math.isnan(untrained)):
        baseline = ""
    elif low is None or high is None or low == high:  # one net (scored before the baseline took several)
        baseline = f" (untrained {_fmt(untrained, 2)}, one draw)"
    else:
        baseline = f" (untrained {_fmt(untrained, 2)}, {_fmt(low, 2)}-{_fmt(high, 2)})"
    return f"{_fmt(seed['identification_auroc'], 2)}{baseline} / {error_text}"


def _transfer_text(seed: dict[str, Any]) -> str:
    """``task: violation / feasible-reward ratio`` of each transfer of one seed."""
    parts = []
    for task in ("same", "reward", "dynamics"):
        if f"transfer_{task}_violation_rate" in seed:
            ratio = seed[f"transfer_{task}_feasible_ratio"]
            parts.append(f"{task} {100 * seed[f'transfer_{task}_violation_rate']:.0f}% / {_fmt(ratio, 2)}")
    return ", ".join(parts) or "-"


def _run_args(folder: str | os.PathLike | None, file_name: str = "args.yml") -> dict[str, Any] | None:
    """A run folder's ``args.yml`` (or another yml file beside it; ``None`` when it has none, or it cannot be read)."""
    found = sorted(pathlib.Path(folder).glob(f"*/{file_name}")) if folder is not None else []
    if not found:
        return None
    try:
        with open(found[0]) as file:
            content = yaml.safe_load(file)
    except (OSError, yaml.YAMLError):
        return None
    return content if isinstance(content, dict) else None


def training_provenance(folder: str | os.PathLike) -> dict[str, Any]:
    """
    How a run was trained, for a reader who trains it again: ``git_revision``, the code it started with (its
    ``versions.yml``), and ``training_starts``, how many times its training started (the lines of its
    ``command.txt``: 1 when it ran uninterrupted; a resumed run goes on with fresh random streams, so it is not
    bit-identical to one that was not).

    :return: Those of the two the folder records
    """
    provenance: dict[str, Any] = {}
    revision = (_run_args(folder, "versions.yml") or {}).get("git_revision")
    if revision is not None:
        provenance["git_revision"] = str(revision)
    try:
        with open(os.path.join(folder, "command.txt")) as file:
            provenance["training_starts"] = sum(1 for line in file if line.strip())
    except OSError:
        pass
    return provenance


def recorded_recipe_version(folder: str | os.PathLike) -> str | None:
    """The recipe version a run recorded (``--recipe-version`` in its ``args.yml``), ``None`` when it recorded none."""
    version = (_run_args(folder) or {}).get("recipe_version")
    return str(version) if version is not None else None


def check_recipe_versions(cell: dict[str, Any], expected: str | None = None) -> None:
    """
    Refuse a cell whose runs recorded different recipe versions (a run that recorded none counts as its own version):
    its statistics would mix two recipes; and, for a suite that names its version, a cell whose runs recorded another
    one (or none): the suite reports its own recipes only.

    :param cell: A cell of :func:`summarise_suite`
    :param expected: The suite's ``recipe_version`` (``None``: the suite names none)
    """
    versions = {seed.get("recipe_version") for seed in cell["per_seed"]}
    if len(versions) > 1:
        shown = ", ".join(f"seed {seed['seed']}: {seed.get('recipe_version') or 'none recorded'}" for seed in cell["per_seed"])
        raise ValueError(
            f"The {cell['algo']} runs on {cell['env']} ({cell['variant']}) used different recipe versions ({shown}): a "
            "cell reports one recipe. Run the others again with the suite's version, or report them apart (--only)."
        )
    (version,) = versions
    if expected is not None and version != expected:
        seeds = ", ".join(str(seed["seed"]) for seed in cell["per_seed"])
        raise ValueError(
            f"The {cell['algo']} runs on {cell['env']} ({cell['variant']}; seeds {seeds}) used recipe version "
            f"{version or 'none recorded'}, not {expected}, the suite's: it reports its own recipes only. Train them "
            "again with `sb3-icrl benchmark run`, or leave them out (--only)."
        )


def demonstrations_source(run: RunSpec, folder: str | os.PathLike | None = None) -> tuple[str, float | None]:
    """
    The demonstrations a run learned from: the ``demonstrations`` and ``violating_fraction`` of its ``args.yml``
    when the run folder has one, else of its variant settings; by default the env's shipped dataset.

    :param run: The run
    :param folder: Its run folder (``None``: the variant settings only)
    :return: ``(name or path, violating fraction)``, as :func:`sb3_icrl.data.load_demonstrations` takes them
    """
    recorded = _run_args(folder)
    settings: dict[str, Any] = recorded if recorded is not None else dict(run.variant_settings)
    name = settings.get("demonstrations") or env_name(run.env_id)
    fraction = settings.get("violating_fraction")
    return str(name), float(fraction) if isinstance(fraction, (int, float)) and fraction else None


def expert_return(name: str, violating_fraction: float | None = None) -> float | None:
    """
    Mean return (sum of ``rews``) of the trajectories of a demonstration dataset.

    :param name: Shipped dataset name (env name) or path
    :param violating_fraction: The imperfect-expert variant of a shipped dataset
    :return: The mean return; ``None`` when there is no such dataset or it is empty
    """
    try:
        demonstrations = load_demonstrations(name, violating_fraction=violating_fraction)
    except (OSError, ValueError):  # DemonstrationError is a ValueError: no dataset for this env
        return None
    if not len(demonstrations):
        return None
    return float(np.mean([float(np.sum(trajectory.rews)) for trajectory in demonstrations]))


def _expert_return_once(source: tuple[str, float | None], loaded: dict[tuple[str, float | None], float | None]) -> float:
    """:func:`expert_return` of a dataset, loaded once however many runs share it (NaN when there is none)."""
    if source not in loaded:
        loaded[source] = expert_return(*source)
    value = loaded[source]
    return math.nan if value is None else value


def _core_hours(seconds: Sequence[float | None]) -> float | None:
    """Core-hours of runs taking one core each (``None`` when no run's time is known)."""
    known = [value for value in seconds if value is not None]
    return sum(known) / 3600 if known else None


def format_hours(hours: float) -> str:
    """Core-hours for a table: whole hours from 100 on, one decimal from 1, two below."""
    return f"{hours:,.0f}" if hours >= 100 else f"{hours:.1f}" if hours >= 1 else f"{hours:.2f}"


def format_mean_std(mean: float, std: float) -> str:
    """
    ``mean ± std`` of a reward at the precision its size asks for: whole numbers from 100 on, one decimal from 10, two
    below (a Pendulum's 0.46 does not read as 0).
    """
    digits = reward_digits(mean)
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def reward_digits(value: float) -> int:
    """Decimals a reward of this size is shown with: none from 100 on, one from 10, two below."""
    return 0 if abs(value) >= 100 else 1 if abs(value) >= 10 else 2


def format_reward(value: float) -> str:
    """A reward at the precision its size asks for (:func:`reward_digits`)."""
    return f"{value:.{reward_digits(value)}f}"


def format_rate(rate: float) -> str:
    """A published violation rate: whole percents, one decimal below 1% so that 0.004 does not read as 0."""
    return f"{100 * rate:.1f}%" if 0 < 100 * rate < 1 else f"{100 * rate:.0f}%"


def beats(cell: dict[str, Any], pair: Sequence[float] | None) -> bool | None:
    """
    Whether a cell beats a published ``[feasible reward, violation rate]``: a higher mean feasible reward and a mean
    violation rate no higher (a mean equal to it up to float rounding counts as equal). ``None`` without a published
    pair.

    :param cell: A cell of :func:`summarise_suite`
    :param pair: The published numbers
    """
    if pair is None:
        return None
    return bool(cell["feasible_reward_mean"] > pair[0] and cell["violation_rate_mean"] <= pair[1] + 1e-9)


def published_pairs(cell: dict[str, Any]) -> dict[str, Sequence[float]]:
    """``{"paper": pair, source: pair, ...}``: the published numbers of a cell's method on its env."""
    pairs: dict[str, Sequence[float]] = {}
    if cell.get("paper_feasible_reward") is not None:
        pairs["paper"] = (cell["paper_feasible_reward"], cell["paper_violation_rate"])
    pairs.update((cell.get("others") or {}).items())
    return pairs


def _published(pair: Sequence[float] | None) -> str:
    """``reward / violation`` of a published pair, ``-`` without one."""
    return f"{pair[0]:g} / {format_rate(pair[1])}" if pair else "-"


def _fraction_text(cell: dict[str, Any]) -> str:
    fraction = cell.get("feasible_reward_fraction")
    return f"{fraction:.2f} of expert" if fraction is not None else "-"


def _fmt(value: float, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.{digits}f}"


#: The reference rows of a suite: unconstrained PPO (normalised score 0) and PPO-Lagrangian on the true cost, the
#: oracle (normalised score 1)
PPO_ROW, ORACLE_ROW = "ppo", "ppolag"


def spread(values: Sequence[float]) -> dict[str, Any]:
    """
    A cell's centre and interval, labelled for what they are at its number of seeds: from
    :data:`~sb3_icrl.common.statistics.MIN_SEEDS_FOR_INTERVAL` seeds on, the IQM with its 95% bootstrap CI
    (``kind: "iqm"``); below, the mean with the seeds' [min, max] (``kind: "mean"``). NaN values are left out.

    :param values: Per-seed values
    :return: ``{"kind", "centre", "interval", "n"}``
    """
    finite = np.asarray([value for value in values if value is not None and math.isfinite(value)], dtype=float)
    if finite.size == 0:
        return {"kind": "mean", "centre": math.nan, "interval": [math.nan, math.nan], "n": 0}
    if finite.size >= MIN_SEEDS_FOR_INTERVAL:
        return {"kind": "iqm", "centre": iqm(finite), "interval": list(stratified_bootstrap_ci([finite])), "n": finite.size}
    return {
        "kind": "mean",
        "centre": float(finite.mean()),
        "interval": [float(finite.min()), float(finite.max())],
        "n": finite.size,
    }


def format_spread(entry: dict[str, Any] | None, shown: Callable[[float], str] = format_reward) -> str:
    """
    ``IQM c [lo, hi]`` or ``mean c [min, max]`` (:func:`spread`), ``-`` without values.

    :param entry: A :func:`spread`
    :param shown: How a value is written (default: a reward at the precision its size asks for)
    """
    if not entry or not entry["n"]:
        return "-"
    low, high = entry["interval"]
    return f"{'IQM' if entry['kind'] == 'iqm' else 'mean'} {shown(entry['centre'])} [{shown(low)}, {shown(high)}]"


def format_score(value: float) -> str:
    """A normalised score: two decimals."""
    return f"{value:.2f}"


#: The most violations the oracle row may have for its feasible reward to be a score's 1: an oracle that breaks the
#: constraint it was trained on marks no reachable goal, and scores against it would say nothing
ORACLE_MAX_VIOLATION_RATE = 0.05


def oracle_problem(ppo: dict[str, Any], oracle: dict[str, Any]) -> str | None:
    """
    Why the reference rows of an env cannot normalise its scores, or ``None`` when they can: the oracle must keep the
    constraint (mean violation rate at most :data:`ORACLE_MAX_VIOLATION_RATE`) and earn more feasible reward than PPO.

    :param ppo: The env's ``ppo`` cell
    :param oracle: Its ``ppolag`` cell
    """
    if oracle["violation_rate_mean"] > ORACLE_MAX_VIOLATION_RATE + 1e-9:
        return f"the oracle breaks the constraint in {100 * oracle['violation_rate_mean']:.0f}% of episodes"
    if not oracle["feasible_reward_mean"] > ppo["feasible_reward_mean"]:
        return "the oracle earns no more feasible reward than PPO"
    return None


#: The per-seed values :func:`add_reference_scores` derives from the reference rows
SCORE_KEYS = ("normalised_score", "success")


def add_reference_scores(cells: list[dict[str, Any]], success: dict[str, float] | None) -> None:
    """
    Where an env and variant have both reference rows, and the oracle keeps the constraint and earns more feasible
    reward than PPO (:func:`oracle_problem`; otherwise each cell gets ``normalisation_problem`` instead), each of their
    cells' runs gets ``normalised_score`` (:func:`~sb3_icrl.common.statistics.normalised_score` between the two rows'
    mean feasible rewards), each cell ``normalised_score_mean`` and ``normalised_score_spread``; with a ``success`` rule,
    each run ``success`` and each cell ``success_count``, ``success_probability`` and its Wilson 95% interval
    (``success_ci95``). In place. A run's ``normalised_score`` and ``success`` from elsewhere (an earlier report's, read
    back by ``report --update``) are dropped first: they hold only where this report's reference rows give them.

    :param cells: The cells of :func:`summarise_suite`
    :param success: The suite's rule (``max_violation_rate``, ``min_normalised_score``), or ``None``
    """
    for cell in cells:
        for seed in cell["per_seed"]:
            for key in SCORE_KEYS:
                seed.pop(key, None)
    rows = {(cell["env"], cell["variant"], cell["algo"]): cell for cell in cells}
    for cell in cells:
        low = rows.get((cell["env"], cell["variant"], PPO_ROW))
        high = rows.get((cell["env"], cell["variant"], ORACLE_ROW))
        if low is None or high is None:
            continue
        cell["reference_feasible_reward"] = {PPO_ROW: low["feasible_reward_mean"], ORACLE_ROW: high["feasible_reward_mean"]}
        problem = oracle_problem(low, high)
        if problem is not None:
            cell["normalisation_problem"] = problem
            continue
        scores = []
        for seed in cell["per_seed"]:
            seed["normalised_score"] = normalised_score(
                seed["feasible_reward"], low["feasible_reward_mean"], high["feasible_reward_mean"]
            )
            scores.append(seed["normalised_score"])
        finite = [score for score in scores if math.isfinite(score)]
        cell["normalised_score_mean"] = float(np.mean(finite)) if finite else math.nan
        cell["normalised_score_spread"] = spread(scores)
        if success is None or not finite:
            continue
        for seed in cell["per_seed"]:
            seed["success"] = bool(
                seed["violation_rate"] <= success["max_violation_rate"] + 1e-9
                and seed["normalised_score"] >= success["min_normalised_score"]
            )
        count = sum(seed["success"] for seed in cell["per_seed"])
        cell["success_count"] = count
        cell["success_probability"] = count / len(cell["per_seed"])
        cell["success_ci95"] = list(wilson_interval(count, len(cell["per_seed"])))


def aggregated_envs(cells: list[dict[str, Any]], suite: Suite) -> tuple[list[tuple[str, str]], list[dict[str, str]]]:
    """
    The envs and variants the cross-env aggregates, the probabilities of improvement and the performance profile take:
    the headline ones (the suite's ``headline_envs``, else every env) where both reference rows and every method the
    report has cells of have normalised scores. Elsewhere some method (or reference row) has not finished yet, or the
    reference rows give no scores: aggregates over them would average each method over other envs.

    :param cells: The cells, after :func:`add_reference_scores`
    :param suite: The suite (its envs, variants, headline envs and algorithms)
    :return: ``(aggregated, left_out)``: the ``(env, variant)`` taken, in the suite's order, and for each other headline
        one ``{"env", "variant", "reason"}``; both empty for a suite without both reference rows (no scores at all)
    """
    if PPO_ROW not in suite.algos or ORACLE_ROW not in suite.algos:
        return [], []
    rows: dict[tuple[str, str], dict[str, dict[str, Any]]] = {}
    for cell in cells:
        rows.setdefault((cell["env"], cell["variant"]), {})[cell["algo"]] = cell
    # The reference rows, and the methods the report has (a report of some of them: --only)
    algos = [algo for algo in suite.algos if algo in (PPO_ROW, ORACLE_ROW) or any(cell["algo"] == algo for cell in cells)]
    aggregated, left_out = [], []
    for env in (env_name(env_id) for env_id in suite.envs):
        if suite.headline_envs is not None and env not in suite.headline_envs:
            continue
        for variant in suite.variants:
            present = rows.get((env, variant), {})
            # Every method over the same envs: a variant that some of them do not run (its `algos`) is left out
            absent = [algo for algo in algos if algo not in suite.variant_algos(variant)]
            missing = [algo for algo in algos if algo not in present]
            problems = [cell["normalisation_problem"] for cell in present.values() if "normalisation_problem" in cell]
            unscored = [algo for algo in algos if algo in present and "normalised_score_mean" not in present[algo]]
            if absent:
                reason = f"the variant does not run {', '.join(absent)} (its `algos`)"
            elif missing:
                reason = f"no finished run of {', '.join(missing)}"
            elif problems:
                reason = f"no normalised scores: {problems[0]}"
            elif unscored:
                reason = f"no normalised scores of {', '.join(unscored)}"
            else:
                aggregated.append((env, variant))
                continue
            left_out.append({"env": env, "variant": variant, "reason": reason})
    return aggregated, left_out


def normalised_aggregates(
    cells: list[dict[str, Any]], algos: Sequence[str]
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """
    Across envs, per algorithm: the IQM, mean and optimality gap (below 1, the oracle) of the normalised scores with
    stratified bootstrap 95% CIs; and for each pair of algorithms other than the reference rows, the probability of
    improvement with its CI, over the envs both have scores on.

    :param cells: The cells, after :func:`add_reference_scores`
    :param algos: The algorithms, in the suite's order
    :return: ``(aggregates, improvements)``
    """

    def tasks(algo: str) -> dict[tuple[str, str], list[float]]:
        return {
            (cell["env"], cell["variant"]): [
                s["normalised_score"] for s in cell["per_seed"] if math.isfinite(s["normalised_score"])
            ]
            for cell in cells
            if cell["algo"] == algo and "normalised_score_mean" in cell
        }

    by_algo = {algo: tasks(algo) for algo in algos}
    aggregates = []
    for algo, scores in by_algo.items():
        groups = [values for values in scores.values() if values]
        if not groups:
            continue
        flat = np.concatenate(groups)
        # With one run per env every resample is the runs themselves: no interval
        spread_out = any(len(values) > 1 for values in groups)
        aggregates.append(
            {
                "algo": algo,
                "n_cells": len(groups),
                "n_runs": int(flat.size),
                "normalised_score_iqm": iqm(flat),
                "normalised_score_iqm_ci95": list(stratified_bootstrap_ci(groups)) if spread_out else None,
                # rliable's mean: of the per-env means (the flat mean when every env has as many seeds), its
                # interval of the same statistic
                "normalised_score_mean": mean_of_task_means(groups),
                "normalised_score_mean_ci95": list(stratified_bootstrap_ci_of_task_means(groups)) if spread_out else None,
                "optimality_gap": optimality_gap(flat),
                "optimality_gap_ci95": (
                    list(stratified_bootstrap_ci(groups, statistic=optimality_gap)) if spread_out else None
                ),
            }
        )
    methods = [algo for algo in algos if algo not in (PPO_ROW, ORACLE_ROW) and by_algo[algo]]
    improvements = []
    for x in methods:
        for y in methods:
            if x == y:
                continue
            shared = sorted(set(by_algo[x]) & set(by_algo[y]))
            if not shared:
                continue
            xs, ys = [by_algo[x][task] for task in shared], [by_algo[y][task] for task in shared]
            spread_out = any(len(values) > 1 for values in (*xs, *ys))
            improvements.append(
                {
                    "x": x,
                    "y": y,
                    "n_cells": len(shared),
                    "probability": probability_of_improvement(xs, ys),
                    "ci95": list(probability_of_improvement_ci(xs, ys)) if spread_out else None,
                }
            )
    return aggregates, improvements


def summarise_suite(
    suite: Suite,
    runs: Sequence[RunSpec],
    results: Sequence[tuple[RunSpec, RunResult]],
    metrics: dict[str, dict[str, Any]] | None = None,
    model: str = "final",
) -> dict[str, Any]:
    """
    Per cell (env, variant, algorithm): seeds, per-seed values, mean and std, IQM with its 95% bootstrap CI, the
    Wilcoxon test against the suite's reference, the paper's and other sources' numbers (``others``), our expert's
    return (``expert_return``: mean return of the demonstrations the runs learned from) and the feasible reward as a
    fraction of it (``feasible_reward_fraction``), the runs' compute (``core_hours``) and, per published number, whether
    the cell beats it (``beats``: :func:`beats`); per algorithm, the IQM of the violation rate over the headline envs
    with a stratified bootstrap CI (``aggregates``), and the normalised aggregates over the envs of
    :func:`aggregated_envs` (``normalised_aggregates``, ``improvements``; ``aggregated_envs`` and
    ``aggregates_left_out`` name them); the runs not finished yet; the suite's compute. With the suite keys ``beats``
    and ``aim``, also their judgements (``beats_judgement``: :func:`beats_judgement`; ``aim``: :func:`aim_outcome`).

    :param suite: The suite
    :param runs: Its runs (to list the missing ones)
    :param results: ``(run, held-out result)`` of the finished runs
    :param metrics: Per run (``result.run``), identification and transfer columns added to its per-seed values
        (:func:`constraint_metrics`); the cell gets the mean identification AUROC over the seeds that have one.
        Also the run's ``wall_time_s`` and ``expert_return`` (:func:`run_facts`): the cell sums the former into
        ``core_hours`` and averages the latter; a run without an ``expert_return`` there takes the dataset its variant
        settings name
    :param model: Which model of each run ``results`` evaluated (``"final"`` or ``"best"``), recorded as ``model``
    :return: A JSON-ready summary
    """
    metrics = {name: dict(entry) for name, entry in (metrics or {}).items()}  # the caller's stays as it was
    by_cell: dict[tuple[str, str], list[RunResult]] = {}
    returns: dict[tuple[str, float | None], float | None] = {}  # one load per dataset, however many runs share it
    for run, result in results:
        by_cell.setdefault((env_name(run.env_id), run.variant), []).append(result)
        extra = metrics.setdefault(result.run, {})
        if "expert_return" not in extra:
            extra["expert_return"] = _expert_return_once(demonstrations_source(run), returns)
    wall_time = {result.run: metrics[result.run].get("wall_time_s") for _, result in results}
    cells = []
    for (env, variant), cell_results in sorted(by_cell.items()):
        reference = suite.reference if any(r.algo == suite.reference for r in cell_results) else None
        summary = summarise(cell_results, reference=reference)
        for algo, entry in sorted(
            summary.items(), key=lambda item: suite.algos.index(item[0]) if item[0] in suite.algos else 99
        ):
            mine = sorted((r for r in cell_results if r.algo == algo), key=lambda r: r.seed)
            feasible = [r.feasible_reward for r in mine]
            violation = [r.violation_rate for r in mine]
            paper = suite.paper.get(env, {}).get(algo)
            expert = _mean_of([metrics[r.run]["expert_return"] for r in mine])
            feasible_mean = entry.get("feasible_reward_mean")
            cells.append(
                {
                    "env": env,
                    "variant": variant,
                    "algo": algo,
                    "n_seeds": len(mine),
                    "per_seed": [
                        {
                            "seed": r.seed,
                            "feasible_reward": r.feasible_reward,
                            "violation_rate": r.violation_rate,
                            "reward": r.reward,
                            "timesteps": r.timesteps,
                            "n_episodes": r.n_episodes,
                            # A learner that ends its episodes on purpose shows here (null: evaluated before it was kept)
                            "episode_length": r.episode_length,
                            **r.outcome_rates,  # driving envs: how the held-out episodes ended
                            **r.constraint_violation_rates,  # envs with several constraints: each one's
                            **metrics.get(r.run, {}),
                        }
                        for r in mine
                    ],
                    "identification_auroc_mean": _mean_of([metrics.get(r.run, {}).get("identification_auroc") for r in mine]),
                    # The paper's protocol, over the seeds whose Monitor files hold it
                    **{
                        f"{key}_mean": _mean_of([metrics.get(r.run, {}).get(key) for r in mine])
                        for key in LAST_TRAINING_COLUMNS
                    },
                    **{key: value for key, value in entry.items() if key != "seeds"},
                    "feasible_reward_spread": spread(feasible),
                    "violation_rate_spread": spread(violation),
                    # An IQM with a bootstrap interval only where there are seeds enough for one to mean anything
                    **(
                        {
                            "feasible_reward_iqm": iqm(feasible),
                            "feasible_reward_iqm_ci95": list(stratified_bootstrap_ci([feasible])),
                            "violation_rate_iqm": iqm(violation),
                            "violation_rate_iqm_ci95": list(stratified_bootstrap_ci([violation])),
                        }
                        if len(mine) >= MIN_SEEDS_FOR_INTERVAL
                        else {}
                    ),
                    "reference": reference if algo != reference else None,
                    "paper_feasible_reward": paper[0] if paper else None,
                    "paper_violation_rate": paper[1] if paper else None,
                    "others": {
                        source: list(numbers[env][algo])
                        for source, numbers in suite.others.items()
                        if algo in numbers.get(env, {})
                    },
                    "expert_return": expert,
                    # A fraction of a return that is not positive says nothing
                    "feasible_reward_fraction": (
                        feasible_mean / expert
                        if expert is not None and expert > 0 and feasible_mean is not None and math.isfinite(feasible_mean)
                        else None
                    ),
                    "core_hours": _core_hours([wall_time[r.run] for r in mine]),
                }
            )
            check_recipe_versions(cells[-1], suite.recipe_version)
            cells[-1]["recipe_version"] = cells[-1]["per_seed"][0].get("recipe_version")
            # Higher feasible reward and no higher violation rate than each published number of the same method
            cells[-1]["beats"] = {source: beats(cells[-1], pair) for source, pair in published_pairs(cells[-1]).items()}
    add_reference_scores(cells, suite.success)
    for cell in cells:
        cell["headline"] = suite.headline_envs is None or cell["env"] in suite.headline_envs
    aggregated, left_out = aggregated_envs(cells, suite)
    for cell in cells:
        cell["aggregated"] = (cell["env"], cell["variant"]) in aggregated
    normalised, improvements = normalised_aggregates([cell for cell in cells if cell["aggregated"]], suite.algos)
    aggregates = []
    for algo in suite.algos:
        # The headline envs only, as the normalised aggregates
        tasks = [
            [seed["violation_rate"] for seed in cell["per_seed"]]
            for cell in cells
            if cell["algo"] == algo and cell["headline"]
        ]
        if tasks:
            lower, upper = stratified_bootstrap_ci(tasks)
            aggregates.append(
                {
                    "algo": algo,
                    "n_cells": len(tasks),
                    "violation_rate_iqm": iqm(np.concatenate(tasks)),
                    "violation_rate_iqm_ci95": [lower, upper],
                }
            )
    finished = {run for run, _ in results}
    unfinished = [run for run in runs if run not in finished]
    missing = [run.name for run in unfinished]
    # A judgement is final only when every run of its envs in the whole suite is in, whatever part this report takes
    to_come = [run for run in suite.runs() if run not in finished]
    judgements: dict[str, Any] = {}  # the suite's own, only where it writes them: other summaries stay as they were
    if suite.beats is not None:
        judgement = beats_judgement(cells, suite)
        judged = {(env, variant) for env, variant in judgement["tasks"]}
        judgements["beats_judgement"] = {**judgement, "pending_runs": _count_runs(to_come, judged, ICRL_ALGOS)}
    if suite.aim is not None:
        headline = {
            (env_name(env_id), variant)
            for env_id in suite.envs
            for variant in suite.variants
            if suite.headline_envs is None or env_name(env_id) in suite.headline_envs
        }
        judgements["aim"] = aim_outcome(cells, aggregated, left_out, suite)
        judgements["aim"]["pending_runs"] = _count_runs(to_come, headline)
    return {
        "suite": suite.name,
        "model": model,
        "description": suite.description,
        "eval_episodes": suite.eval_episodes,
        "eval_seed": suite.eval_seed,
        "eval_budget": suite.eval_budget,
        "reference": suite.reference,
        "cells": cells,
        "aggregates": aggregates,
        "normalised_aggregates": normalised,
        "improvements": improvements,
        "headline_envs": list(suite.headline_envs) if suite.headline_envs is not None else None,
        "aggregated_envs": [list(task) for task in aggregated],
        "aggregates_left_out": left_out,
        "success_rule": suite.success,
        "runs_missing": missing,
        "runs_missing_by_env": _missing_by_task(suite, [*runs, *(finished - set(runs))], unfinished),
        "others_sources": list(suite.others),
        "core_hours": _core_hours(list(wall_time.values())),
        "core_hours_runs": sum(value is not None for value in wall_time.values()),
        **judgements,
    }


def _count_runs(runs: Sequence[RunSpec], tasks: set[tuple[str, str]], algos: Sequence[str] | None = None) -> int:
    """How many of ``runs`` are on one of ``tasks`` (``(env, variant)``), of one of ``algos`` when given."""
    return sum((env_name(run.env_id), run.variant) in tasks and (algos is None or run.algo in algos) for run in runs)


def _runs_text(count: int) -> str:
    """``1 run``, ``2 runs``."""
    return f"{count} run" + "s" * (count != 1)


def _missing_by_task(suite: Suite, runs: Sequence[RunSpec], unfinished: Sequence[RunSpec]) -> list[list[Any]]:
    """
    ``[env, variant, runs not finished, runs]`` per env and variant with an unfinished run, in the suite's order: of
    ``runs``, the report's runs (finished or not, those an updated report keeps included).
    """
    counts: dict[tuple[str, str], list[int]] = {}
    for env_id in suite.envs:
        for variant in suite.variants:
            counts[(env_name(env_id), variant)] = [0, 0]
    for run in runs:
        counts.setdefault((env_name(run.env_id), run.variant), [0, 0])[1] += 1
    for run in unfinished:
        counts[(env_name(run.env_id), run.variant)][0] += 1
    return [[env, variant, left, total] for (env, variant), (left, total) in counts.items() if left]


def column_pair(cell: dict[str, Any], column: str) -> tuple[float, float] | None:
    """
    A cell's mean ``(feasible reward, violation rate)`` under an evaluation column of :data:`BEATS_COLUMNS`.

    :param cell: A cell of :func:`summarise_suite`
    :param column: ``heldout`` (the held-out episodes of the final models) or ``last_training`` (the last training
        episodes, the paper's protocol)
    :return: The pair; ``None`` when it is missing: for ``last_training``, unless every seed has it (a mean over some
        seeds would judge the cell on fewer runs than its held-out column)
    """
    values: list[list[Any]]
    if column == "heldout":
        values = [[cell.get("feasible_reward_mean")], [cell.get("violation_rate_mean")]]
    else:
        values = [[seed.get(key) for seed in cell["per_seed"]] for key in LAST_TRAINING_COLUMNS]
    if not values[0] or any(value is None or not math.isfinite(value) for column in values for value in column):
        return None
    return float(np.mean(values[0])), float(np.mean(values[1]))


def _all_of(verdicts: Sequence[bool | None]) -> bool | None:
    """``False`` where some verdict is, else ``None`` where some is missing, else ``True``."""
    if any(verdict is False for verdict in verdicts):
        return False
    return None if any(verdict is None for verdict in verdicts) else True


def beats_judgement(cells: list[dict[str, Any]], suite: Suite) -> dict[str, Any]:
    """
    The suite's judgement "beats the paper" (its key ``beats``): each ICRL method's cell on each judged env and variant
    against the paper's row of the method ``against``, under each column named (:func:`column_pair`, :func:`beats`),
    ``None`` where the column's value is missing; a cell beats the row where it does under every column. Each judged
    cell gets ``beats_judgement`` (``{column: verdict, "beats": verdict}``), in place.

    :param cells: The cells of :func:`summarise_suite`
    :param suite: The suite (its ``beats`` rule, ``paper`` numbers, variants and algorithms)
    :return: ``against``, ``columns``, ``paper`` (env -> the row's pair), ``tasks`` (``[env, variant]``), per ICRL method
        (``methods``) its verdicts per task and the tasks it beats the row on (``beaten``), does not (``not_beaten``) and
        that are not decided yet (``undecided``); ``best``, the methods that beat it on the most tasks; ``outcome``:
        ``True`` where some method beats it on every task, ``False`` where every method fails on one, else ``None``
    """
    rule = suite.beats
    assert rule is not None
    rows = {(cell["env"], cell["variant"], cell["algo"]): cell for cell in cells}
    tasks = [(env, variant) for env in rule.envs for variant in suite.variants]
    methods: list[dict[str, Any]] = []
    for algo in (algo for algo in suite.algos if algo in ICRL_ALGOS):
        entries = []
        for env, variant in tasks:
            if algo not in suite.variant_algos(variant):  # a variant it does not run (its `algos`): not judged there
                entries.append({"env": env, "variant": variant, "runs": False})
                continue
            pair = suite.paper[env][rule.against]
            cell = rows.get((env, variant, algo))
            verdicts: dict[str, bool | None] = {
                column: None if cell is None else beats_pair(column_pair(cell, column), pair) for column in rule.columns
            }
            verdicts["beats"] = _all_of(list(verdicts.values()))
            if cell is not None:
                cell["beats_judgement"] = dict(verdicts)
            entries.append({"env": env, "variant": variant, **verdicts})
        judged = [entry for entry in entries if entry.get("runs", True)]
        methods.append(
            {
                "algo": algo,
                "tasks": entries,
                "n_tasks": len(judged),
                **{
                    name: [[entry["env"], entry["variant"]] for entry in judged if entry["beats"] is verdict]
                    for name, verdict in (("beaten", True), ("not_beaten", False), ("undecided", None))
                },
            }
        )
    most = max(len(method["beaten"]) for method in methods)
    everywhere = [method["algo"] for method in methods if method["n_tasks"] and len(method["beaten"]) == method["n_tasks"]]
    return {
        "against": rule.against,
        "columns": list(rule.columns),
        "paper": {env: list(suite.paper[env][rule.against]) for env in rule.envs},
        "tasks": [list(task) for task in tasks],
        "methods": methods,
        "best": [method["algo"] for method in methods if len(method["beaten"]) == most],
        "outcome": True if everywhere else False if all(method["not_beaten"] for method in methods) else None,
    }


def beats_pair(ours: tuple[float, float] | None, pair: Sequence[float]) -> bool | None:
    """:func:`beats` of a ``(feasible reward, violation rate)`` of ours, ``None`` when ours is missing."""
    if ours is None:
        return None
    return beats({"feasible_reward_mean": ours[0], "violation_rate_mean": ours[1]}, pair)


#: Short names of the evaluation columns in the tables
COLUMN_LABELS = {"heldout": "held-out", "last_training": "last training"}


def _verdict_text(verdict: bool | None) -> str:
    return "-" if verdict is None else "yes" if verdict else "no"


def beats_judgement_text(judgement: dict[str, Any]) -> str:
    """
    The judgement "beats the paper" in one plain sentence: the rule, each method's count and the outcome.

    :param judgement: A summary's ``beats_judgement`` (:func:`beats_judgement`)
    """
    n_tasks = len(judgement["tasks"])
    columns = " and ".join(COLUMN_LABELS[column] for column in judgement["columns"])
    envs = ", ".join(_task_text(env, variant) for env, variant in judgement["tasks"])
    parts = []
    for method in judgement["methods"]:
        named = ", ".join(_task_text(env, variant) for env, variant in method["beaten"])
        undecided = len(method["undecided"])
        notes = [named] * bool(named) + [f"{undecided} not decided yet"] * bool(undecided)
        parts.append(
            f"{method['algo'].upper()} on {len(method['beaten'])} of {method.get('n_tasks', n_tasks)}"
            + (f" ({'; '.join(notes)})" if notes else "")
        )
    best = " and ".join(algo.upper() for algo in judgement["best"])
    most = max(len(method["beaten"]) for method in judgement["methods"])
    leader = f"; the most, {most} of {n_tasks}: {best}" if most else ""
    pending = judgement.get("pending_runs", 0)
    # A verdict on seeds still coming is the verdict so far: one more seed can move a mean either way
    so_far = f" so far, {_runs_text(pending)} of the judged envs not finished" if pending else ""
    if judgement["outcome"]:
        outcome = f"{best} on every judged env{so_far}"
    elif judgement["outcome"] is False:
        outcome = f"no method on every judged env{leader}{so_far}"
    else:
        outcome = f"not decided yet, values missing{leader} so far"
    return (
        f"beats the paper's {judgement['against'].upper()} row (a higher mean feasible reward and a mean violation rate no "
        f"higher, under the {columns} columns alike; the suite's `beats`) on {envs}: "
        + "; ".join(parts)
        + f". Outcome: {outcome}."
    )


def beats_judgement_lines(summary: dict[str, Any]) -> list[str]:
    """The judgement "beats the paper" as a Markdown table and its outcome, after a blank line; none without it."""
    judgement = summary.get("beats_judgement")
    if not judgement:
        return []
    columns = judgement["columns"]
    headings = [f"{_task_text(env, variant)} ({_published(judgement['paper'][env])})" for env, variant in judgement["tasks"]]
    lines = [
        "",
        f"Beats the paper, each entry {' / '.join(COLUMN_LABELS[column] for column in columns)} ("
        + "; ".join(f"{COLUMN_LABELS[column]}: {BEATS_COLUMNS[column]}" for column in columns)
        + '; "-": no value yet, a run not finished or a seed without its training episodes):',
        "",
        "| algo | " + " | ".join(headings) + " | envs beaten |",
        "|---" * (len(headings) + 2) + "|",
    ]
    for method in judgement["methods"]:
        entries = [
            " / ".join(_verdict_text(entry[column]) for column in columns) if entry.get("runs", True) else "not run"
            for entry in method["tasks"]
        ]
        judged = method.get("n_tasks", len(judgement["tasks"]))
        lines.append(f"| {method['algo']} | " + " | ".join(entries) + f" | {len(method['beaten'])} of {judged} |")
    text = beats_judgement_text(judgement)
    return [*lines, "", text[0].upper() + text[1:]]


def aim_outcome(
    cells: list[dict[str, Any]], aggregated: list[tuple[str, str]], left_out: list[dict[str, str]], suite: Suite
) -> dict[str, Any]:
    """
    The suite's aim (its key ``aim``): per algorithm, over the envs and variants of the cross-env aggregates
    (:func:`aggregated_envs`), each run's feasible reward over its env's oracle mean (the ``ppolag`` row's mean
    feasible reward there), with its IQM and mean and their stratified bootstrap 95% CIs, beside the violation rate's
    IQM and CI over the same runs (no interval with one run per env, as :func:`normalised_aggregates`); then the best
    ICRL method, the one with the highest IQM of that fraction (the first in the suite's order on a tie), and whether it
    meets the aim. An env whose oracle mean is not positive is left out (a fraction of it says nothing), and said so.

    :param cells: The cells, after :func:`add_reference_scores`
    :param aggregated: The envs and variants of the cross-env aggregates
    :param left_out: The headline ones they leave out, with the reason
    :param suite: The suite (its ``aim`` and algorithms)
    :return: The thresholds, ``envs`` (``[env, variant]`` taken), ``left_out`` (headline ones not taken, with the
        reason), ``oracle_feasible_reward`` (per env taken), ``aggregates`` per algorithm, ``best`` and ``met``
        (``None`` without any env taken)
    """
    aim = suite.aim
    assert aim is not None
    rows = {(cell["env"], cell["variant"], cell["algo"]): cell for cell in cells}
    taken, skipped = [], list(left_out)
    for env, variant in aggregated:
        oracle = rows[(env, variant, ORACLE_ROW)]["feasible_reward_mean"]
        if math.isfinite(oracle) and oracle > 0:
            taken.append((env, variant))
        else:
            reason = f"the oracle's mean feasible reward, {format_reward(oracle)}, is not positive"
            skipped.append({"env": env, "variant": variant, "reason": reason})
    aggregates: list[dict[str, Any]] = []
    for algo in suite.algos:
        fractions, violations = [], []
        for env, variant in taken:
            cell = rows.get((env, variant, algo))
            if cell is None:
                continue
            oracle = rows[(env, variant, ORACLE_ROW)]["feasible_reward_mean"]
            fractions.append([s["feasible_reward"] / oracle for s in cell["per_seed"] if math.isfinite(s["feasible_reward"])])
            violations.append([s["violation_rate"] for s in cell["per_seed"] if math.isfinite(s["violation_rate"])])
        groups = [values for values in fractions if values]
        if not groups:
            continue
        # With one run per env every resample is the runs themselves: no interval
        spread_out = any(len(values) > 1 for values in (*groups, *violations))
        aggregates.append(
            {
                "algo": algo,
                "n_cells": len(groups),
                "n_runs": sum(map(len, groups)),
                "oracle_fraction_iqm": iqm(np.concatenate(groups)),
                "oracle_fraction_iqm_ci95": list(stratified_bootstrap_ci(groups)) if spread_out else None,
                # rliable's mean, as the normalised aggregates': of the per-env means
                "oracle_fraction_mean": mean_of_task_means(groups),
                "oracle_fraction_mean_ci95": list(stratified_bootstrap_ci_of_task_means(groups)) if spread_out else None,
                "violation_rate_iqm": iqm(np.concatenate(violations)),
                "violation_rate_iqm_ci95": list(stratified_bootstrap_ci(violations)) if spread_out else None,
            }
        )
    methods = [entry for entry in aggregates if entry["algo"] in ICRL_ALGOS]
    best = max(methods, key=lambda entry: entry["oracle_fraction_iqm"]) if methods else None  # max keeps the first
    return {
        **aim,
        "envs": [list(task) for task in taken],
        "left_out": skipped,
        "oracle_feasible_reward": [
            [env, variant, rows[(env, variant, ORACLE_ROW)]["feasible_reward_mean"]] for env, variant in taken
        ],
        "aggregates": aggregates,
        "best": best["algo"] if best else None,
        "met": (
            bool(
                best["oracle_fraction_iqm"] >= aim["min_oracle_fraction_iqm"] - 1e-9
                and best["violation_rate_iqm"] <= aim["max_violation_rate_iqm"] + 1e-9
            )
            if best
            else None
        ),
    }


def _percent_interval_text(interval: Sequence[float] | None) -> str:
    """`` [low%, high%]`` of a rate's interval, nothing for one that has none."""
    return f" [{100 * interval[0]:.0f}%, {100 * interval[1]:.0f}%]" if interval is not None else ""


def aim_text(aim: dict[str, Any]) -> str:
    """
    The aim and its outcome in one plain sentence.

    :param aim: A summary's ``aim`` (:func:`aim_outcome`)
    """
    rule = (
        f"the suite's aim: the best ICRL method's feasible reward as a fraction of the oracle's (each run's over the "
        f"{ORACLE_ROW} row's mean on its env), IQM >= {aim['min_oracle_fraction_iqm']:g}, with a violation-rate IQM <= "
        f"{100 * aim['max_violation_rate_iqm']:g}%"
    )
    left_out = "; ".join(f"{_task_text(entry['env'], entry['variant'])} ({entry['reason']})" for entry in aim["left_out"])
    left = f" Left out: {left_out}." if left_out else ""
    best = next((entry for entry in aim["aggregates"] if entry["algo"] == aim["best"]), None)
    if best is None:
        return f"{rule}: not judged yet, no env to judge it on.{left}"
    envs = ", ".join(_task_text(env, variant) for env, variant in aim["envs"])
    failures = []
    if best["oracle_fraction_iqm"] < aim["min_oracle_fraction_iqm"] - 1e-9:
        failures.append(f"its fraction's IQM is below {aim['min_oracle_fraction_iqm']:g}")
    if best["violation_rate_iqm"] > aim["max_violation_rate_iqm"] + 1e-9:
        failures.append(f"its violation-rate IQM is above {100 * aim['max_violation_rate_iqm']:g}%")
    fraction = f"{best['oracle_fraction_iqm']:.2f}{_interval_text(best.get('oracle_fraction_iqm_ci95'))}"
    violation = f"{100 * best['violation_rate_iqm']:.0f}%{_percent_interval_text(best.get('violation_rate_iqm_ci95'))}"
    verdict = "met" if aim["met"] else f"not met, {' and '.join(failures)}"
    pending = aim.get("pending_runs", 0)
    if pending:
        # The envs and seeds still coming can move either IQM: the verdict is provisional until they are in
        verdict += f" so far (provisional: {_runs_text(pending)} of the headline envs not finished)"
    return (
        f"{rule}; over {envs}: the best, {best['algo'].upper()} (highest IQM of that fraction), has {fraction} and a "
        f"violation-rate IQM of {violation}: {verdict}.{left}"
    )


def aim_lines(summary: dict[str, Any]) -> list[str]:
    """The aim: per algorithm its fraction of the oracle's feasible reward and violation rate, then the outcome."""
    aim = summary.get("aim")
    if not aim:
        return []
    lines = []
    if aim["aggregates"]:
        lines += [
            "",
            "Feasible reward as a fraction of the oracle's, F / F_oracle per run (stratified bootstrap 95% CIs over the "
            "seeds of each env):",
            "",
            "| algo | envs | runs | F / F_oracle IQM | mean | violation rate IQM |",
            "|---|---|---|---|---|---|",
        ]
        for entry in aim["aggregates"]:
            lines.append(
                f"| {entry['algo']} | {entry['n_cells']} | {entry['n_runs']} | {entry['oracle_fraction_iqm']:.2f}"
                f"{_interval_text(entry.get('oracle_fraction_iqm_ci95'))} | {entry['oracle_fraction_mean']:.2f}"
                f"{_interval_text(entry.get('oracle_fraction_mean_ci95'))} | {100 * entry['violation_rate_iqm']:.0f}%"
                f"{_percent_interval_text(entry.get('violation_rate_iqm_ci95'))} |"
            )
        if any(entry.get("oracle_fraction_iqm_ci95") is None for entry in aim["aggregates"]):
            lines += ["", "A value without [95% CI]: no interval: one run per env (the bootstrap would draw the same runs)."]
    text = aim_text(aim)
    return [*lines, "", text[0].upper() + text[1:]]


def compute_line(summary: dict[str, Any]) -> str | None:
    """``Compute: N core-hours over M runs`` (runs with a recorded wall time), ``None`` without any."""
    if summary.get("core_hours") is None:
        return None
    return f"Compute: {format_hours(summary['core_hours'])} core-hours over {summary.get('core_hours_runs', 0)} runs"


def other_sources(summary: dict[str, Any]) -> list[str]:
    """The other sources of a summary, in the suite's order (a summary's cells may name them only)."""
    sources = list(summary.get("others_sources") or [])
    for cell in summary["cells"]:
        sources += [source for source in cell.get("others") or {} if source not in sources]
    return sources


#: Under a report of best models: what they are
BEST_MODELS_NOTE = (
    "Models: each run's `best_model.zip`, chosen during training by its algorithm's selection score (for the ICRL "
    "methods learned quantities only, never the true constraint), with the normalisation statistics saved with it; "
    "not the final model."
)


def markdown_table(summary: dict[str, Any]) -> str:
    """
    The cells as a Markdown table: ours (mean ± sample std, and IQM [95% CI] from 5 seeds on or mean [min, max] below,
    fraction of our expert's return; with the reference rows, the normalised score and the success probability with its
    Wilson interval) beside the paper's and other sources', per-seed values visible, a Wilcoxon column only where some
    cell has 6 pairs or more; then the cross-env aggregates and the compute line.
    """
    sources = other_sources(summary)
    cells = summary["cells"]
    normalised = any("normalised_score_spread" in cell or "normalisation_problem" in cell for cell in cells)
    success = any("success_probability" in cell for cell in cells)
    wilcoxon = any((cell.get("wilcoxon_pairs") or 0) >= MIN_PAIRS_FOR_WILCOXON for cell in cells)
    last_training = any(cell.get("last_training_feasible_reward_mean") is not None for cell in cells)
    headings = ["env", "variant", "algo", "seeds", "feasible reward (mean ± std)", "IQM [95% CI] or mean [min, max]"]
    headings += ["normalised score"] * normalised + ["success [Wilson 95%]"] * success
    headings += ["vs our expert", "violation rate"] + ["Wilcoxon p"] * wilcoxon
    headings += [f"last {LAST_TRAINING_EPISODES} training episodes (feasible / violation)"] * last_training
    headings += ["paper", *sources]
    headings += [
        "per seed (feasible / violation" + (" / normalised" if normalised else "") + ")",
        "identification per seed (AUROC / threshold error)",
        "transfer per seed (violation / feasible reward ÷ oracle's)",
        "core-hours",
    ]
    lines = ["| " + " | ".join(headings) + " |", "|---" * len(headings) + "|"]
    for cell in cells:
        paper = (
            f"{cell['paper_feasible_reward']:g} / {100 * cell['paper_violation_rate']:.0f}%"
            if cell["paper_feasible_reward"] is not None
            else "-"
        )
        per_seed = ", ".join(
            f"{s['seed']}: {format_reward(s['feasible_reward'])} / {100 * s['violation_rate']:.0f}%"
            + (f" / {_fmt(s['normalised_score'], 2)}" if "normalised_score" in s else "")
            for s in cell["per_seed"]
        )
        identification = ", ".join(f"{s['seed']}: {_identification_text(s)}" for s in cell["per_seed"])
        transfer = ", ".join(f"{s['seed']}: {_transfer_text(s)}" for s in cell["per_seed"] if _transfer_text(s) != "-")
        hours = cell.get("core_hours")
        pairs = cell.get("wilcoxon_pairs") or 0
        p_value = cell.get("wilcoxon_p") if pairs >= MIN_PAIRS_FOR_WILCOXON else None
        # † marks an env outside the headline aggregates (the suite's headline_envs)
        row = [cell["env"] + ("" if cell.get("headline", True) else " †"), cell["variant"], cell["algo"], str(cell["n_seeds"])]
        row += [f"{_fmt(cell['feasible_reward_mean'])} ± {_fmt(cell['feasible_reward_std'])}"]
        row += [format_spread(cell.get("feasible_reward_spread") or spread([s["feasible_reward"] for s in cell["per_seed"]]))]
        if normalised:
            problem = cell.get("normalisation_problem")
            row.append(f"none: {problem}" if problem else format_spread(cell.get("normalised_score_spread"), format_score))
        if success:
            row.append(_success_text(cell))
        row += [
            _fraction_text(cell),
            f"{100 * cell['violation_rate_mean']:.0f}% ± {_fmt(100 * cell['violation_rate_std'], 0)}%",
        ]
        if wilcoxon:
            row.append(_fmt(p_value, 3) if p_value is not None else "-")
        if last_training:
            row.append(_last_training_text(cell))
        row += [paper, *(_published((cell.get("others") or {}).get(source)) for source in sources), per_seed]
        row += [identification if any("identification_auroc" in s for s in cell["per_seed"]) else "-", transfer or "-"]
        row.append(format_hours(hours) if hours is not None else "-")
        lines.append("| " + " | ".join(row) + " |")
    lines += aggregate_lines(summary)
    lines += beats_judgement_lines(summary)
    lines += aim_lines(summary)
    lines += constraint_lines(summary)
    lines += outcome_lines(summary)
    if summary.get("model") == "best":
        lines += ["", BEST_MODELS_NOTE]
    if summary["runs_missing"]:
        lines += ["", not_finished_text(summary)]
    compute = compute_line(summary)
    if compute is not None:
        lines += ["", compute]
    return "\n".join(lines) + "\n"


#: Up to this many unfinished runs are named one by one; more are counted per env
MAX_MISSING_NAMED = 12


def not_finished_text(summary: dict[str, Any]) -> str:
    """
    The runs not finished yet: named when there are few (:data:`MAX_MISSING_NAMED`), else counted per env and variant
    (the summary's ``runs_missing`` still names them all).

    :param summary: A summary of :func:`summarise_suite`
    """
    missing, by_task = summary["runs_missing"], summary.get("runs_missing_by_env")
    if len(missing) <= MAX_MISSING_NAMED or not by_task:
        return f"Not finished yet ({len(missing)}): " + ", ".join(missing)
    counts = "; ".join(f"{_task_text(env, variant)} {left} of {total}" for env, variant, left, total in by_task)
    return f"Not finished yet ({len(missing)} runs, all named in summary.json's `runs_missing`): {counts}."


def _last_training_text(cell: dict[str, Any]) -> str:
    """The paper's protocol: mean over seeds of the last training episodes' feasible reward and violation rate."""
    feasible, violation = cell.get("last_training_feasible_reward_mean"), cell.get("last_training_violation_rate_mean")
    if feasible is None or violation is None:
        return "-"
    return f"{format_reward(feasible)} / {100 * violation:.0f}%"


def _success_text(cell: dict[str, Any]) -> str:
    if "success_probability" not in cell:
        return "-"
    low, high = cell["success_ci95"]
    return f"{cell['success_count']}/{cell['n_seeds']} [{low:.2f}, {high:.2f}]"


def aggregate_lines(summary: dict[str, Any]) -> list[str]:
    """
    The cross-env aggregates of the normalised score (IQM, mean, optimality gap, each with its stratified bootstrap 95%
    CI) and the probabilities of improvement between methods, as Markdown lines after a blank line; none without
    reference rows.
    """
    aggregates = summary.get("normalised_aggregates") or []
    if not aggregates:
        left_out = summary.get("aggregates_left_out") or []
        reasons = "; ".join(f"{_task_text(entry['env'], entry['variant'])} ({entry['reason']})" for entry in left_out)
        return ["", f"No cross-env aggregates yet: {reasons}."] if left_out else []
    rule = summary.get("success_rule")
    lines = [
        "",
        "Normalised score: (F - F_ppo) / (F_oracle - F_ppo) per run, with the mean feasible rewards of unconstrained PPO "
        "(0) and PPO-Lagrangian on the true cost (1) on the same env and variant."
        + (
            f" Success: violation rate <= {100 * rule['max_violation_rate']:g}% and normalised score >= "
            f"{rule['min_normalised_score']:g}, with the Wilson 95% interval of its probability."
            if rule
            else ""
        ),
        "",
        "Across envs (stratified bootstrap 95% CIs over the seeds of each env)" + _aggregated_text(summary),
        "",
        "| algo | envs | runs | IQM | mean | optimality gap |",
        "|---|---|---|---|---|---|",
    ]
    for entry in aggregates:
        cells = [
            f"{entry[key]:.2f}{_interval_text(entry.get(key + '_ci95'))}"
            for key in ("normalised_score_iqm", "normalised_score_mean", "optimality_gap")
        ]
        lines.append(f"| {entry['algo']} | {entry['n_cells']} | {entry['n_runs']} | " + " | ".join(cells) + " |")
    improvements = summary.get("improvements") or []
    if improvements:
        lines += ["", "Probability of improvement, P(X > Y) on the normalised score:", ""]
        lines += ["| X | Y | envs | P(X > Y) [95% CI] |", "|---|---|---|---|"]
        for entry in improvements:
            lines.append(
                f"| {entry['x']} | {entry['y']} | {entry['n_cells']} | {entry['probability']:.2f}"
                f"{_interval_text(entry.get('ci95'))} |"
            )
    if any(entry.get("normalised_score_iqm_ci95") is None for entry in aggregates):
        lines += ["", "A value without [95% CI]: no interval: one run per env (the bootstrap would draw the same runs)."]
    return lines


def _interval_text(interval: Sequence[float] | None) -> str:
    """`` [low, high]`` of an aggregate's interval, nothing for one that has none (one run per env)."""
    return f" [{interval[0]:.2f}, {interval[1]:.2f}]" if interval is not None else ""


def _aggregated_text(summary: dict[str, Any]) -> str:
    """What the cross-env aggregates of a summary take (:func:`aggregated_envs`) and leave out, ending the line that
    introduces them; for a summary written before they were recorded, its headline envs."""
    headline = summary.get("headline_envs")
    chosen = (
        f"the headline envs only ({', '.join(headline)}; the others, marked † in the table, do not bind or cannot be "
        "identified)"
        if headline
        else "the envs"
    )
    if "aggregated_envs" not in summary:
        return f", {chosen}:" if headline else ":"
    taken = ", ".join(_task_text(env, variant) for env, variant in summary["aggregated_envs"])
    text = f", over {taken}: {chosen} where every row has normalised scores."
    left_out = summary.get("aggregates_left_out") or []
    if left_out:
        reasons = "; ".join(f"{_task_text(entry['env'], entry['variant'])} ({entry['reason']})" for entry in left_out)
        text += f" Left out of them: {reasons}."
    return text


def _task_text(env: str, variant: str) -> str:
    """An env, with its variant when it is not the base one."""
    return env if variant == "base" else f"{env} ({variant})"


#: The per-seed keys of the driving outcome rates, in :data:`OUTCOME_KEYS` order
OUTCOME_COLUMNS = tuple(OUTCOME_RATE_KEYS[key] for key in OUTCOME_KEYS)


def constraint_columns(summary: dict[str, Any]) -> list[str]:
    """The per-seed keys of each constraint's violation rate in a summary, in the order the cells first give them."""
    columns: list[str] = []
    for cell in summary["cells"]:
        for seed in cell["per_seed"]:
            columns += [key for key in seed if key.startswith(CONSTRAINT_VIOLATION_PREFIX) and key not in columns]
    return columns


def constraint_lines(summary: dict[str, Any]) -> list[str]:
    """
    For the cells of envs with several constraints: each constraint's violation rate beside the overall one (an
    episode that breaks any) and the feasible reward, mean over seeds and per seed, as Markdown lines after a blank
    line; no lines for a summary without such cells.
    """
    cells = [cell for cell in summary["cells"] if len(cell.get("constraint_violation_rates_mean") or {}) > 1]
    if not cells:
        return []
    columns = [column for column in constraint_columns(summary) if any(column in cell["per_seed"][0] for cell in cells)]
    names = [column.removeprefix(CONSTRAINT_VIOLATION_PREFIX) for column in columns]
    heading = (
        "Each constraint's violation rate (envs with several constraints; mean over seeds, then per seed; an episode "
        "that breaks two counts in both, and once in the overall rate):"
    )
    lines = ["", heading, ""]
    lines += [
        f"| env | variant | algo | feasible reward | violation rate (any) | {' | '.join(names)} "
        f"| per seed (any / {' / '.join(names)}) |",
        "|---" * (6 + len(names)) + "|",
    ]
    for cell in cells:
        means = cell["constraint_violation_rates_mean"]
        row = " | ".join(format_outcome_rate(means.get(column)) for column in columns)
        per_seed = ", ".join(
            f"{seed['seed']}: " + " / ".join(format_outcome_rate(seed.get(column)) for column in ("violation_rate", *columns))
            for seed in cell["per_seed"]
        )
        lines.append(
            f"| {cell['env']} | {cell['variant']} | {cell['algo']} | {_fmt(cell['feasible_reward_mean'])} "
            f"| {format_outcome_rate(cell['violation_rate_mean'])} | {row} | {per_seed} |"
        )
    return lines


def outcome_lines(summary: dict[str, Any]) -> list[str]:
    """
    For the cells of driving envs: how their held-out episodes ended (collision, off road, time out, goal reached),
    mean over seeds and per seed, as Markdown lines after a blank line; no lines for a summary without such cells.
    """
    cells = [cell for cell in summary["cells"] if cell.get("outcome_rates_mean")]
    if not cells:
        return []
    titles = [OUTCOME_TITLES[key] for key in OUTCOME_KEYS]
    # Not a partition: an episode can end both in a collision and off the road
    heading = (
        "How the held-out episodes ended (driving envs; mean over seeds, then per seed; a collision off the road "
        "counts twice):"
    )
    lines = ["", heading, ""]
    lines += [
        f"| env | variant | algo | {' | '.join(titles)} | per seed ({' / '.join(titles)}) |",
        "|---" * (4 + len(titles)) + "|",
    ]
    for cell in cells:
        means = cell["outcome_rates_mean"]
        per_seed = ", ".join(
            f"{seed['seed']}: " + " / ".join(format_outcome_rate(seed.get(column)) for column in OUTCOME_COLUMNS)
            for seed in cell["per_seed"]
        )
        row = " | ".join(format_outcome_rate(means.get(column)) for column in OUTCOME_COLUMNS)
        lines.append(f"| {cell['env']} | {cell['variant']} | {cell['algo']} | {row} | {per_seed} |")
    return lines


def latex_table(summary: dict[str, Any]) -> str:
    """
    The cells as a LaTeX ``tabular`` (booktabs): feasible reward (mean ± std, fraction of our expert's return) and
    violation rate, and the paper's and other sources' numbers.
    """
    sources = other_sources(summary)
    # Source names are free text: escape what LaTeX reads as markup (underscores are escaped below, for all cells)
    names = [source.replace("&", "\\&").replace("%", "\\%").replace("#", "\\#") for source in sources]
    rows = [
        "\\begin{tabular}{lllrrrrr" + "rr" * len(sources) + "}",
        "\\toprule",
        "Env & Variant & Method & Feasible reward & Of expert & Violation rate & Paper reward & Paper violation"
        + "".join(f" & {name} reward & {name} violation" for name in names)
        + " \\\\",
        "\\midrule",
    ]
    for cell in summary["cells"]:
        paper_reward = _fmt(cell["paper_feasible_reward"], 2) if cell["paper_feasible_reward"] is not None else "--"
        paper_violation = f"{100 * cell['paper_violation_rate']:.0f}\\%" if cell["paper_violation_rate"] is not None else "--"
        others = ""
        for source in sources:
            pair = (cell.get("others") or {}).get(source)
            percent = format_rate(pair[1]).replace("%", "\\%") if pair else ""
            others += f" & {pair[0]:g} & {percent}" if pair else " & -- & --"
        fraction = cell.get("feasible_reward_fraction")
        rows.append(
            f"{cell['env']} & {cell['variant']} & {cell['algo'].upper()} & "
            f"${_fmt(cell['feasible_reward_mean'])} \\pm {_fmt(cell['feasible_reward_std'])}$ & "
            f"{_fmt(fraction, 2) if fraction is not None else '--'} & "
            f"${100 * cell['violation_rate_mean']:.0f}\\% \\pm {100 * cell['violation_rate_std']:.0f}\\%$ & "
            f"{paper_reward} & {paper_violation}{others} \\\\"
        )
    rows += ["\\bottomrule", "\\end{tabular}"]
    return "\n".join(rows).replace("_", "\\_") + "\n"


def csv_rows(summary: dict[str, Any]) -> str:
    """
    One row per run: cell, seed, held-out values, training time; then the cell's expert return and published numbers
    (paper, other sources), repeated on each of its rows.
    """
    sources = other_sources(summary)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    header = ["env", "variant", "algo", "seed", "feasible_reward", "violation_rate", "reward", "timesteps", "n_episodes"]
    header.append("episode_length")
    per_constraint = constraint_columns(summary)  # none for suites without such envs
    published = ["paper_feasible_reward", "paper_violation_rate"]
    for source in sources:
        published += [f"{source}_feasible_reward", f"{source}_violation_rate"]
    writer.writerow(
        [
            *header,
            *OUTCOME_COLUMNS,
            *per_constraint,
            *IDENTIFICATION_COLUMNS,
            *TRANSFER_COLUMNS,
            *LAST_TRAINING_COLUMNS,
            "wall_time_s",
            "training_starts",
            "git_revision",
            "expert_return",
            *published,
        ]
    )
    for cell in summary["cells"]:
        numbers = [cell.get("paper_feasible_reward"), cell.get("paper_violation_rate")]
        for source in sources:
            numbers += list((cell.get("others") or {}).get(source) or ["", ""])
        for seed in cell["per_seed"]:
            writer.writerow(
                [
                    cell["env"],
                    cell["variant"],
                    cell["algo"],
                    seed["seed"],
                    seed["feasible_reward"],
                    seed["violation_rate"],
                    seed["reward"],
                    seed["timesteps"],
                    seed["n_episodes"],
                    _csv_number(seed.get("episode_length")),
                    *(_csv_number(seed.get(column)) for column in (*OUTCOME_COLUMNS, *per_constraint)),
                    *(seed.get(column, "") for column in (*IDENTIFICATION_COLUMNS, *TRANSFER_COLUMNS, *LAST_TRAINING_COLUMNS)),
                    seed.get("wall_time_s", ""),
                    seed.get("training_starts", ""),
                    seed.get("git_revision", ""),
                    *("" if value is None else value for value in (cell.get("expert_return"), *numbers)),
                ]
            )
    return buffer.getvalue()


def _csv_number(value: float | None) -> Any:
    """A number for the CSV, empty when it is unknown (``None`` or NaN)."""
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else value


def finite_or_null(value: Any) -> Any:
    """
    A copy of a JSON-like value with every NaN or infinite float replaced by ``None``, so that strict JSON readers
    can read it (a threshold error is infinite when the learned cost never crosses the threshold: the run's own
    ``identification.json`` keeps the value and the reason).

    :param value: Nested dicts, lists, tuples and scalars
    :return: The same structure, with ``null`` where a float was not finite
    """
    if isinstance(value, dict):
        return {key: finite_or_null(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_report(summary: dict[str, Any], output: str) -> list[str]:
    """
    Write ``summary.json`` (strict JSON: non-finite floats become ``null``), ``table.md``, ``runs.csv`` and
    ``table.tex`` to ``output`` (atomically).

    :return: The paths written
    """
    paths = {
        "summary.json": json.dumps(finite_or_null(summary), indent=2, sort_keys=True, allow_nan=False) + "\n",
        "table.md": markdown_table(summary),
        "runs.csv": csv_rows(summary),
        "table.tex": latex_table(summary),
    }
    written = []
    for name, text in paths.items():
        path = os.path.join(output, name)
        atomic_write_bytes(path, text.encode())
        written.append(path)
    return written


#: Per run of a report, what its figures draw (training curves, learned-cost curves): kept in the report folder, so
#: that a report updated once the earlier runs' folders are gone (another machine) still draws them
FIGURE_DATA_FILE = "figure_data.json"
#: The ``evaluations.npz`` arrays a report's training curves read (their mean over each evaluation's episodes)
_CURVE_KEYS = ("violations", "feasible_rewards", "results")


def run_figure_data(run: RunSpec, root: str, model: str = "final") -> dict[str, Any]:
    """
    What a report's figures draw of one run, read from its folder: ``curves`` (evaluation timesteps and, per
    evaluation, the mean over its episodes of each of :data:`_CURVE_KEYS`) and ``learned_cost`` (its cached
    identification's :func:`~sb3_icrl.metrics.identification.learned_cost_curves`, for the report's model).

    :param run: The run
    :param root: The log root
    :param model: ``"final"`` or ``"best"``
    :return: Those of the two the folder has (an empty dict when it has neither)
    """
    folder = run.run_folder(root)
    data: dict[str, Any] = {}
    try:
        arrays = load_evaluations(folder)
        curves = {"timesteps": np.asarray(arrays["timesteps"], dtype=float).tolist()}
        for key in _CURVE_KEYS:
            if key in arrays:
                values = np.asarray(arrays[key], dtype=float)
                curves[key] = values.reshape(len(values), -1).mean(axis=1).tolist()
        if curves["timesteps"]:
            data["curves"] = curves
    except (FileNotFoundError, ValueError):  # no folder, not evaluated, or a damaged file: no curve
        pass
    cache = os.path.join(folder, identification_file(model))
    if os.path.isfile(cache):
        try:
            with open(cache) as file:
                data["learned_cost"] = learned_cost_curves(json.load(file))
        except (OSError, ValueError, KeyError, TypeError):  # a cache cut short or of another layout: no curve
            pass
    return data


def summary_run(suite: Suite, cell: dict[str, Any], seed: dict[str, Any]) -> RunSpec:
    """The run of one seed of a summary's cell (its name and folder; steps are not known there: 0)."""
    return RunSpec(suite.name, cell["variant"], cell["algo"], cell["env"], int(seed["seed"]), 0)


def figure_data(summary: dict[str, Any], suite: Suite, root: str, output: str) -> dict[str, dict[str, Any]]:
    """
    Per run of the summary (by name), what its figures draw: read from its folder where it has one, else kept from
    the report already in ``output`` (``report --update`` of runs trained elsewhere).

    :return: ``{run name: run_figure_data(...)}``, runs with nothing to draw left out
    """
    model = summary.get("model", "final")
    earlier: dict[str, Any] = {}
    path = os.path.join(output, FIGURE_DATA_FILE)
    if os.path.isfile(path):
        try:
            with open(path) as file:
                content = json.load(file)
            # (another suite's or model's file in the same folder draws nothing here)
            if content.get("suite") == suite.name and content.get("model", "final") == model:
                earlier = dict(content.get("runs", {}))
        except (OSError, ValueError, AttributeError):  # unreadable: the runs with folders are drawn, the others not
            earlier = {}
    data: dict[str, dict[str, Any]] = {}
    for cell in summary["cells"]:
        for seed in cell["per_seed"]:
            run = summary_run(suite, cell, seed)
            # A folder whose run is not finished (trained again since the summary's result) draws nothing of it
            fresh = run_figure_data(run, root, model) if is_finished(run.run_folder(root)) else {}
            entry = {**(earlier.get(run.name) or {}), **fresh}
            if entry:
                data[run.name] = entry
    return data


def _partial(
    summary: dict[str, Any], env: str, variant: str, drawn: Collection[str], candidates: Collection[str] | None = None
) -> str:
    """
    ``", curves of mecl, vicrl only"`` in a figure's title when it draws only some of the env and variant's methods
    (of ``candidates``, default all: a learned-cost figure has none of the reference rows to draw).
    """
    algos = [
        cell["algo"]
        for cell in summary["cells"]
        if (cell["env"], cell["variant"]) == (env_name(env), variant) and (candidates is None or cell["algo"] in candidates)
    ]
    shown = [algo for algo in algos if algo in drawn]
    return "" if len(shown) == len(algos) else f", curves of {', '.join(shown)} only"


def constraint_figures(summary: dict[str, Any], suite: Suite, output: str, data: dict[str, dict[str, Any]]) -> list[str]:
    """
    Per env and variant: each method's learned cost over the constrained feature, one line per seed, the true threshold
    marked (:func:`~sb3_icrl.metrics.identification.learned_cost_figure`), for the runs the report scored.
    Written as ``constraint_<EnvName>_<variant>.png``; none for envs whose constraint is not a threshold on a feature
    (the grid worlds), and none where no scored run has its curve (the figure already there stays).

    :param data: :func:`figure_data`
    :return: The paths written
    """
    runs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for cell in summary["cells"]:
        for seed in cell["per_seed"]:
            name = summary_run(suite, cell, seed).name
            if "identification_auroc" in seed and "learned_cost" in data.get(name, {}):
                runs.setdefault((cell["env"], cell["variant"]), []).append(data[name]["learned_cost"])
    written = []
    suffix = " (best models)" if summary.get("model", "final") == "best" else ""
    for (env_id, variant), curves in runs.items():
        drawn = {str(curve["algo"]) for curve in curves}
        title = f"{env_name(env_id)} ({variant}{_partial(summary, env_id, variant, drawn, ICRL_ALGOS)}): learned cost{suffix}"
        try:
            figure = learned_cost_figure(curves, title=title)
        except ValueError:  # no feature threshold to draw against
            continue
        written.append(str(save_figure(figure, os.path.join(output, f"constraint_{env_name(env_id)}_{variant}.png"))))
    return written


def write_figures(summary: dict[str, Any], suite: Suite, root: str, output: str) -> list[str]:
    """
    Per env and variant: training curves (mean +- std over the seeds of each method, from their ``evaluations.npz``)
    and each method's learned cost over the constrained feature (:func:`constraint_figures`); per suite: ours against
    the paper, cell by cell. PNG files in ``output``, with the data they draw in :data:`FIGURE_DATA_FILE`: a report
    updated where some runs' folders are gone draws them from it.

    :return: The paths written
    """
    data = figure_data(summary, suite, root, output)
    path = os.path.join(output, FIGURE_DATA_FILE)
    # (strict JSON, as summary.json: a non-finite value is written null and read back as NaN)
    kept = {"suite": suite.name, "model": summary.get("model", "final"), "runs": data}
    atomic_write_json(path, finite_or_null(kept), sort_keys=True, allow_nan=False)
    written = [path]
    # Per env and variant, each method's seeds with curves
    by_task: dict[tuple[str, str], dict[str, list[dict[str, np.ndarray]]]] = {}
    for cell in summary["cells"]:
        for seed in cell["per_seed"]:
            curves = data.get(summary_run(suite, cell, seed).name, {}).get("curves")
            if curves is not None:
                arrays = {key: np.asarray(values, dtype=float) for key, values in curves.items()}
                by_task.setdefault((cell["env"], cell["variant"]), {}).setdefault(cell["algo"], []).append(arrays)
    for env_id in suite.envs:
        for variant in suite.variants:
            runs = by_task.get((env_name(env_id), variant))
            if not runs:  # nothing to draw: the figure already there, if any, stays
                continue
            title = f"{env_name(env_id)} ({variant}{_partial(summary, env_id, variant, runs)})"
            try:
                figure = training_curves_figure({algo.upper(): seeds for algo, seeds in runs.items()}, title=title)
            except ValueError:
                continue
            written.append(str(save_figure(figure, os.path.join(output, f"curves_{env_name(env_id)}_{variant}.png"))))
    written += constraint_figures(summary, suite, output, data)
    compared = [cell for cell in summary["cells"] if cell["paper_feasible_reward"] is not None]
    if compared:
        figure = new_figure(width=max(6.4, 0.5 * len(compared)), height=4.8)
        axes = figure.subplots(1, 2)
        labels = [f"{cell['env'].split('-')[0]}\n{cell['algo']}" for cell in compared]
        positions = np.arange(len(compared))
        for ax, key, title in (
            (axes[0], "feasible_reward", "feasible reward / paper's"),
            (axes[1], "violation_rate", "violation rate"),
        ):
            if key == "feasible_reward":
                ours = [
                    cell["feasible_reward_mean"] / cell["paper_feasible_reward"] if cell["paper_feasible_reward"] else np.nan
                    for cell in compared
                ]
                ax.bar(positions, ours, color="tab:blue", label="ours / paper")
                ax.axhline(1.0, color="black", linewidth=0.8)
            else:
                ax.bar(positions - 0.2, [cell["violation_rate_mean"] for cell in compared], width=0.4, label="ours")
                ax.bar(positions + 0.2, [cell["paper_violation_rate"] for cell in compared], width=0.4, label="paper")
            ax.set_xticks(positions, labels, rotation=90, fontsize=7)
            ax.set_title(title)
            ax.legend(fontsize=7)
        figure.tight_layout()
        written.append(str(save_figure(figure, os.path.join(output, "ours_vs_paper.png"))))
    profile = performance_profile_figure(summary)
    if profile is not None:
        written.append(str(save_figure(profile, os.path.join(output, "performance_profile.png"))))
    axis = study_axis(suite)
    if axis is not None:
        study = study_figure(summary, *axis)
        if study is not None:
            written.append(str(save_figure(study, os.path.join(output, "study.png"))))
    return written


#: The variant settings a study varies, with the axis label of its figure (the noise on a log scale)
STUDY_AXES = {
    "transition_noise": "transition noise sigma",
    "violating_fraction": "share of violating demonstrations",
}


def study_axis(suite: Suite) -> tuple[str, dict[str, float]] | None:
    """
    The setting a study's variants vary (:data:`STUDY_AXES`) and each variant's level, when every variant of the
    suite (two at least) sets it to a number; ``None`` for a suite that is not such a study.
    """
    if len(suite.variants) < 2:
        return None
    for key in STUDY_AXES:
        levels = {variant: settings.get(key) for variant, settings in suite.variants.items()}
        if all(isinstance(level, (int, float)) and not isinstance(level, bool) for level in levels.values()):
            return key, {variant: float(level) for variant, level in levels.items()}  # type: ignore[arg-type]
    return None


def study_figure(summary: dict[str, Any], key: str, levels: dict[str, float]) -> Any:
    """
    The paper's study figure from ours: one column per env, the violation rate (top) and the feasible reward (bottom)
    of each method against the study's level (:func:`study_axis`), its mean over seeds joined by a line and each
    seed's value a dot; ``None`` when the summary has no cell of those variants.

    :param summary: A summary of :func:`summarise_suite`
    :param key: The setting varied (a key of :data:`STUDY_AXES`)
    :param levels: Each variant's level
    """
    cells = [cell for cell in summary["cells"] if cell["variant"] in levels]
    if not cells:
        return None
    envs = list(dict.fromkeys(cell["env"] for cell in cells))
    algos = list(dict.fromkeys(cell["algo"] for cell in cells))
    figure = new_figure(width=max(4.8, 3.6 * len(envs)), height=6.4)
    axes = np.asarray(figure.subplots(2, len(envs), squeeze=False))
    colours = {algo: f"C{index % 10}" for index, algo in enumerate(algos)}
    # Noise levels a decade apart: a log axis; a level of 0 (no noise) needs the linear stretch of a symlog one
    scale: dict[str, Any] = {}
    if key == "transition_noise":
        positive = [level for level in levels.values() if level > 0]
        scale = (
            {"value": "log"} if len(positive) == len(levels) else {"value": "symlog", "linthresh": min(positive, default=1.0)}
        )
    for column, env in enumerate(envs):
        for row, (metric, title) in enumerate((("violation_rate", "violation rate"), ("feasible_reward", "feasible reward"))):
            ax = axes[row, column]
            for algo in algos:
                mine = sorted(
                    ((levels[cell["variant"]], cell) for cell in cells if cell["env"] == env and cell["algo"] == algo),
                    key=lambda pair: pair[0],
                )
                if not mine:
                    continue
                xs = [level for level, _ in mine]
                ax.plot(xs, [cell[f"{metric}_mean"] for _, cell in mine], marker="o", color=colours[algo])
                for level, cell in mine:
                    values = [seed[metric] for seed in cell["per_seed"] if math.isfinite(seed[metric])]
                    ax.scatter([level] * len(values), values, s=8, color=colours[algo], alpha=0.35)
            if scale:
                ax.set_xscale(**scale)
            ax.set_xlabel(STUDY_AXES[key])
            ax.set_ylabel(title)
            if row == 0:
                ax.set_title(env)
    # One legend with every method, whichever env it has cells on
    handles = [Line2D([], [], marker="o", color=colours[algo], label=algo) for algo in algos]
    axes[0, 0].legend(handles=handles, fontsize=7)
    figure.tight_layout()
    return figure


#: Thresholds of the performance profile: normalised scores from PPO's (0) to beyond the oracle's (1)
PROFILE_TAUS = np.linspace(-0.5, 1.5, 81)


def normalised_scores_by_algo(summary: dict[str, Any]) -> dict[str, list[list[float]]]:
    """
    Per algorithm, the finite per-seed normalised scores of each of its cells in the envs the aggregates take
    (:func:`aggregated_envs`; in a summary written before it, the headline envs), one list per env and variant.
    """
    scores: dict[str, list[list[float]]] = {}
    for cell in summary["cells"]:
        if not cell.get("aggregated", cell.get("headline", True)):  # outside the aggregates
            continue
        values = [s["normalised_score"] for s in cell["per_seed"] if math.isfinite(s.get("normalised_score", math.nan))]
        if values:
            scores.setdefault(cell["algo"], []).append(values)
    return scores


def performance_profile_figure(summary: dict[str, Any]) -> Any:
    """
    rliable's performance profile of the normalised scores: per algorithm, the share of runs scoring above each
    threshold (each env weighing the same), with its stratified-bootstrap 95% band where some env has several runs;
    ``None`` without normalised scores.
    """
    scores = normalised_scores_by_algo(summary)
    if not scores:
        return None
    figure = new_figure(width=6.4, height=4.4)
    ax = figure.subplots()
    for algo, tasks in scores.items():
        profile = performance_profile(tasks, PROFILE_TAUS)
        envs = f"{len(tasks)} env" + ("s" if len(tasks) != 1 else "")
        (line,) = ax.plot(PROFILE_TAUS, profile, label=f"{algo} ({envs}, {sum(map(len, tasks))} runs)")
        if any(len(values) > 1 for values in tasks):  # with one run per env, no band: every resample is the runs
            lower, upper = performance_profile_ci(tasks, PROFILE_TAUS, reps=500)
            ax.fill_between(PROFILE_TAUS, lower, upper, color=line.get_color(), alpha=0.2)
    for tau, text in ((0.0, "PPO"), (1.0, "oracle")):
        ax.axvline(tau, color="gray", linewidth=0.8, linestyle="--")
        ax.text(tau, 1.02, text, ha="center", fontsize=8, color="gray")
    ax.set_xlabel("normalised score τ (feasible reward: 0 = PPO, 1 = PPO-Lagrangian on the true cost)")
    ax.set_ylabel("share of runs with score > τ")
    ax.set_ylim(0, 1.08)
    ax.legend(fontsize=7)
    figure.tight_layout()
    return figure
