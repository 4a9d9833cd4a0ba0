"""
The text of a suite's report, from its summary (:func:`~sb3_icrl.benchmark.report.summarise_suite`): the Markdown
table (:func:`markdown_table`) with its cross-env aggregates, judgements, aim, per-constraint violation rates, driving
outcomes, the runs not finished yet and the compute line (the ``*_lines`` and ``*_text`` functions), the LaTeX table
(:func:`latex_table`) and one CSV row per run (:func:`csv_rows`), with the columns they show and the formatting of
summaries' entries (:func:`format_spread`). It reads the summary only: nothing here evaluates a run or judges a cell
(:mod:`~sb3_icrl.benchmark.judgements`); numbers are written as :mod:`~sb3_icrl.benchmark.report_numbers` says.
"""

import csv
import io
import math
from collections.abc import Callable, Sequence
from typing import Any

from sb3_icrl.benchmark.judgements import LAST_TRAINING_COLUMNS, ORACLE_ROW, spread
from sb3_icrl.benchmark.report_numbers import format_hours, format_rate, format_reward, format_score, is_finite_number
from sb3_icrl.benchmark.study import BASELINE_VARIANT, baseline_cells, baseline_line
from sb3_icrl.benchmark.suite import BEATS_COLUMNS
from sb3_icrl.common.env_ids import registered_constraints
from sb3_icrl.common.evaluation import (
    CONSTRAINT_VIOLATION_PREFIX,
    OUTCOME_KEYS,
    OUTCOME_RATE_KEYS,
    constraint_violation_key,
)
from sb3_icrl.common.statistics import MIN_PAIRS_FOR_WILCOXON, sign_test_p
from sb3_icrl.metrics.identification import SAFE_END_CROSSINGS
from sb3_icrl.metrics.transfer import transfer_spent_seconds
from sb3_icrl.run_evaluation import OUTCOME_TITLES, format_outcome_rate
from sb3_icrl.run_folder import LAST_TRAINING_EPISODES

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
    "identification_unconstrained_run",
)


#: The transfer tests' reference learners whose feasible rewards the report keeps beside each ratio
TRANSFER_REFERENCES = ("oracle", "ppo")
#: Transfer columns of the per-seed values, in table order
TRANSFER_COLUMNS = tuple(
    f"transfer_{task}_{metric}"
    for task in ("same", "reward", "dynamics")
    for metric in ("violation_rate", "feasible_ratio", *(f"{reference}_feasible_reward" for reference in TRANSFER_REFERENCES))
)


def _identification_text(seed: dict[str, Any]) -> str:
    """
    ``AUROC / threshold error`` of one seed: ``-`` where the learned cost never reaches 0.5 (or there is no
    threshold); where it is at or above 0.5 at the safe end of the feature's range (no finite error), how it meets the
    level: ``everywhere``, ``reversed`` (below 0.5 at the unsafe end), ``both ends`` (below it between) or ``safe end``
    (a run reported before the three were told apart, its curve not kept). Beside the
    AUROC, untrained nets' median and range (``one draw`` for a run scored when the baseline was a single net, ``on every
    draw`` where all draws scored alike).
    """
    if "identification_auroc" not in seed:
        return "-"
    error = seed.get("threshold_error")
    # (a summary read back from JSON has null for both non-finite errors: its crossing tells them apart)
    crossing = seed.get("threshold_crossing")
    if crossing in SAFE_END_CROSSINGS:
        error_text = str(crossing)
    elif error is not None and math.isinf(error):  # (a seed with no crossing recorded)
        error_text = "safe end"
    else:
        error_text = _fmt(error, 2) if error is not None and math.isfinite(error) else "-"
    untrained, low, high = (seed.get(key) for key in ("untrained_auroc", "untrained_auroc_low", "untrained_auroc_high"))
    if untrained is None or (isinstance(untrained, float) and math.isnan(untrained)):
        baseline = ""
    elif low is None or high is None:  # one net (scored before the baseline took several)
        baseline = f" (untrained {_fmt(untrained, 2)}, one draw)"
    elif low == high:  # every draw alike (a net that starts constant ranks nothing: 0.5)
        baseline = f" (untrained {_fmt(untrained, 2)} on every draw)"
    else:
        baseline = f" (untrained {_fmt(untrained, 2)}, {_fmt(low, 2)}-{_fmt(high, 2)})"
    return f"{_fmt(seed['identification_auroc'], 2)}{baseline} / {error_text}"


def _transfer_text(seed: dict[str, Any]) -> str:
    """
    ``task: violation / feasible-reward ratio`` of each transfer of one seed; where the transfer oracle earns no more
    than the PPO reference (a task whose reward runs toward the line leaves little to earn short of it), the two beside
    it: that ratio says nothing of the learned cost.
    """
    parts = []
    for task in ("same", "reward", "dynamics"):
        if f"transfer_{task}_violation_rate" in seed:
            ratio = seed[f"transfer_{task}_feasible_ratio"]
            text = f"{task} {100 * seed[f'transfer_{task}_violation_rate']:.0f}% / {_fmt(ratio, 2)}"
            oracle, ppo = (seed.get(f"transfer_{task}_{reference}_feasible_reward") for reference in TRANSFER_REFERENCES)
            if oracle is not None and ppo is not None and oracle <= ppo:
                text += f" (oracle {format_reward(oracle)} <= PPO {format_reward(ppo)})"
            parts.append(text)
    return ", ".join(parts) or "-"


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


def format_spread(entry: dict[str, Any] | None, shown: Callable[[float], str] = format_reward) -> str:
    """
    ``IQM c [lo, hi]`` or ``mean c [min, max]`` (:func:`~sb3_icrl.benchmark.judgements.spread`), ``-`` without values.

    :param entry: A :func:`~sb3_icrl.benchmark.judgements.spread`
    :param shown: How a value is written (default: a reward at the precision its size asks for)
    """
    if not entry or not entry["n"]:
        return "-"
    low, high = entry["interval"]
    return f"{'IQM' if entry['kind'] == 'iqm' else 'mean'} {shown(entry['centre'])} [{shown(low)}, {shown(high)}]"


#: Short names of the evaluation columns in the tables
COLUMN_LABELS = {"heldout": "held-out", "last_training": "last training"}


def _verdict_text(verdict: bool | None) -> str:
    return "-" if verdict is None else "yes" if verdict else "no"


def _seeds_note(entry: dict[str, Any]) -> str:
    """
    `` (1 of 5 seeds)`` for a verdict on fewer seeds than the suite runs there, else nothing (older summaries say
    nothing of their seeds).
    """
    n_seeds, of_seeds = entry.get("n_seeds"), entry.get("of_seeds")
    if not n_seeds or of_seeds is None or n_seeds >= of_seeds:
        return ""
    return f" ({n_seeds} of {of_seeds} seeds)"


def beats_judgement_text(judgement: dict[str, Any]) -> str:
    """
    The judgement "beats the paper" in one plain sentence: the rule, each method's count and the outcome.

    :param judgement: A summary's ``beats_judgement`` (:func:`~sb3_icrl.benchmark.judgements.beats_judgement`)
    """
    n_tasks = len(judgement["tasks"])
    columns = " and ".join(COLUMN_LABELS[column] for column in judgement["columns"])
    envs = ", ".join(_task_text(env, variant) for env, variant in judgement["tasks"])
    parts = []
    for method in judgement["methods"]:
        # (the tasks it beats the row on, ``beaten``, in order, each with its seeds)
        named = ", ".join(
            _task_text(entry["env"], entry["variant"]) + _seeds_note(entry)
            for entry in method["tasks"]
            if entry.get("beats") is True
        )
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
    so_far = f" so far, {_runs(pending)} of the judged envs not finished" if pending else ""
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
            (
                " / ".join(_verdict_text(entry[column]) for column in columns) + _seeds_note(entry)
                if entry.get("runs", True)
                else "not run"
            )
            for entry in method["tasks"]
        ]
        judged = method.get("n_tasks", len(judgement["tasks"]))
        lines.append(f"| {method['algo']} | " + " | ".join(entries) + f" | {len(method['beaten'])} of {judged} |")
    text = beats_judgement_text(judgement)
    return [*lines, "", text[0].upper() + text[1:]]


def _percent_interval_text(interval: Sequence[float] | None) -> str:
    """`` [low%, high%]`` of a rate's interval, nothing for one that has none."""
    return f" [{100 * interval[0]:.0f}%, {100 * interval[1]:.0f}%]" if interval is not None else ""


def aim_text(aim: dict[str, Any]) -> str:
    """
    The aim and its outcome in one plain sentence.

    :param aim: A summary's ``aim`` (:func:`~sb3_icrl.benchmark.judgements.aim_outcome`)
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
        verdict += f" so far (provisional: {_runs(pending)} of the headline envs not finished)"
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
    """
    ``Compute: N core-hours of training over M runs`` (runs with a recorded wall time; the CPU time of those that
    recorded one beside their wall time, see :func:`~sb3_icrl.benchmark.report.cpu_compute`) and, where runs have
    transfer tests, their core-hours (:func:`transfer_compute_text`); ``None`` without any training time.
    """
    if summary.get("core_hours") is None:
        return None
    runs = summary.get("core_hours_runs", 0)
    line = f"Compute: {format_hours(summary['core_hours'])} core-hours of training over {runs} runs"
    if summary.get("cpu_hours") is not None:  # the wall clock counts the time a run waited for a shared core
        timed = summary["cpu_hours_runs"]
        line += (
            f" (wall clock; {'all of them' if timed == runs else _runs(timed)} recorded CPU time too: "
            f"{format_hours(summary['cpu_hours'])} CPU-hours against {format_hours(summary['cpu_runs_wall_hours'])} wall)"
        )
    transfer = transfer_compute_text(summary)
    return line if transfer is None else f"{line}; {transfer}"


def transfer_compute(per_seed: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """
    The transfer tests' compute over runs' per-seed entries: ``transfer_runs``, how many runs have a transfer result;
    ``transfer_core_hours_runs``, how many of them a recorded transfer time; ``transfer_core_hours``, their learned-cost
    learners' core-hours plus each reference learner's once, however many runs read it (``None`` when none is timed).
    """
    timed = [seed for seed in per_seed if seed.get("transfer_wall_time_s") is not None]
    seconds = transfer_spent_seconds(
        (float(seed["transfer_wall_time_s"]), seed.get("transfer_reference_wall_time_s") or {}) for seed in timed
    )
    return {
        "transfer_runs": sum(any(column in seed for column in TRANSFER_COLUMNS) for seed in per_seed),
        "transfer_core_hours_runs": len(timed),
        "transfer_core_hours": seconds / 3600 if timed else None,
    }


def transfer_compute_text(summary: dict[str, Any]) -> str | None:
    """
    ``transfer tests X core-hours over K runs (...)`` (:func:`transfer_compute` over the summary's runs): says how many
    runs' transfer tests have no recorded time (reported before times were). ``None`` where no run has a transfer test.
    """
    compute = transfer_compute([seed for cell in summary["cells"] for seed in cell["per_seed"]])
    tested, timed = compute["transfer_runs"], compute["transfer_core_hours_runs"]
    if not tested:
        return None
    if not timed:
        return f"transfer tests of {_runs(tested)} not timed"
    text = f"transfer tests {format_hours(compute['transfer_core_hours'])} core-hours over {_runs(timed)} (references once)"
    untimed = tested - timed
    return text if not untimed else f"{text}, {untimed} more not timed"


def _runs(count: int) -> str:
    """``1 run``, ``2 runs``."""
    return f"{count} run" if count == 1 else f"{count} runs"


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


def ranked_pairs(entry: dict[str, Any]) -> int:
    """The seed pairs a cell's Wilcoxon test ranks (tied seeds left out; a summary written before they were counted
    apart: every pair)."""
    return int(entry.get("wilcoxon_ranked_pairs", entry.get("wilcoxon_pairs")) or 0)


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
    wilcoxon = any(ranked_pairs(cell) >= MIN_PAIRS_FOR_WILCOXON for cell in cells)
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
        p_value = cell.get("wilcoxon_p") if ranked_pairs(cell) >= MIN_PAIRS_FOR_WILCOXON else None
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
    if summary.get("transfer_tests_missing"):
        lines += ["", untested_text(summary)]
    lines += study_level_lines(summary)
    baseline = baseline_line(summary)
    if baseline is not None:
        lines += ["", baseline]
    compute = compute_line(summary)
    if compute is not None:
        lines += ["", compute]
    return "\n".join(lines) + "\n"


def study_level_lines(summary: dict[str, Any]) -> list[str]:
    """
    A study's table by level (none for a suite that is no study): per env and method, the mean held-out feasible
    reward and violation rate of each level, level 0 first where the report has one (on the seeds of the study's own
    runs: :func:`~sb3_icrl.benchmark.study.baseline_cells`), with how many seeds each mean takes; with a level 0, each
    level's change from it paired by seed; and where learned costs were scored, their identification by level (mean
    AUROC, and how many seeds score above untrained nets).

    :param summary: A summary of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    """
    study: dict[str, Any] = summary.get("study") or {}
    levels: dict[str, float] = study.get("levels", {})
    cells = [cell for cell in summary["cells"] if cell["variant"] in levels]
    if not cells:
        return []
    variants = sorted(levels, key=lambda variant: levels[variant])
    baseline: dict[str, Any] = summary.get("study_baseline") or {}
    level_0 = baseline_cells(baseline, cells) if baseline else []
    columns = ([f"{BASELINE_VARIANT} ({baseline['suite']})"] if level_0 else []) + variants
    by_key = {(cell["env"], cell["algo"], cell["variant"]): cell for cell in [*cells, *level_0]}
    keys = list(dict.fromkeys((cell["env"], cell["algo"]) for cell in cells))
    # The reference rows a study of the demonstrations takes from level 0, each after its env's methods
    every_level = [(cell["env"], cell["algo"]) for cell in level_0 if cell.get("every_level")]
    rows = [key for env in dict.fromkeys(env for env, _ in keys) for key in [*keys, *every_level] if key[0] == env]
    shown = ([BASELINE_VARIANT] if level_0 else []) + variants

    def text(env: str, algo: str, variant: str, cell_text: Callable[[dict[str, Any]], str]) -> str:
        if (env, algo) in every_level and variant != BASELINE_VARIANT:
            return "as level 0"
        cell = by_key.get((env, algo, variant))
        return (cell_text(cell) if cell is not None else "") or "-"

    reference = " and ".join(dict.fromkeys(algo for _, algo in every_level))
    intro = (
        f"By level of {study['setting']} (mean held-out feasible reward / violation rate over each cell's seeds, their "
        "number in brackets"
        + (f"; {BASELINE_VARIANT}: the same seeds' runs of suite {baseline['suite']!r}" if level_0 else "")
        + (f"; {reference} learn from no demonstrations: their level-0 runs stand for every level" if reference else "")
        + "):"
    )
    lines = _table_by_level(intro, columns, {key: [text(*key, variant, _level_text) for variant in shown] for key in rows})
    lines += _demonstration_lines(study, [BASELINE_VARIANT, *variants], [env for env, _ in keys])
    if level_0:
        paired = {
            (env, algo): [
                _paired_text(by_key.get((env, algo, BASELINE_VARIANT)), by_key.get((env, algo, v))) for v in variants
            ]
            for env, algo in keys
        }
        lines += _table_by_level(
            "Change from level 0, paired by seed (over the seeds a level and level 0 both hold: the mean of the level's "
            "feasible reward minus level 0's / of its violation rate minus level 0's in points; then the seeds paired, "
            "how many of them earned less, and the exact two-sided sign test's p-value of that split, over the seeds whose "
            "reward changed: with 5 seeds it cannot go below 0.0625, with 4 below 0.125):",
            variants,
            paired,
        )
    identification = {key: [text(*key, variant, _level_identification_text) for variant in shown] for key in keys}
    identification = {key: row for key, row in identification.items() if any(entry != "-" for entry in row)}
    if identification:
        lines += _table_by_level(
            "Identification by level (the learned cost's mean identification AUROC over each cell's seeds; then how many of "
            "them score above the highest AUROC of untrained nets of the same architecture, the range a cost that learned "
            "nothing of the constraint can reach):",
            columns,
            identification,
        )
    return lines


def _demonstration_lines(study: dict[str, Any], variants: list[str], envs: list[str]) -> list[str]:
    """
    For a study of the demonstrations, what each level's held (``study["demonstrations"]``): a row per env the report
    has runs of, a column per level; none for another study.
    """
    every_env: dict[str, dict[str, dict[str, Any]]] = study.get("demonstrations") or {}
    held = {env: every_env[env] for env in dict.fromkeys(envs) if env in every_env}
    if not held:
        return []

    def text(facts: dict[str, Any] | None) -> str:
        if facts is None:
            return "-"
        return (
            f"{facts['violating_trajectories']} of {facts['trajectories']} / {format_rate(facts['violating_step_share'])} "
            f"/ {format_reward(facts['mean_return'])}"
        )

    lines = [
        "",
        "The demonstrations of each level (what its runs learned from, counted from their true costs: the trajectories "
        "that break the constraint, the share of all their steps in the constrained region, their mean return):",
        "",
        "| env | " + " | ".join(variants) + " |",
        "|---" * (len(variants) + 1) + "|",
    ]
    return lines + [
        f"| {env} | " + " | ".join(text(by_level.get(v)) for v in variants) + " |" for env, by_level in held.items()
    ]


def _table_by_level(intro: str, columns: list[str], rows: dict[tuple[str, str], list[str]]) -> list[str]:
    """One of a study's tables: after a blank line its introduction, then a row per env and method, a column per level."""
    lines = ["", intro, "", "| env | algo | " + " | ".join(columns) + " |", "|---" * (len(columns) + 2) + "|"]
    return lines + [f"| {env} | {algo} | " + " | ".join(row) + " |" for (env, algo), row in rows.items()]


def _level_identification_text(cell: dict[str, Any]) -> str:
    """
    One cell of a study's identification table: ``mean AUROC (k of n above untrained)`` over the seeds with an AUROC
    (a seed without the untrained nets' range counts as not above; where the untrained nets of every seed scored one
    value alike, that value is named); empty for a cell without one (a reference row).
    """
    scored = [seed for seed in cell["per_seed"] if is_finite_number(seed.get("identification_auroc"))]
    if not scored:
        return ""
    mean = sum(seed["identification_auroc"] for seed in scored) / len(scored)
    highs = [seed.get("untrained_auroc_high") for seed in scored]
    above = sum(
        is_finite_number(high) and seed["identification_auroc"] > high for seed, high in zip(scored, highs, strict=True)
    )
    # Untrained nets that all score alike (a cost net that starts constant ranks nothing: 0.5) make "above" a low bar
    alike = all(
        is_finite_number(high) and seed.get("untrained_auroc_low") == high for seed, high in zip(scored, highs, strict=True)
    )
    value = f", all {highs[0]:.2f}" if alike and len(set(highs)) == 1 else ""
    return f"{mean:.2f} ({above} of {len(scored)} above untrained{value})"


def _paired_text(base: dict[str, Any] | None, cell: dict[str, Any] | None) -> str:
    """
    One cell of the paired changes: ``+/-reward / +/-points (n paired, k lower, sign test p = P)``, ``-`` without a
    pair (:func:`~sb3_icrl.common.statistics.sign_test_p` of the reward changes).
    """
    if base is None or cell is None:
        return "-"
    level_0 = {seed["seed"]: seed for seed in base["per_seed"]}
    pairs = [
        (seed["feasible_reward"] - level_0[seed["seed"]]["feasible_reward"], seed, level_0[seed["seed"]])
        for seed in cell["per_seed"]
        if seed["seed"] in level_0
        and is_finite_number(seed["feasible_reward"])
        and is_finite_number(level_0[seed["seed"]]["feasible_reward"])
    ]
    if not pairs:
        return "-"
    reward = sum(change for change, _, _ in pairs) / len(pairs)
    rates = [
        seed["violation_rate"] - zero["violation_rate"]
        for _, seed, zero in pairs
        if is_finite_number(seed["violation_rate"]) and is_finite_number(zero["violation_rate"])
    ]
    points = f"{100 * sum(rates) / len(rates):+.0f} pts" if rates else "-"
    sign = "+" if reward >= 0 else "-"
    lower = sum(change < 0 for change, _, _ in pairs)
    p_value = sign_test_p([change for change, _, _ in pairs])
    test = f", sign test p = {p_value:.3g}" if is_finite_number(p_value) else ", no seed changed"
    return f"{sign}{format_reward(abs(reward))} / {points} ({len(pairs)} paired, {lower} lower{test})"


def _level_text(cell: dict[str, Any]) -> str:
    """One cell of a study's table by level: ``feasible / violation (seeds)``."""
    reward, rate = cell["feasible_reward_mean"], cell["violation_rate_mean"]
    shown = [format_reward(reward) if is_finite_number(reward) else "-", format_rate(rate) if is_finite_number(rate) else "-"]
    return f"{shown[0]} / {shown[1]} ({len(cell['per_seed'])})"


#: Up to this many runs of a list (those not finished, those without a transfer test) are named one by one; more are
#: counted
MAX_MISSING_NAMED = 12


def not_finished_text(summary: dict[str, Any]) -> str:
    """
    The runs not finished yet: named when there are few (:data:`MAX_MISSING_NAMED`), else counted per env and variant
    (the summary's ``runs_missing`` still names them all).

    :param summary: A summary of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    """
    missing, by_task = summary["runs_missing"], summary.get("runs_missing_by_env")
    if len(missing) <= MAX_MISSING_NAMED or not by_task:
        return f"Not finished yet ({len(missing)}): " + ", ".join(missing)
    counts = "; ".join(f"{_task_text(env, variant)} {left} of {total}" for env, variant, left, total in by_task)
    return f"Not finished yet ({len(missing)} runs, all named in summary.json's `runs_missing`): {counts}."


def untested_text(summary: dict[str, Any]) -> str:
    """
    The finished runs without a transfer result their suite asks for: named when there are few
    (:data:`MAX_MISSING_NAMED`), else counted (the summary's ``transfer_tests_missing`` names them all).

    :param summary: A summary of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    """
    untested = summary["transfer_tests_missing"]
    head = f"Finished without the transfer tests the suite asks for, their transfer columns empty ({len(untested)})"
    if len(untested) <= MAX_MISSING_NAMED:
        return f"{head}: " + ", ".join(untested)
    return f"{head}, all named in summary.json's `transfer_tests_missing`."


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


#: Below this many runs of a method in the cross-env aggregates, the report says their intervals are rough (the
#: fresh-seed protocol reports 10 seeds of an env)
FEW_AGGREGATED_RUNS = 10


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
    few = sorted({entry["n_runs"] for entry in aggregates if entry["n_runs"] < FEW_AGGREGATED_RUNS})
    if few:
        counts = f"{few[0]}" if len(few) == 1 else f"{few[0]}-{few[-1]}"
        lines += [
            "",
            f"Few runs: {counts} per method in these aggregates (under {FEW_AGGREGATED_RUNS}). Percentile bootstrap "
            "intervals from so few runs tend to be too narrow, and a probability of improvement of 0 or 1 then has a "
            "zero-width interval however few runs agree: read them as rough; the per-seed values in the table are the "
            "evidence.",
        ]
    return lines


def _interval_text(interval: Sequence[float] | None) -> str:
    """`` [low, high]`` of an aggregate's interval, nothing for one that has none (one run per env)."""
    return f" [{interval[0]:.2f}, {interval[1]:.2f}]" if interval is not None else ""


def _aggregated_text(summary: dict[str, Any]) -> str:
    """What the cross-env aggregates of a summary take (:func:`~sb3_icrl.benchmark.judgements.aggregated_envs`) and
    leave out, ending the line that introduces them; for a summary written before they were recorded, its headline envs."""
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
    """
    The per-seed keys of each constraint's violation rate in a summary: in the order its envs are registered with
    them (velocity before distance), then by name; the same whether the cells come from runs or from a summary.json,
    which keeps its keys sorted.
    """
    columns: set[str] = set()
    for cell in summary["cells"]:
        for seed in cell["per_seed"]:
            columns.update(key for key in seed if key.startswith(CONSTRAINT_VIOLATION_PREFIX))
    declared = dict.fromkeys(
        constraint_violation_key(name) for cell in summary["cells"] for name in registered_constraints(cell["env"])
    )
    rank = {key: position for position, key in enumerate(declared)}
    return sorted(columns, key=lambda key: (rank.get(key, len(rank)), key))


def several_constraint_cells(summary: dict[str, Any]) -> tuple[list[dict[str, Any]], list[str]]:
    """
    The cells of envs with several constraints, and the keys of the constraints they report
    (:func:`constraint_columns`, in that order): what the table of each constraint and its figure show.

    :param summary: A summary of :func:`~sb3_icrl.benchmark.report.summarise_suite`
    :return: ``(cells, keys)``, both empty for a summary without such cells
    """
    cells = [cell for cell in summary["cells"] if len(cell.get("constraint_violation_rates_mean") or {}) > 1]
    reported = {key for cell in cells for key in cell["constraint_violation_rates_mean"]}
    keys = [key for key in constraint_columns(summary) if key in reported]
    return cells, keys


def constraint_lines(summary: dict[str, Any]) -> list[str]:
    """
    For the cells of envs with several constraints: each constraint's violation rate beside the overall one (an
    episode that breaks any) and the feasible reward, mean over seeds and per seed, as Markdown lines after a blank
    line; no lines for a summary without such cells.
    """
    cells, columns = several_constraint_cells(summary)
    if not cells:
        return []
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
            "cpu_time_s",
            "transfer_wall_time_s",
            "training_starts",
            "constraint_updates",
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
                    _csv_number(seed["feasible_reward"]),
                    _csv_number(seed["violation_rate"]),
                    _csv_number(seed["reward"]),
                    seed["timesteps"],
                    seed["n_episodes"],
                    _csv_number(seed.get("episode_length")),
                    *(_csv_number(seed.get(column)) for column in (*OUTCOME_COLUMNS, *per_constraint)),
                    *(
                        _csv_number(seed.get(column))
                        for column in (*IDENTIFICATION_COLUMNS, *TRANSFER_COLUMNS, *LAST_TRAINING_COLUMNS)
                    ),
                    _csv_number(seed.get("wall_time_s")),
                    _csv_number(seed.get("cpu_time_s")),
                    _csv_number(seed.get("transfer_wall_time_s")),
                    seed.get("training_starts", ""),
                    seed.get("constraint_updates", ""),
                    seed.get("git_revision", ""),
                    *("" if value is None else value for value in (cell.get("expert_return"), *numbers)),
                ]
            )
    return buffer.getvalue()


def _csv_number(value: Any) -> Any:
    """
    A value for the CSV: a number as it is, empty when it is unknown (``None`` or NaN) or infinite, as the summary keeps
    it (strict JSON: :func:`~sb3_icrl.benchmark.report_numbers.finite_or_null`), so that a report written from fresh
    runs and one updated from its summary give the same file (an infinite threshold error has its reason in
    ``threshold_crossing``).
    """
    return "" if value is None or (isinstance(value, float) and not math.isfinite(value)) else value
