"""
The figures of a suite's report: per env and variant the training curves and each method's learned cost over the
constrained feature, ours against the paper, rliable's performance profile of the normalised scores, for a study of a
variant setting (:data:`~sb3_icrl.benchmark.study.STUDY_AXES`) the paper's study figure and for envs with several
constraints its figure of them (:func:`write_figures`).
What they draw of each run is kept in the report folder (:data:`FIGURE_DATA_FILE`, :func:`figure_data`), so that a
report updated once some runs' folders are gone still draws them.
"""

import json
import math
import os
from collections.abc import Collection, Sequence
from typing import Any

import numpy as np
from matplotlib.lines import Line2D

from sb3_icrl.benchmark.report_numbers import finite_or_null, is_finite_number
from sb3_icrl.benchmark.report_text import several_constraint_cells
from sb3_icrl.benchmark.study import BASELINE_VARIANT, STUDY_AXES, baseline_cells, study_axis
from sb3_icrl.benchmark.suite import RunSpec, Suite
from sb3_icrl.common.evaluation import CONSTRAINT_VIOLATION_PREFIX, OUTCOME_RATE_KEYS
from sb3_icrl.common.statistics import performance_profile, performance_profile_ci
from sb3_icrl.common.utils import atomic_write_json
from sb3_icrl.metrics.identification import headline_crossing, identification_file, learned_cost_curves, learned_cost_figure
from sb3_icrl.plots.figures import load_evaluations, new_figure, save_figure, training_curves_figure
from sb3_icrl.registry import ICRL_ALGOS, env_name
from sb3_icrl.run_evaluation import RunResult
from sb3_icrl.run_folder import is_finished

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


def kept_figure_data(output: str, suite_name: str, model: str = "final") -> dict[str, dict[str, Any]]:
    """
    What the report already in ``output`` keeps to draw its runs (:data:`FIGURE_DATA_FILE`), by run name; empty where
    there is none, it cannot be read, or it is another suite's or model's.

    :param output: The report folder
    :param suite_name: The suite the report is of
    :param model: ``"final"`` or ``"best"``, the models it evaluated
    """
    path = os.path.join(output, FIGURE_DATA_FILE)
    if not os.path.isfile(path):
        return {}
    try:
        with open(path) as file:
            content = json.load(file)
        # (another suite's or model's file in the same folder draws nothing here)
        if content.get("suite") == suite_name and content.get("model", "final") == model:
            return dict(content.get("runs", {}))
    except (OSError, ValueError, AttributeError):  # unreadable: the runs with folders are drawn, the others not
        pass
    return {}


def refresh_crossings(
    kept: Sequence[tuple[RunSpec, RunResult]], metrics: dict[str, dict[str, Any]], data: dict[str, dict[str, Any]]
) -> int:
    """
    Each kept run's ``threshold_crossing`` told again from the learned-cost curve the report keeps for it (its
    :func:`~sb3_icrl.metrics.identification.headline_crossing`), so that a report updated with today's code tells
    every run's crossing alike. A run with no curve kept whose crossing says only that the cost is at or above 0.5 at
    the safe end (``"everywhere"``, as reports told all three such kinds before they were told apart) becomes
    ``"safe end"``: its shape over the rest of the range is not known.

    :param kept: ``(run, held-out result)`` of the runs kept from the earlier report
    :param metrics: Their metrics by ``result.run``, changed in place
    :param data: The earlier report's figure data by run name (:func:`kept_figure_data`)
    :return: How many crossings changed
    """
    changed = 0
    for run, result in kept:
        entry = metrics.get(result.run)
        if not entry or "threshold_crossing" not in entry:
            continue
        learned = (data.get(run.name) or {}).get("learned_cost") or {}
        crossing = headline_crossing(learned.get("features") or {})
        if crossing is None:
            crossing = "safe end" if entry["threshold_crossing"] == "everywhere" else entry["threshold_crossing"]
        if crossing != entry["threshold_crossing"]:
            entry["threshold_crossing"] = crossing
            changed += 1
    return changed


def figure_data(summary: dict[str, Any], suite: Suite, root: str, output: str) -> dict[str, dict[str, Any]]:
    """
    Per run of the summary (by name), what its figures draw: read from its folder where it has one, else kept from
    the report already in ``output`` (``report --update`` of runs trained elsewhere).

    :return: ``{run name: run_figure_data(...)}``, runs with nothing to draw left out
    """
    model = summary.get("model", "final")
    earlier = kept_figure_data(output, suite.name, model)
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
    the paper, cell by cell, the performance profile, a study's figure (:func:`study_figure`) and that of envs with
    several constraints (:func:`multi_constraint_figure`). PNG files in ``output``, with the data they draw in
    :data:`FIGURE_DATA_FILE`: a report updated where some runs' folders are gone draws them from it.

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
        written.append(str(save_figure(figure, os.path.join(output, "ours_vs_paper.png"))))
    profile = performance_profile_figure(summary)
    if profile is not None:
        written.append(str(save_figure(profile, os.path.join(output, "performance_profile.png"))))
    axis = study_axis(suite)
    if axis is not None:
        study = study_figure(summary, *axis, baseline=summary.get("study_baseline"))
        if study is not None:
            written.append(str(save_figure(study, os.path.join(output, "study.png"))))
    multi = multi_constraint_figure(summary)
    if multi is not None:
        written.append(str(save_figure(multi, os.path.join(output, "multi_constraint.png"))))
    return written


def study_figure(summary: dict[str, Any], key: str, levels: dict[str, float], baseline: dict[str, Any] | None = None) -> Any:
    """
    The paper's study figure from ours: one column per env, the violation rate (top) and the feasible reward (middle)
    of each method against the study's level (:func:`~sb3_icrl.benchmark.study.study_axis`), its mean over seeds joined
    by a line and each seed's value a dot; below them, where the learned costs were scored, their identification AUROC
    the same way, over a grey band from the lowest to the highest AUROC of untrained nets (their mean over the env's
    scored runs whose untrained nets did not all score alike). ``None`` when the summary has no cell of those variants.

    :param summary: A summary of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    :param key: The setting varied (a key of :data:`~sb3_icrl.benchmark.study.STUDY_AXES`)
    :param levels: Each variant's level
    :param baseline: The study's level 0 (:func:`~sb3_icrl.benchmark.study.study_baseline`): drawn at level 0
        beside the study's cells, on the seeds they hold (:func:`~sb3_icrl.benchmark.study.baseline_cells`); a reference
        row that stands for every level (a study of the demonstrations) as a dashed line across them all
    """
    cells = [cell for cell in summary["cells"] if cell["variant"] in levels]
    if not cells:
        return None
    if baseline:
        cells += baseline_cells(baseline, cells)
        levels = {**levels, BASELINE_VARIANT: 0.0}
    envs = list(dict.fromkeys(cell["env"] for cell in cells))
    algos = list(dict.fromkeys(cell["algo"] for cell in cells))
    every_level = {cell["algo"] for cell in cells if cell.get("every_level")}
    metrics = [("violation_rate", "violation rate"), ("feasible_reward", "feasible reward")]
    if any(_finite_values(cell, "identification_auroc") for cell in cells):
        metrics.append(("identification_auroc", "AUROC (grey: untrained range)"))
    figure = new_figure(width=max(4.8, 3.6 * len(envs)), height=3.2 * len(metrics))
    axes = np.asarray(figure.subplots(len(metrics), len(envs), squeeze=False))
    colours = {algo: f"C{index % 10}" for index, algo in enumerate(algos)}
    # Noise levels a decade apart: a log axis; a level of 0 (no noise) needs the linear stretch of a symlog one
    scale: dict[str, Any] = {}
    if key == "transition_noise":
        positive = [level for level in levels.values() if level > 0]
        scale = (
            {"value": "log"} if len(positive) == len(levels) else {"value": "symlog", "linthresh": min(positive, default=1.0)}
        )
    for column, env in enumerate(envs):
        for row, (metric, title) in enumerate(metrics):
            ax = axes[row, column]
            if metric == "identification_auroc":
                _untrained_band(ax, [cell for cell in cells if cell["env"] == env])
            for algo in algos:
                mine = sorted(
                    (
                        (levels[cell["variant"]], _finite_values(cell, metric))
                        for cell in cells
                        if cell["env"] == env and cell["algo"] == algo
                    ),
                    key=lambda pair: pair[0],
                )
                mine = [(level, values) for level, values in mine if values]
                if not mine:
                    continue
                if algo in every_level:  # its level-0 runs stand for every level: a dashed line across them all
                    mean = float(np.mean(mine[0][1]))
                    ax.plot([min(levels.values()), max(levels.values())], [mean, mean], linestyle="--", color=colours[algo])
                else:
                    ax.plot(
                        [level for level, _ in mine], [np.mean(values) for _, values in mine], marker="o", color=colours[algo]
                    )
                for level, values in mine:
                    ax.scatter([level] * len(values), values, s=8, color=colours[algo], alpha=0.35)
            if scale:
                ax.set_xscale(**scale)
            ax.set_xlabel(STUDY_AXES[key])
            ax.set_ylabel(title)
            if row == 0:
                ax.set_title(env)
    # One legend with every method, whichever env it has cells on
    handles = [
        (
            Line2D([], [], linestyle="--", color=colours[algo], label=f"{algo} (level 0)")
            if algo in every_level
            else Line2D([], [], marker="o", color=colours[algo], label=algo)
        )
        for algo in algos
    ]
    # Below the panels, where it hides no point (a column per env leaves little room beside them)
    figure.legend(handles=handles, fontsize=7, loc="outside lower center", ncols=min(len(handles), 4))
    return figure


def multi_constraint_figure(summary: dict[str, Any]) -> Any:
    """
    The paper's figure of several constraints at once (its speed and distance study), from ours: a row per env and
    variant with several constraints, and in it each method's held-out violation rate of each constraint, its feasible
    reward and, where the episodes tell how they ended (the driving envs), its share that reached the goal (the paper's
    success rate); a bar for the mean over seeds, a dot per seed. ``None`` without such cells.

    :param summary: A summary of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    """
    cells, constraints = several_constraint_cells(summary)
    if not cells:
        return None
    panels = [(key, f"{key.removeprefix(CONSTRAINT_VIOLATION_PREFIX)} violation rate") for key in constraints]
    panels.append(("feasible_reward", "feasible reward"))
    goal = OUTCOME_RATE_KEYS["goal_reached"]
    if any(_finite_values(cell, goal) for cell in cells):
        panels.append((goal, "goal reached (success)"))
    tasks = list(dict.fromkeys((cell["env"], cell["variant"]) for cell in cells))
    algos = list(dict.fromkeys(cell["algo"] for cell in cells))
    figure = new_figure(width=3.2 * len(panels), height=3.4 * len(tasks))
    axes = np.asarray(figure.subplots(len(tasks), len(panels), squeeze=False))
    for row, (env, variant) in enumerate(tasks):
        mine = [cell for cell in cells if (cell["env"], cell["variant"]) == (env, variant)]
        positions = np.arange(len(mine))
        for column, (key, title) in enumerate(panels):
            ax = axes[row, column]
            for position, cell in zip(positions, mine, strict=True):
                values = _finite_values(cell, key)
                if values:
                    ax.bar(position, np.mean(values), color=f"C{algos.index(cell['algo']) % 10}")
                    ax.scatter([position] * len(values), values, s=8, color="black", zorder=3)
            ax.set_xticks(positions, [cell["algo"] for cell in mine], rotation=90, fontsize=7)
            ax.set_title(title, fontsize=9)
            if column == 0:
                ax.set_ylabel(f"{env}\n({variant})", fontsize=8)
    return figure


def _finite_values(cell: dict[str, Any], metric: str) -> list[float]:
    """A cell's per-seed values of ``metric`` that are numbers (none where its runs lack it: a reference row's AUROC)."""
    return [float(seed[metric]) for seed in cell["per_seed"] if is_finite_number(seed.get(metric))]


def _untrained_band(ax: Any, cells: list[dict[str, Any]]) -> None:
    """Shade the untrained nets' AUROC range, its low and high each a mean over the runs with a range (not one value)."""
    ranges = [
        (seed["untrained_auroc_low"], seed["untrained_auroc_high"])
        for cell in cells
        for seed in cell["per_seed"]
        if is_finite_number(seed.get("untrained_auroc_low"))
        and is_finite_number(seed.get("untrained_auroc_high"))
        and seed["untrained_auroc_low"] < seed["untrained_auroc_high"]
    ]
    if ranges:
        low, high = np.mean(ranges, axis=0)
        ax.axhspan(low, high, color="0.85", zorder=0)


#: Thresholds of the performance profile: normalised scores from PPO's (0) to beyond the oracle's (1)
PROFILE_TAUS = np.linspace(-0.5, 1.5, 81)


def normalised_scores_by_algo(summary: dict[str, Any]) -> dict[str, list[list[float]]]:
    """
    Per algorithm, the finite per-seed normalised scores of each of its cells in the envs the aggregates take
    (:func:`~sb3_icrl.benchmark.judgements.aggregated_envs`; in a summary written before it, the headline envs), one list
    per env and variant.
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
    return figure
