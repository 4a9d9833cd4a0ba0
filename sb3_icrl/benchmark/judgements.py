"""
The judgements and scores of a suite's report, made from the cells of
:func:`~sb3_icrl.benchmark.report.summarise_suite`: whether a cell beats a published ``[feasible reward, violation
rate]`` (:func:`beats`) and the suite's judgement "beats the paper" (its key ``beats``, :func:`beats_judgement`); with
the reference rows (``ppo``, unconstrained, and ``ppolag`` on the true cost, the oracle), each run's normalised score
``(F - F_ppo) / (F_oracle - F_ppo)`` with the two rows' means on the same env and variant, and under the suite's
``success`` rule (a violation rate at most ``max_violation_rate`` and a normalised score at least
``min_normalised_score``) each cell's success probability with its Wilson 95% interval (:func:`add_reference_scores`,
where the oracle allows it: :func:`oracle_problem`); the envs the cross-env aggregates take (:func:`aggregated_envs`),
the aggregates and probabilities of improvement (:func:`normalised_aggregates`), the suite's aim (its key ``aim``,
:func:`aim_outcome`), and a cell's centre and interval at its number of seeds (:func:`spread`). Values only: their
tables and sentences are in :mod:`~sb3_icrl.benchmark.report_text`.
"""

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_icrl.benchmark.report_numbers import format_reward
from sb3_icrl.benchmark.suite import Suite
from sb3_icrl.common.statistics import (
    MIN_SEEDS_FOR_INTERVAL,
    iqm,
    mean_of_task_means,
    normalised_score,
    optimality_gap,
    probability_of_improvement,
    probability_of_improvement_ci,
    stratified_bootstrap_ci,
    stratified_bootstrap_ci_of_task_means,
    wilson_interval,
)
from sb3_icrl.registry import ICRL_ALGOS, env_name

#: The paper's protocol per seed: the last training episodes' feasible reward and violation rate (Monitor files)
LAST_TRAINING_COLUMNS = ("last_training_feasible_reward", "last_training_violation_rate")


def beats(cell: dict[str, Any], pair: Sequence[float] | None) -> bool | None:
    """
    Whether a cell beats a published ``[feasible reward, violation rate]``: a higher mean feasible reward and a mean
    violation rate no higher (a mean equal to it up to float rounding counts as equal). ``None`` without a published
    pair, or where either mean is missing or not a number (not judged, rather than judged not to beat it).

    :param cell: A cell of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    :param pair: The published numbers
    """
    if pair is None:
        return None
    reward, violation = cell.get("feasible_reward_mean"), cell.get("violation_rate_mean")
    if reward is None or violation is None or not (math.isfinite(reward) and math.isfinite(violation)):
        return None
    return bool(reward > pair[0] and violation <= pair[1] + 1e-9)


def published_pairs(cell: dict[str, Any]) -> dict[str, Sequence[float]]:
    """``{"paper": pair, source: pair, ...}``: the published numbers of a cell's method on its env."""
    pairs: dict[str, Sequence[float]] = {}
    if cell.get("paper_feasible_reward") is not None:
        pairs["paper"] = (cell["paper_feasible_reward"], cell["paper_violation_rate"])
    pairs.update((cell.get("others") or {}).items())
    return pairs


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
    if oracle["violation_rate_mean"] is None or not math.isfinite(oracle["violation_rate_mean"]):
        return "the oracle has no violation rate"
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

    :param cells: The cells of :func:`~sb3_icrl.benchmark.report.summarise_suite`
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


def column_pair(cell: dict[str, Any], column: str) -> tuple[float, float] | None:
    """
    A cell's mean ``(feasible reward, violation rate)`` under an evaluation column of :data:`BEATS_COLUMNS`.

    :param cell: A cell of :func:`~sb3_icrl.benchmark.report.summarise_suite`
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
    cell gets ``beats_judgement`` (``{column: verdict, "beats": verdict}``), in place. Each verdict says on how many
    seeds it rests (``n_seeds``, of the ``of_seeds`` the suite runs there): a verdict on fewer is one "so far".

    :param cells: The cells of :func:`~sb3_icrl.benchmark.report.summarise_suite`
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
            # The seeds the verdict rests on, beside the suite's: one seed's verdict is not five seeds'
            seeds = {
                "n_seeds": 0 if cell is None else int(cell.get("n_seeds", 0)),
                "of_seeds": len(suite.env_seeds.get(env, suite.seeds)),
            }
            entries.append({"env": env, "variant": variant, **verdicts, **seeds})
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
    # A method that runs none of the judged variants is not judged
    judged_methods = [method for method in methods if method["n_tasks"]]
    most = max((len(method["beaten"]) for method in judged_methods), default=0)
    everywhere = [method["algo"] for method in judged_methods if len(method["beaten"]) == method["n_tasks"]]
    return {
        "against": rule.against,
        "columns": list(rule.columns),
        "paper": {env: list(suite.paper[env][rule.against]) for env in rule.envs},
        "tasks": [list(task) for task in tasks],
        "methods": methods,
        "best": [method["algo"] for method in judged_methods if len(method["beaten"]) == most],
        "outcome": (
            True
            if everywhere
            else False if judged_methods and all(method["not_beaten"] for method in judged_methods) else None
        ),
    }


def beats_pair(ours: tuple[float, float] | None, pair: Sequence[float]) -> bool | None:
    """:func:`beats` of a ``(feasible reward, violation rate)`` of ours, ``None`` when ours is missing."""
    if ours is None:
        return None
    return beats({"feasible_reward_mean": ours[0], "violation_rate_mean": ours[1]}, pair)


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
