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

This module collects the finished runs and evaluates them (:func:`evaluate_finished`, :func:`constraint_metrics`,
:func:`run_facts`; an earlier report's runs: :func:`previous_results`), builds the summary (:func:`summarise_suite`)
and writes it (:func:`write_report`). The judgements and scores it adds are made in
:mod:`~sb3_icrl.benchmark.judgements`, the tables and sentences in :mod:`~sb3_icrl.benchmark.report_text`, the figures
in :mod:`~sb3_icrl.benchmark.report_figures`, and numbers are written as :mod:`~sb3_icrl.benchmark.report_numbers` says.
"""

import json
import math
import os
import pathlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, fields
from typing import Any

import numpy as np
import yaml

from sb3_icrl.benchmark.judgements import (
    LAST_TRAINING_COLUMNS,
    ORACLE_ROW,
    PPO_ROW,
    add_reference_scores,
    aggregated_envs,
    aim_outcome,
    beats,
    beats_judgement,
    normalised_aggregates,
    published_pairs,
    spread,
)
from sb3_icrl.benchmark.report_figures import summary_run
from sb3_icrl.benchmark.report_numbers import finite_or_null
from sb3_icrl.benchmark.report_text import TRANSFER_REFERENCES, csv_rows, latex_table, markdown_table, transfer_compute
from sb3_icrl.benchmark.study import BASELINE_VARIANT, DEMONSTRATION_AXES, study_axis
from sb3_icrl.benchmark.suite import RunSpec, Suite, result_current
from sb3_icrl.common.constraint_spec import get_constraint_spec
from sb3_icrl.common.evaluation import CONSTRAINT_VIOLATION_PREFIX, OUTCOME_RATE_KEYS
from sb3_icrl.common.saved import read_saved_data_text
from sb3_icrl.common.statistics import MIN_SEEDS_FOR_INTERVAL, iqm, stratified_bootstrap_ci
from sb3_icrl.common.utils import atomic_write_bytes, atomic_write_json
from sb3_icrl.data import load_demonstrations
from sb3_icrl.envs import heldout_env_kwargs
from sb3_icrl.metrics.identification import PROBE_POLICIES_FOLDER, headline, identification_cached, identify_run
from sb3_icrl.metrics.transfer import (
    REFERENCES_FOLDER,
    default_references_dir,
    read_transfers,
    transfer_file,
    transfer_times,
)
from sb3_icrl.registry import ICRL_ALGOS, env_name
from sb3_icrl.run_evaluation import (
    RunResult,
    UnfinishedEpisodesError,
    episode_step_cap,
    evaluate_run,
    heldout_steps,
    summarise,
)
from sb3_icrl.run_folder import (
    FINISHED_FILE,
    find_vecnormalize,
    finished_cpu_time,
    finished_wall_time,
    is_finished,
    lacks_own_statistics,
    last_training_episodes,
    read_finished,
    unreadable_finished,
)

#: Held-out evaluation cached in each run folder
HELDOUT_FILE = "heldout.json"
#: The same for ``best_model.zip`` (``model="best"``)
HELDOUT_BEST_FILE = "heldout_best.json"


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
                identified = identify_run(folder, model=model)
                entry.update(headline(identified["scores"]))
                # Whose unconstrained episodes were among the probes (none until a PPO run of the env has finished)
                unconstrained = identified["settings"].get("unconstrained_run")
                entry["identification_unconstrained_run"] = unconstrained
                # (grid worlds have no probe episodes, the others the learner's and, when a PPO run is found, its)
                episodes = "learner" in (identified["scores"].get("sources") or {})
                if episodes and (unconstrained is None or os.path.basename(unconstrained) != os.path.basename(folder)):
                    whose = "no" if unconstrained is None else f"another seed's ({unconstrained})"
                    log(
                        f"{run.name}: its probes hold {whose} unconstrained PPO episodes, no finished ppo run of seed "
                        f"{run.seed} being beside it: to score it on its own seed's, train that run (`benchmark run "
                        "--reported` trains it again with the seed's ICRL runs) and report again"
                    )
            except Exception as error:  # a run that cannot be scored leaves its columns empty, not the report unwritten
                log(f"no identification scores for {run.name}: {type(error).__name__}: {error}")
        current = []
        transfers = read_transfers(folder) if model == "final" else {}
        for task, transfer in transfers.items():
            if not result_current(folder, transfer_file(task)):
                log(
                    f"{run.name}: its {transfer_file(task)} predates its final model (trained again since): left out; "
                    "`benchmark run` runs the transfer again"
                )
                continue
            entry[f"transfer_{task}_violation_rate"] = float(transfer["violation_rate"])
            entry[f"transfer_{task}_feasible_ratio"] = float(transfer["feasible_reward_ratio"])
            # The references' feasible rewards, to read the ratio by: over an oracle that earns no more than PPO it says
            # nothing of the learned cost
            learners = transfer.get("results") or {}
            for reference in TRANSFER_REFERENCES:
                value = learners.get(reference, {}).get("feasible_reward")
                if value is not None:
                    entry[f"transfer_{task}_{reference}_feasible_reward"] = float(value)
            current.append(transfer)
        untested = [task for task in run.transfer_tasks() if task not in transfers] if model == "final" else []
        if untested:
            log(
                f"{run.name}: no transfer result for task {', '.join(untested)} (the suite tests this env's runs on it): "
                "its transfer columns stay empty; `benchmark run` runs the test, then report again"
            )
        # The transfer tests' compute: the suite's counts each reference file once, however many runs read it
        learned, references = transfer_times(current)
        if learned is not None:
            entry["transfer_wall_time_s"] = learned
        if references:
            entry["transfer_reference_wall_time_s"] = references
    return metrics


def keep_transfer_references(runs: Sequence[RunSpec], root: str, output: str) -> list[str]:
    """
    Copy the reference results the runs' transfer tests read (the oracle and unconstrained PPO learners, trained once
    per env, seed and variant: most of a seed's transfer compute) into ``<output>/transfer_references/<variant>/``, so
    that ``benchmark run --reported <output>`` on a machine without them restores them
    (:func:`restore_transfer_references`) instead of training them again. Each is looked up by its file name in the
    run's variant folder (``<root>/<suite>/<variant>/transfer_references/``, where the transfer tests of a suite keep
    them, so a log root moved since is no matter); a file already kept as it is, or one a test read from a folder of
    another name (``sb3-icrl transfer --references-dir``), is left alone.

    :param runs: The reported runs (those with no folder under ``root`` are passed over)
    :param root: The log root
    :param output: The report folder
    :return: The paths written
    """
    written = []
    for run in runs:
        shared = default_references_dir(run.run_folder(root))
        for transfer in read_transfers(run.run_folder(root)).values():
            for path in transfer.get("settings", {}).get("reference_files", {}).values():
                recorded = pathlib.Path(path)
                source = shared / recorded.name
                if recorded.parent.name != REFERENCES_FOLDER or not source.is_file():
                    continue
                target = pathlib.Path(output, REFERENCES_FOLDER, run.variant, source.name)
                data = source.read_bytes()
                if target.is_file() and target.read_bytes() == data:
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                atomic_write_bytes(str(target), data)
                written.append(str(target))
    return written


def restore_transfer_references(reported: str, root: str, suite: Suite, log: Callable[[str], None] = print) -> list[str]:
    """
    The reference results a report keeps (:func:`keep_transfer_references`), copied into the log folder where the
    suite's transfer tests look them up (``<root>/<suite>/<variant>/transfer_references/``) when it lacks them: a
    transfer test reads a reference whose settings match, and trains the others. A file already there is never
    replaced; one that is not a reference's result (cut short, say) is left in the report, with a line in ``log``, and
    its reference trained again.

    :param reported: The report folder (``--reported``)
    :param root: The log root
    :param suite: The suite
    :param log: Where the files passed over are named
    :return: The paths written
    """
    written = []
    for source in sorted(pathlib.Path(reported, REFERENCES_FOLDER).glob("*/*.json")):
        if source.parent.name not in suite.variants:
            continue
        target = pathlib.Path(root, suite.name, source.parent.name, REFERENCES_FOLDER, source.name)
        if target.exists():
            continue
        data = source.read_bytes()
        try:
            saved = json.loads(data)
        except ValueError:
            saved = None
        if not (isinstance(saved, dict) and isinstance(saved.get("settings"), dict) and isinstance(saved.get("result"), dict)):
            log(f"transfer references: {source} is not a reference's result (no settings and result): not restored")
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(str(target), data)
        written.append(str(target))
    return written


def probe_policy_folder(root: str | os.PathLike, run: RunSpec) -> str:
    """
    Where a log root keeps a ``ppo`` row's final policy brought from a report (:func:`restore_probe_policies`):
    ``<root>/<suite>/<variant>/probe_policies/ppo/<EnvName>_<seed>``, which the identification reads when the row's
    own folder is not there (:func:`~sb3_icrl.metrics.identification.find_unconstrained_run`).
    """
    return os.path.join(run.log_folder(root), PROBE_POLICIES_FOLDER, run.algo, f"{env_name(run.env_id)}_{run.seed}")


def kept_probe_policy_folder(report: str | os.PathLike, run: RunSpec) -> str:
    """Where a report keeps a ``ppo`` row's final policy (:func:`keep_probe_policies`)."""
    return os.path.join(os.fspath(report), PROBE_POLICIES_FOLDER, run.variant, run.algo, f"{env_name(run.env_id)}_{run.seed}")


def _probe_policy_files(run: RunSpec) -> tuple[list[str], list[str]]:
    """
    The files of a PPO run folder that its kept policy holds, relative to the folder: those it needs (the final model
    and its arguments, which the identification's probes load, and ``finished.json``, last, so that a copy is written
    in this order and one cut short is not a finished run) and those kept when present
    (the normalisation statistics, and what tells one training from another: the command lines and versions).
    """
    name = env_name(run.env_id)
    needed = [f"{name}.zip", f"{name}/args.yml", FINISHED_FILE]
    return needed, [f"{name}/config.yml", f"{name}/vecnormalize.pkl", f"{name}/versions.yml", "command.txt"]


def keep_probe_policies(
    suite: Suite, results: Sequence[tuple[RunSpec, RunResult]], metrics: dict[str, dict[str, Any]], root: str, output: str
) -> list[str]:
    """
    Copy the final policy of each reported ``ppo`` row whose episodes its seed's identification probes read
    (:meth:`~sb3_icrl.benchmark.suite.Suite.probe_runs`) into ``<output>/probe_policies/<variant>/ppo/<EnvName>_<seed>/``
    (about 200 KB for a MuJoCo row: the model, its arguments and statistics, not its checkpoints or Monitor files), so that
    ``benchmark run --reported <output>`` on a machine without the row's folder restores it
    (:func:`restore_probe_policies`) instead of training the row again for the probes. Only a folder that is the
    reported row is kept: its last training episodes and training starts those of the report's row (a row trained
    again after a stop goes on with fresh random streams, and its policy is another). A file already kept as it is is
    not written again.

    :param suite: The suite
    :param results: Every ``(run, result)`` of the report
    :param metrics: Per ``result.run``, the report's per-seed metrics
    :param root: The log root
    :param output: The report folder
    :return: The paths written
    """
    probes = set(suite.probe_runs(suite.runs()).values())
    written = []
    for run, result in results:
        folder = run.run_folder(root)
        if run not in probes or not is_finished(folder) or not _is_reported_row(folder, metrics.get(result.run, {})):
            continue
        needed, optional = _probe_policy_files(run)
        if not all(os.path.isfile(os.path.join(folder, path)) for path in needed):
            continue
        target = kept_probe_policy_folder(output, run)
        # finished.json last (``needed`` ends with it): a copy cut short is not a finished run
        for path in [*(path for path in optional if os.path.isfile(os.path.join(folder, path))), *needed]:
            data = pathlib.Path(folder, path).read_bytes()
            destination = pathlib.Path(target, path)
            if destination.is_file() and destination.read_bytes() == data:
                continue
            atomic_write_bytes(str(destination), data)
            written.append(str(destination))
    return written


def _is_reported_row(folder: str, reported: dict[str, Any]) -> bool:
    """Whether a run folder is the row the report keeps: the same last training episodes and training starts."""
    compared, differences = _row_differences(folder, reported)
    return compared and not differences


def restore_probe_policies(reported: str, root: str, suite: Suite, log: Callable[[str], None] = print) -> list[str]:
    """
    The ``ppo`` rows' policies a report keeps (:func:`keep_probe_policies`), copied into the log folder
    (:func:`probe_policy_folder`) when it lacks them, so that the identification of their seeds' ICRL runs reads the
    reported row's episodes without training it again. A folder already there is never replaced; a kept policy that
    lacks a file it needs is left in the report, with a line in ``log``, and the row trained again.

    :param reported: The report folder (``--reported``)
    :param root: The log root
    :param suite: The suite
    :param log: Where the policies passed over are named
    :return: The folders written
    """
    written = []
    by_name = {
        (run.variant, run.algo, f"{env_name(run.env_id)}_{run.seed}"): run for run in suite.probe_runs(suite.runs()).values()
    }
    for source in sorted(pathlib.Path(reported, PROBE_POLICIES_FOLDER).glob("*/*/*")):
        variant, algo, name = source.parts[-3:]
        run = by_name.get((variant, algo, name))
        if run is None or not source.is_dir():
            continue
        target = probe_policy_folder(root, run)
        if os.path.exists(target):
            continue
        needed, optional = _probe_policy_files(run)
        missing = [path for path in needed if not (source / path).is_file()]
        if missing or read_finished(source) is None:
            log(f"probe policies: {source} lacks {', '.join(missing) or 'a readable finished.json'}: not restored")
            continue
        for path in [*(path for path in optional if (source / path).is_file()), *needed]:
            atomic_write_bytes(os.path.join(target, path), (source / path).read_bytes())
        written.append(target)
    return written


def run_facts(results: Sequence[tuple[RunSpec, RunResult]], root: str) -> dict[str, dict[str, Any]]:
    """
    Per finished run, its training time (``wall_time_s``, from ``finished.json``, see :func:`finished_wall_time`) and
    the CPU time its process spent on it (``cpu_time_s``, see :func:`finished_cpu_time`), the
    mean return of our expert's demonstrations (``expert_return``, see :func:`expert_source`; NaN when there are none,
    e.g. an env without a shipped dataset), its recipe version, its :func:`training_provenance` and
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
        finished = read_finished(folder)
        for column, seconds in (("wall_time_s", finished_wall_time(finished)), ("cpu_time_s", finished_cpu_time(finished))):
            if seconds is not None:
                entry[column] = seconds
        entry["expert_return"] = _expert_return_once(expert_source(run, folder), returns)
        version = recorded_recipe_version(folder)
        if version is not None:
            entry["recipe_version"] = version
        entry.update(training_provenance(folder))
        if run.algo in ICRL_ALGOS:
            updates = constraint_updates_made(os.path.join(folder, f"{env_name(run.env_id)}.zip"))
            if updates is not None:
                entry["constraint_updates"] = updates
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
    report's :data:`~sb3_icrl.benchmark.report_figures.FIGURE_DATA_FILE`).

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


def reported_runs_trained_again(summary: dict[str, Any], suite: Suite, runs: Sequence[RunSpec], root: str) -> list[str]:
    """
    The selected ``runs`` that an earlier report holds and whose folder under ``root`` is another training of the same
    recipe version than the one it reported: another training time or git revision, or not finished (yet; counted only
    when some selected run has finished, as ``report --update`` changes nothing otherwise). ``report --update`` would
    put that training in the reported row's place (or drop the row, if it has not finished); ``benchmark run
    --reported`` trains a reported PPO row again only for its seed's identification probes, and that copy must not
    replace it. A folder that recorded another recipe version than the reported row is a new recipe's run: not listed.

    :param summary: The earlier report's summary
    :param suite: The suite it reported
    :param runs: The runs ``--only`` selects
    :param root: The log root
    :return: One line per such run, naming what differs
    """
    selected = set(runs)
    kept, kept_metrics, _ = previous_results(summary, suite, root)
    lines, unfinished = [], []
    for run, result in kept:
        folder = run.run_folder(root)
        if run not in selected or not os.path.isdir(folder):
            continue
        reported = kept_metrics.get(result.run, {})
        version, reported_version = recorded_recipe_version(folder), reported.get("recipe_version")
        if version is not None and reported_version is not None and version != str(reported_version):
            continue
        finished = read_finished(folder)
        if finished is None:
            unfinished.append(f"{run.name}: its training here has not finished")
            continue
        differences = []
        here, there = finished_wall_time(finished), reported.get("wall_time_s")
        if here is not None and there is not None and not math.isclose(here, float(there), rel_tol=1e-9):
            differences.append(f"trained {here / 60:.1f} min here against the report's {float(there) / 60:.1f}")
        revision, reported_revision = training_provenance(folder).get("git_revision"), reported.get("git_revision")
        if revision is not None and reported_revision is not None and revision != str(reported_revision):
            differences.append(
                f"git revision {_short_revision(revision)} here against the report's {_short_revision(str(reported_revision))}"
            )
        if differences:
            lines.append(f"{run.name}: {'; '.join(differences)}")
    if unfinished and any(is_finished(run.run_folder(root)) for run in runs):
        lines += unfinished
    return lines


def _short_revision(revision: str) -> str:
    """A git revision's first 7 characters, with the ``-dirty`` suffix of a working tree that had changes kept."""
    return revision[:7] + ("-dirty" if revision.endswith("-dirty") else "")


def probe_rows_unlike_report(
    suite: Suite,
    scored: Sequence[RunSpec],
    results: Sequence[tuple[RunSpec, RunResult]],
    metrics: dict[str, dict[str, Any]],
    root: str,
) -> list[str]:
    """
    The ICRL runs scored now whose probes read a ``ppo`` folder that is not the ``ppo`` row the report keeps for their
    seed: the identification runs that folder's final policy for its episodes, so a row trained again that differs
    from the reported one (stopped and resumed, it goes on with fresh random streams) scores the runs on episodes the
    report does not show. Told apart by the folder's last training episodes and training starts against the kept
    row's; a row reported by this same report is its folder, and only the folder each run's identification recorded
    reading counts.

    :param suite: The suite
    :param scored: The runs evaluated by this report (not those kept from an earlier one)
    :param results: Every ``(run, result)`` of the report, kept ones too
    :param metrics: Per ``result.run`` (relative to ``root``), the report's per-seed metrics, the kept rows' read from
        the earlier summary and the scored runs' with the ``identification_unconstrained_run`` they recorded
    :param root: The log root
    :return: One line per such probe row, naming the runs it probed and what brings the reported row back
    """
    scored_runs = set(scored)
    by_run = dict(results)
    probed: dict[RunSpec, list[RunSpec]] = {}
    for run, probe in suite.probe_runs(scored).items():
        if run not in by_run or probe not in by_run or probe in scored_runs:
            continue
        recorded = metrics.get(by_run[run].run, {}).get("identification_unconstrained_run")
        if recorded is None:
            continue  # not scored, or on no PPO episodes (said elsewhere)
        read = os.path.realpath(os.path.join(root, by_run[run].run, recorded))
        if read == os.path.realpath(probe.run_folder(root)):
            probed.setdefault(probe, []).append(run)
    lines = []
    for probe, runs in probed.items():
        reported = metrics.get(by_run[probe].run, {})
        _, differences = _row_differences(probe.run_folder(root), reported)
        starts_reported = reported.get("training_starts")
        if not differences:
            continue  # the same row, or nothing to tell them apart by
        if starts_reported is not None and int(starts_reported) > 1:
            remedy = (
                f"the reported row itself started {starts_reported} times, so no training here gives its episodes: "
                "those runs' identification reads a PPO agent the report does not show"
            )
        else:
            remedy = (
                "move that folder out of the log root, train the row again without a stop (`benchmark run` without "
                "--reported, --only its env, seed and algo=ppo) and report those runs again"
            )
        shown = ", ".join(run.name for run in runs)
        lines.append(
            f"{probe.name}: its folder here is not the reported row ({'; '.join(differences)}), yet it probed {shown}: "
            + remedy
        )
    return lines


def _row_differences(folder: str, reported: dict[str, Any]) -> tuple[bool, list[str]]:
    """
    How a ``ppo`` folder differs from the row a report keeps, by its last training episodes and its training starts.

    :param folder: The run folder
    :param reported: The report's per-seed metrics of the row
    :return: Whether the last training episodes could be compared (both sides have them, and the folder's Monitor
        files read), and one phrase per difference found
    """
    differences = []
    try:
        here = last_training_episodes(folder)
    except (ValueError, IndexError):  # a Monitor line cut short: judged by its training starts alone
        here = None
    reported_feasible, reported_violation = (
        reported.get("last_training_feasible_reward"),
        reported.get("last_training_violation_rate"),
    )
    compared = False
    if here is not None and reported_feasible is not None and reported_violation is not None:
        compared = True
        reported_values = (float(reported_feasible), float(reported_violation))
        here_values = (here["feasible_reward"], here["violation_rate"])
        if not all(math.isclose(a, b, rel_tol=1e-9) for a, b in zip(here_values, reported_values, strict=True)):
            differences.append(
                f"last training episodes {_pair_text(*here_values)} against the report's {_pair_text(*reported_values)}"
            )
    starts_here, starts_reported = training_provenance(folder).get("training_starts"), reported.get("training_starts")
    if starts_here is not None and starts_reported is not None and int(starts_here) != int(starts_reported):
        differences.append(f"training starts {starts_here} against {starts_reported}")
    return compared, differences


def _pair_text(feasible: float, violation: float) -> str:
    """``feasible / violation%`` for a message."""
    return f"{feasible:.1f} / {100 * violation:.0f}%"


def constraint_updates_made(model_file: str | os.PathLike) -> int | None:
    """
    How many times an ICRL model's constraint was updated (its ``n_constraint_updates``), read from the model zip's
    data without loading the model. A run whose count is far below its peers' stopped learning its constraint early
    (``match_tolerance`` skipped its updates, or its episodes rarely ended).

    :param model_file: A saved ICRL model
    :return: The count, ``None`` when there is no such file or it keeps no count
    """
    text = read_saved_data_text(pathlib.Path(model_file))
    try:
        data = json.loads(text) if text is not None else None
    except ValueError:
        return None
    count = data.get("n_constraint_updates") if isinstance(data, dict) else None
    return int(count) if isinstance(count, int) else None


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
    return _dataset_of(recorded if recorded is not None else dict(run.variant_settings), run.env_id)


def _dataset_of(settings: dict[str, Any], env_id: str) -> tuple[str, float | None]:
    """The dataset that run settings (``args.yml`` or a variant's) name on an env: :func:`demonstrations_source`."""
    name = settings.get("demonstrations") or env_name(env_id)
    fraction = settings.get("violating_fraction")
    return str(name), float(fraction) if isinstance(fraction, (int, float)) and fraction else None


def expert_source(run: RunSpec, folder: str | os.PathLike | None = None) -> tuple[str, None]:
    """
    The demonstrations that measure a run against our expert: those it learned from (:func:`demonstrations_source`)
    without their violating share. An imperfect-expert run's dataset mixes the expert's trajectories with perturbed
    ones that break the constraint and return less; dividing by that mix would make the same policy look better the
    more of the data was spoiled. Against the clean dataset every share reads on one scale, the one of level 0.

    :param run: The run
    :param folder: Its run folder (``None``: the variant settings only)
    :return: ``(name or path, None)``, as :func:`expert_return` takes them
    """
    return demonstrations_source(run, folder)[0], None


def expert_return(name: str, violating_fraction: float | None = None) -> float | None:
    """
    Mean return (sum of ``rews``) of the trajectories of a demonstration dataset.

    :param name: Shipped dataset name (env name) or path
    :param violating_fraction: The imperfect-expert variant of a shipped dataset
    :return: The mean return; ``None`` when there is no such dataset or it is empty
    """
    facts = demonstrations_facts(name, violating_fraction)
    return None if facts is None else facts["mean_return"]


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


def cpu_compute(metrics: dict[str, dict[str, Any]], wall_time: dict[str, float | None]) -> dict[str, Any]:
    """
    The training CPU time of the runs that recorded one beside their wall time (runs reported before it was kept did
    not): ``cpu_hours_runs``, how many; ``cpu_hours``, their CPU-hours; ``cpu_runs_wall_hours``, the wall-clock
    core-hours of the same runs, so a reader sees how much of the wall time was waiting for a shared core.

    :param metrics: Per run, its facts (:func:`run_facts`: ``cpu_time_s``)
    :param wall_time: Per run, its training wall time in seconds
    :return: The three entries; ``cpu_hours`` and ``cpu_runs_wall_hours`` are ``None`` when no run recorded a CPU time
    """
    timed = [run for run, wall in wall_time.items() if wall is not None and metrics.get(run, {}).get("cpu_time_s") is not None]
    return {
        "cpu_hours_runs": len(timed),
        "cpu_hours": _core_hours([metrics[run]["cpu_time_s"] for run in timed]),
        "cpu_runs_wall_hours": _core_hours([wall_time[run] for run in timed]),
    }


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
    return (``expert_return``: mean return of its demonstrations, :func:`expert_source`) and the feasible reward as a
    fraction of it (``feasible_reward_fraction``), the runs' compute (``core_hours``) and, per published number, whether
    the cell beats it (``beats``: :func:`~sb3_icrl.benchmark.judgements.beats`); per algorithm, the IQM of the violation
    rate over the headline envs with a stratified bootstrap CI (``aggregates``), and the normalised aggregates over the
    envs of :func:`~sb3_icrl.benchmark.judgements.aggregated_envs` (``normalised_aggregates``, ``improvements``;
    ``aggregated_envs`` and ``aggregates_left_out`` name them); the runs not finished yet, and the finished ones
    without a transfer result their suite asks for (``transfer_tests_missing``); the suite's compute. With the
    suite keys ``beats`` and ``aim``, also their judgements (``beats_judgement``:
    :func:`~sb3_icrl.benchmark.judgements.beats_judgement`; ``aim``: :func:`~sb3_icrl.benchmark.judgements.aim_outcome`).

    :param suite: The suite
    :param runs: Its runs (to list the missing ones)
    :param results: ``(run, held-out result)`` of the finished runs
    :param metrics: Per run (``result.run``), identification and transfer columns added to its per-seed values
        (:func:`constraint_metrics`); the cell gets the mean identification AUROC over the seeds that have one.
        Also the run's ``wall_time_s`` and ``expert_return`` (:func:`run_facts`): the cell sums the former into
        ``core_hours`` and averages the latter; a run without an ``expert_return`` there takes the dataset its variant
        settings name. A run whose transfer columns lack a task its suite tests it on is named in
        ``transfer_tests_missing`` (``None``: no columns to look in, nothing named)
    :param model: Which model of each run ``results`` evaluated (``"final"`` or ``"best"``), recorded as ``model``
        (transfer tests are of the final model: under ``"best"`` none is missing)
    :return: A JSON-ready summary
    """
    metrics_given = metrics is not None
    metrics = {name: dict(entry) for name, entry in (metrics or {}).items()}  # the caller's stays as it was
    by_cell: dict[tuple[str, str], list[RunResult]] = {}
    returns: dict[tuple[str, float | None], float | None] = {}  # one load per dataset, however many runs share it
    for run, result in results:
        by_cell.setdefault((env_name(run.env_id), run.variant), []).append(result)
        extra = metrics.setdefault(result.run, {})
        if "expert_return" not in extra:
            extra["expert_return"] = _expert_return_once(expert_source(run), returns)
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
    # Over the envs of the normalised aggregates, every method over the same ones (a suite without both reference rows
    # has none: its headline envs); an interval only where some env has more than one run, as theirs
    pooled = "aggregated" if PPO_ROW in suite.algos and ORACLE_ROW in suite.algos else "headline"
    for algo in suite.algos:
        tasks = [
            finite
            for cell in cells
            if cell["algo"] == algo and cell[pooled]
            for finite in [[seed["violation_rate"] for seed in cell["per_seed"] if math.isfinite(seed["violation_rate"])]]
            if finite
        ]
        if tasks:
            spread_out = any(len(values) > 1 for values in tasks)
            aggregates.append(
                {
                    "algo": algo,
                    "n_cells": len(tasks),
                    "violation_rate_iqm": iqm(np.concatenate(tasks)),
                    "violation_rate_iqm_ci95": list(stratified_bootstrap_ci(tasks)) if spread_out else None,
                }
            )
    all_seeds = [seed for cell in cells for seed in cell["per_seed"]]
    # Finished runs without a transfer result the suite asks for (a test not run yet, left out as stale, or lost), in
    # the suite's order; only where transfer columns were given to look in
    order = {run.name: index for index, run in enumerate(suite.runs())}
    untested = sorted(
        (
            run.name
            for run, result in results
            if model == "final"
            and metrics_given
            and any(f"transfer_{task}_violation_rate" not in metrics[result.run] for task in run.transfer_tasks())
        ),
        key=lambda name: (order.get(name, len(order)), name),
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
        "transfer_tests_missing": untested,
        "others_sources": list(suite.others),
        **_study_levels(suite),
        "core_hours": _core_hours(list(wall_time.values())),
        "core_hours_runs": sum(value is not None for value in wall_time.values()),
        **cpu_compute(metrics, wall_time),
        **transfer_compute(all_seeds),
        **judgements,
    }


def _study_levels(suite: Suite) -> dict[str, Any]:
    """
    For a study (:func:`~sb3_icrl.benchmark.study.study_axis`), the ``study`` key: the setting and each variant's level;
    for a study of the demonstrations also what each level's demonstrations hold (``demonstrations``, per env and
    variant, level 0 the clean dataset: :func:`demonstrations_facts`).
    """
    axis = study_axis(suite)
    if axis is None:
        return {}
    study: dict[str, Any] = {"setting": axis[0], "levels": axis[1]}
    if axis[0] in DEMONSTRATION_AXES:
        held: dict[str, dict[str, Any]] = {}
        variants = {BASELINE_VARIANT: {}, **suite.variants}
        for env_id in suite.envs:
            facts = {variant: demonstrations_facts(*_dataset_of(settings, env_id)) for variant, settings in variants.items()}
            held[env_name(env_id)] = {variant: fact for variant, fact in facts.items() if fact is not None}
        study["demonstrations"] = held
    return {"study": study}


def demonstrations_facts(name: str, violating_fraction: float | None = None) -> dict[str, Any] | None:
    """
    What a demonstration dataset holds, counted from its trajectories' true costs: how many trajectories, how many of
    them break the constraint, the share of all their steps that do, and their mean return.

    :param name: Shipped dataset name (env name) or path
    :param violating_fraction: The imperfect-expert variant of a shipped dataset
    :return: ``trajectories``, ``violating_trajectories``, ``violating_step_share``, ``mean_return``; ``None`` when
        there is no such dataset or it is empty
    """
    try:
        demonstrations = load_demonstrations(name, violating_fraction=violating_fraction)
    except (OSError, ValueError):  # DemonstrationError is a ValueError: no such dataset
        return None
    if not len(demonstrations):
        return None
    # A step breaks the constraint when any of its costs is positive (several constraints: a column each)
    broken: list[np.ndarray] = []
    for trajectory in demonstrations:
        steps = np.asarray(trajectory.costs) > 0
        broken.append(np.asarray(steps if steps.ndim == 1 else steps.any(axis=1)))
    return {
        "trajectories": len(broken),
        "violating_trajectories": sum(int(steps.any()) for steps in broken),
        "violating_step_share": sum(int(steps.sum()) for steps in broken) / max(1, sum(steps.size for steps in broken)),
        "mean_return": float(np.mean([float(np.sum(trajectory.rews)) for trajectory in demonstrations])),
    }


def _count_runs(runs: Sequence[RunSpec], tasks: set[tuple[str, str]], algos: Sequence[str] | None = None) -> int:
    """How many of ``runs`` are on one of ``tasks`` (``(env, variant)``), of one of ``algos`` when given."""
    return sum((env_name(run.env_id), run.variant) in tasks and (algos is None or run.algo in algos) for run in runs)


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
