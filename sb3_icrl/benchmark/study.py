"""
A study: a suite whose variants vary one setting (transition noise, violating demonstrations) of the fresh-seed table's
runs (:func:`study_axis`), and its level 0, read from another report: that table's runs of the same recipes, seeds and
evaluation are the study's runs without the change. ``report --baseline`` keeps them in the study's summary, its
figure draws them at level 0 and its table lists them beside the levels.
"""

import json
import math
import os
from typing import Any

from sb3_icrl.benchmark.judgements import ORACLE_ROW, PPO_ROW
from sb3_icrl.benchmark.suite import Suite, SuiteError
from sb3_icrl.registry import env_name

#: The variant settings a study varies, with the axis label of its figure (the noise on a log scale)
STUDY_AXES = {
    "transition_noise": "transition noise sigma",
    "violating_fraction": "share of violating demonstrations",
}


#: The settings that change only the demonstrations: the reference rows (PPO, the oracle) learn from none, so a study of
#: them need not train those rows again; their level-0 runs stand for every level
DEMONSTRATION_AXES = ("violating_fraction",)

#: The rows a study of the demonstrations takes from its level 0 for every level (:data:`DEMONSTRATION_AXES`)
REFERENCE_ROWS = (PPO_ROW, ORACLE_ROW)


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


#: The variant name a study's level 0 takes in its figure and table (the runs of another report, without the change)
BASELINE_VARIANT = "level 0"


def baseline_cells(baseline: dict[str, Any], cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """
    The level 0 a study's figure and table show: each baseline cell of a method the study has runs of on that env, on
    the seeds of those runs only (while a study is under way its levels hold fewer seeds than the baseline: its level-0
    mean over other seeds would not compare with theirs), as a cell of variant :data:`BASELINE_VARIANT`; a reference
    row that stands for every level (``every_level``, :func:`study_baseline`) on the seeds of any of the env's methods.
    A value its summary.json holds as ``null`` (no number) is ``nan`` there.

    :param baseline: The study's level 0 (:func:`study_baseline`)
    :param cells: The study's cells
    """
    studied: dict[tuple[str, str], set[int]] = {}
    for cell in cells:
        studied.setdefault((cell["env"], cell["algo"]), set()).update(seed["seed"] for seed in cell["per_seed"])
    on_env: dict[str, set[int]] = {}  # a reference row for every level: on the seeds any method of the env holds
    for (env, _), seeds in studied.items():
        on_env.setdefault(env, set()).update(seeds)
    drawn = []
    for cell in baseline["cells"]:
        seeds = on_env.get(cell["env"], set()) if cell.get("every_level") else studied.get((cell["env"], cell["algo"]), set())
        per_seed = [_levels(seed) for seed in cell["per_seed"] if seed["seed"] in seeds]
        if not per_seed:
            continue
        drawn.append({**cell, **_means(per_seed), "per_seed": per_seed, "variant": BASELINE_VARIANT})
    return drawn


#: The summary keys a baseline report must share with the study's: the same held-out evaluation
_SAME_EVALUATION = ("eval_budget", "eval_episodes", "eval_seed")


def read_report_summary(folder: str, option: str = "--baseline") -> dict[str, Any]:
    """
    :param folder: A report folder (``benchmark report -o``)
    :param option: The option that named it, for the error messages
    :return: Its ``summary.json``
    :raises SuiteError: When the folder holds no intact report
    """
    path = os.path.join(folder, "summary.json")
    if not os.path.isfile(path):
        raise SuiteError(f"{option}: no report in {folder!r} (no summary.json): pass a folder `benchmark report -o` wrote.")
    try:
        with open(path) as file:
            summary = json.load(file)
    except OSError as error:
        raise SuiteError(f"{option}: {path} cannot be read ({error}).") from error
    except ValueError:
        summary = None
    if not isinstance(summary, dict) or not isinstance(summary.get("cells"), list):
        raise SuiteError(f"{option}: {path} is not a report's summary (cut short or overwritten): write that report again.")
    return summary


def study_baseline(baseline: dict[str, Any], suite: Suite, source: str, model: str = "final") -> dict[str, Any]:
    """
    The runs of ``baseline`` (another suite's report) that are the study's at level 0: its cells of the study's envs
    and methods, each with the seeds the study trains on that env, all at the study's recipe version and evaluated as
    the study evaluates.

    :param baseline: The other report's summary (:func:`read_report_summary`)
    :param suite: The study's suite
    :param source: Where that report lies, as the study's report names it
    :param model: The model the study's report evaluates (``final`` or ``best``)
    :return: ``source``, ``suite``, ``recipe_version`` and ``cells`` (per env and method: its seeds' violation rate,
        feasible reward and identification values, and the means of the first two), for the summary's ``study_baseline``
        key. In a study of the demonstrations (:data:`DEMONSTRATION_AXES`) the cells include the reference rows the study
        does not train (:data:`REFERENCE_ROWS`), marked ``every_level``: they learn from no demonstrations, so their runs
        are the same at every level
    :raises SuiteError: When the two reports do not compare like with like, or share no run
    """
    if suite.recipe_version is None:
        raise SuiteError(
            f"--baseline: suite {suite.name!r} names no recipe_version, so nothing shows that the other report's runs "
            "use its recipes. Give the suite the recipe_version of the runs it extends."
        )
    if baseline.get("suite") == suite.name:
        raise SuiteError(f"--baseline: {source!r} is a report of suite {suite.name!r} itself: pass the report it extends.")
    differences = [
        f"{key} {baseline.get(key)!r} there, {value!r} here"
        for key, value in [*((key, getattr(suite, key)) for key in _SAME_EVALUATION), ("model", model)]
        if baseline.get(key, "final" if key == "model" else None) != value
    ]
    if differences:
        raise SuiteError(
            f"--baseline: the report in {source!r} evaluates its runs otherwise than suite {suite.name!r} ("
            + "; ".join(differences)
            + "): its numbers would not be the study's level 0."
        )
    env_ids = {env_name(env_id): env_id for env_id in suite.envs}  # (a report names its envs without their namespace)
    axis = study_axis(suite)
    every_level = (
        [algo for algo in REFERENCE_ROWS if algo not in suite.algos] if axis and axis[0] in DEMONSTRATION_AXES else []
    )
    cells: dict[tuple[str, str], dict[str, Any]] = {}
    for cell in baseline["cells"]:
        if cell["env"] not in env_ids or (cell["algo"] not in suite.algos and cell["algo"] not in every_level):
            continue
        key = (cell["env"], cell["algo"])
        if key in cells:
            raise SuiteError(
                f"--baseline: the report in {source!r} has several variants of {cell['algo']} on {cell['env']}: a level 0 "
                "is one set of runs. Pass a report with one variant per env and method."
            )
        seeds = suite.env_seeds.get(env_ids[cell["env"]], suite.seeds)
        per_seed = [seed for seed in cell["per_seed"] if seed["seed"] in seeds]
        versions = sorted({seed.get("recipe_version") or "none recorded" for seed in per_seed} - {suite.recipe_version})
        if versions:
            raise SuiteError(
                f"--baseline: {cell['algo']} on {cell['env']} in {source!r} ran recipe version {', '.join(versions)}, suite "
                f"{suite.name!r} runs {suite.recipe_version}: the level 0 must use the study's recipes."
            )
        if per_seed:
            cells[key] = {"env": cell["env"], "algo": cell["algo"], "per_seed": [_levels(seed) for seed in per_seed]}
            if cell["algo"] in every_level:
                cells[key]["every_level"] = True
    if not cells:
        raise SuiteError(
            f"--baseline: the report in {source!r} has no run of the envs, methods and seeds of suite {suite.name!r}: pass "
            "the report of the runs it extends (the fresh-seed table's for the shipped studies)."
        )
    for cell in cells.values():
        cell.update(_means(cell["per_seed"]))
    return {
        "source": source,
        "suite": baseline.get("suite"),
        "recipe_version": suite.recipe_version,
        "cells": list(cells.values()),
    }


#: A baseline run's identification values, kept where its report has them (the ICRL rows)
IDENTIFICATION_KEYS = ("identification_auroc", "untrained_auroc_low", "untrained_auroc_high")


def _levels(seed: dict[str, Any]) -> dict[str, Any]:
    """
    One baseline run: its seed, violation rate and feasible reward (``nan`` where its report has ``null``), and the
    identification values (:data:`IDENTIFICATION_KEYS`) its report holds.
    """
    return {
        "seed": seed["seed"],
        **{key: math.nan if seed.get(key) is None else float(seed[key]) for key in ("violation_rate", "feasible_reward")},
        **{key: math.nan if seed[key] is None else float(seed[key]) for key in IDENTIFICATION_KEYS if key in seed},
    }


def _means(per_seed: list[dict[str, Any]]) -> dict[str, float]:
    """The mean violation rate and feasible reward of baseline runs (:func:`_levels`), ``nan`` where none has a number."""
    means = {}
    for metric in ("violation_rate", "feasible_reward"):
        values = [seed[metric] for seed in per_seed if math.isfinite(seed[metric])]
        means[f"{metric}_mean"] = sum(values) / len(values) if values else math.nan
    return means


def baseline_line(summary: dict[str, Any]) -> str | None:
    """
    The report's note on the study figure's level 0 (``None`` without one): whose runs, how many, which recipes.

    :param summary: A summary with the ``study_baseline`` key of :func:`study_baseline`
    """
    baseline = summary.get("study_baseline")
    if not baseline:
        return None
    runs = sum(len(cell["per_seed"]) for cell in baseline["cells"])
    envs = list(dict.fromkeys(cell["env"] for cell in baseline["cells"]))
    return (
        f"Level 0 of study.png: {runs} runs of the report of suite {baseline['suite']!r} ({baseline['source']}) on "
        f"{', '.join(envs)}, the same seeds, recipe version ({baseline['recipe_version']}) and evaluation as this study, "
        "without its change."
    )
