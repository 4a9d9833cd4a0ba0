"""
Where a suite stands, read from its run folders without touching them: which runs finished, which are training now,
which stopped part-way (they resume from their last checkpoint), which failed and which never started, with the
core-hours spent and an estimate of those left.
"""

import json
import os
import warnings
from dataclasses import dataclass, field
from typing import Any

import yaml

from sb3_icrl.benchmark.report_numbers import is_finite_number
from sb3_icrl.benchmark.study import read_report_summary
from sb3_icrl.benchmark.suite import RunSpec, result_current
from sb3_icrl.common.saved import model_damage
from sb3_icrl.common.utils import held_lock_inodes, lock_held
from sb3_icrl.hyperparams import load_hyperparams
from sb3_icrl.metrics.transfer import TransferProgress, transfer_progress, transfer_spent_seconds, transfer_times
from sb3_icrl.registry import REFERENCE_ALGOS, env_name
from sb3_icrl.run_folder import (
    checkpoints,
    failure,
    finished_wall_time,
    is_finished,
    read_finished,
    training_progress,
    training_time_so_far,
    unreadable_finished,
)

#: The states of a run, in the order the summary line counts them
STATES = ("finished", "reported", "running", "interrupted", "failed", "not started")
#: The states of a run that needs no more training: its folder here finished, or a committed report holds it
DONE_STATES = ("finished", "reported")


@dataclass
class RunStatus:
    """
    Where one run stands.

    :param run: The run
    :param state: One of :data:`STATES`: ``"reported"`` when it has no folder here but a committed report holds it
        (:func:`mark_reported`), ``"running"`` when a process on this machine holds its lock (a suite trains
        it now; a run training on another machine of a cluster shows as interrupted),
        ``"interrupted"`` when it has a folder but neither finished nor failed (the suite resumes it), ``"failed"``
        when its training stopped on an error (``failed.json``)
    :param steps_done: Env steps of its final model or last checkpoint (``None`` before the first checkpoint); of a
        running run, of its last episode's end where that is newer
    :param steps_total: The steps it trains for (``None`` when they cannot be told)
    :param wall_time_s: Training time of a finished run; of a running run, its training time so far as its attempt
        record tells it (:func:`~sb3_icrl.run_folder.training_time_so_far`), else its Monitor files
        (:func:`~sb3_icrl.run_folder.training_progress`)
    :param error: The error of a failed run
    :param note: What is wrong with a run's files that its state does not tell: a finished run whose final model is
        missing or damaged (the report leaves it out), a ``finished.json`` that does not read; a finished run's transfer
        tests still to come or running
    :param transfers_due: How many transfer tests the suite asks of the run (its ICRL runs on its transfer envs)
    :param transfers_left: How many of them are still to come (a run the suite skips, being reported, has none left)
    :param transfer_wall_time_s: Seconds the learned-cost learners of its transfer tests done so far trained
    :param transfer_references_s: Per reference file those tests read (by name), the seconds its learner trained
    """

    run: RunSpec
    state: str
    steps_done: int | None = None
    steps_total: int | None = None
    wall_time_s: float | None = None
    error: str | None = None
    note: str | None = None
    transfers_due: int = 0
    transfers_left: int = 0
    transfer_wall_time_s: float | None = None
    transfer_references_s: dict[str, float] = field(default_factory=dict)


def planned_steps(run: RunSpec, root: str, recipes: dict[tuple[str, ...], int | None] | None = None) -> int | None:
    """
    The steps a run trains for: the suite's ``steps``, else ``n_timesteps`` of the recipe the run saved
    (``config.yml``), else of the shipped recipe with the variant's hyper-parameters.

    :param recipes: Steps of the shipped recipes already read, by (algorithm, env, variant hyper-parameters): the runs
        of one cell share them, and each read parses the whole yml file
    :return: Steps, or ``None`` when no recipe tells them (an env the suite's packages register, not imported here)
    """
    if run.steps is not None:
        return run.steps
    config = os.path.join(run.run_folder(root), env_name(run.env_id), "config.yml")
    try:
        with open(config) as file:
            saved = yaml.safe_load(file)
        return int(float(saved["n_timesteps"]))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError):
        pass
    overrides = run.variant_settings.get("hyperparams") or {}
    forward_recipe = run.forward_recipe if run.algo in REFERENCE_ALGOS else None
    key = (run.algo, run.env_id, repr(sorted(overrides.items())), forward_recipe or "")
    if recipes is not None and key in recipes:
        return recipes[key]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the fallback entry of an unknown env says so once per process
            entry, _ = load_hyperparams(run.algo, run.env_id, dict(overrides), forward_recipe=forward_recipe)
        steps: int | None = int(float(entry["n_timesteps"]))
    except Exception:  # a recipe that cannot be read here is reported as unknown steps, not as an error
        steps = None
    if recipes is not None:
        recipes[key] = steps
    return steps


def run_status(
    run: RunSpec, root: str, locked_inodes: set[int] | None, recipes: dict[tuple[str, ...], int | None] | None = None
) -> RunStatus:
    """
    :param run: The run
    :param root: The log root (``-f``)
    :param locked_inodes: :func:`~sb3_icrl.common.utils.held_lock_inodes` (``None``: a run that is neither finished
        nor failed counts as interrupted)
    :param recipes: See :func:`planned_steps`
    """
    status = _training_status(run, root, locked_inodes, recipes)
    jobs = run.transfer_jobs(root)
    if not jobs:
        return status
    status.transfers_due = status.transfers_left = len(jobs)
    if status.state != "finished":
        return status
    folder = run.run_folder(root)
    done = []
    for result_file, _ in jobs:
        if not result_current(folder, result_file):
            continue
        status.transfers_left -= 1
        try:
            with open(os.path.join(folder, result_file)) as file:
                saved = json.load(file)
        except (OSError, ValueError):  # a result that does not read is timed as unknown
            continue
        if isinstance(saved, dict):
            done.append(saved)
    status.transfer_wall_time_s, status.transfer_references_s = transfer_times(done)
    if status.transfers_left:
        running = lock_held(folder + ".lock", locked_inodes)
        tests = f"{status.transfers_left} transfer test{'s' if status.transfers_left > 1 else ''}"
        progress = transfer_progress(run.log_file(root)) if running else None
        tests += " running" if running else " to come"
        if progress is not None:
            tests += f": {progress_words(progress)}"
        notes = [status.note, tests]
        status.note = "; ".join(note for note in notes if note)
    return status


def progress_words(progress: TransferProgress) -> str:
    """
    A transfer test's progress in words.

    :param progress: Its learner under way (:func:`~sb3_icrl.metrics.transfer.transfer_progress`)
    :return: E.g. ``the reward task's learned learner at 600,000 / 2,000,000 steps, about 8 min left at its pace``
    """
    if progress.waiting:
        return f"the {progress.task} task waits for its {progress.learner} reference, which another run is training"
    learner = f"the {progress.task} task's {progress.learner} learner"
    if progress.steps >= progress.total:
        return f"{learner} trained, being evaluated"
    words = f"{learner} at {progress.steps:,} / {progress.total:,} steps"
    if progress.steps_per_s:
        words += f", about {(progress.total - progress.steps) / progress.steps_per_s / 60:.0f} min left at its pace"
    return words


def _training_status(
    run: RunSpec, root: str, locked_inodes: set[int] | None, recipes: dict[tuple[str, ...], int | None] | None
) -> RunStatus:
    """Where the run's training stands (:func:`run_status` without its transfer tests)."""
    folder = run.run_folder(root)
    total = planned_steps(run, root, recipes)
    if is_finished(folder):
        finished = read_finished(folder) or {}
        done: int | None
        try:
            done = int(finished["num_timesteps"])
        except (KeyError, TypeError, ValueError):
            done = total
        return RunStatus(run, "finished", done, total, finished_wall_time(finished), note=_final_model_note(run, folder))
    saved = checkpoints(folder)
    newest = saved[0][0] if saved else None
    # The lock first: a failed run that a suite tries again keeps its failed.json until its training starts
    if lock_held(folder + ".lock", locked_inodes):
        progress = training_progress(folder)
        # A resumed run's Monitor clock runs on through the time it lay stopped: its attempt record tells its time
        so_far = training_time_so_far(folder, not_before=_mtime(folder + ".lock"))
        if progress is None:
            return RunStatus(run, "running", newest, total, wall_time_s=so_far)
        steps, seconds = progress
        # Episodes end between checkpoints, so the Monitor files are the newer count; a checkpoint can be newer only
        # in the middle of a long episode
        return RunStatus(run, "running", max(steps, newest or 0), total, wall_time_s=so_far if so_far is not None else seconds)
    resumed, damaged = _resumable_checkpoint(saved)
    error = failure(folder)
    if error is not None:
        return RunStatus(run, "failed", resumed, total, error=error, note=damaged)
    if os.path.isdir(folder):
        notes = [note for note in (unreadable_finished(folder), damaged) if note]
        return RunStatus(run, "interrupted", resumed, total, note="; ".join(notes) or None)
    if os.path.exists(folder):
        note = f"{folder} is a file, not a run folder: move it away, or the suite cannot train the run"
        return RunStatus(run, "not started", None, total, note=note)
    return RunStatus(run, "not started", None, total)


def _mtime(path: str) -> float | None:
    """A file's modification time, ``None`` where it cannot be read."""
    try:
        return os.path.getmtime(path)
    except OSError:
        return None


def _resumable_checkpoint(saved: list[tuple[int, str]]) -> tuple[int | None, str | None]:
    """
    :param saved: The run's checkpoints, the most steps first (:func:`~sb3_icrl.run_folder.checkpoints`)
    :return: The steps of the newest checkpoint whose zip reads (``None``: none does), and what is wrong with the newer
        ones that do not (``None`` when there are none), as the note of the run
    """
    damaged: list[str] = []
    steps: int | None = None
    for saved_steps, path in saved:
        what = model_damage(path, load=False)  # (as quick as for the final models: no tensor is built)
        if what is None:
            steps = saved_steps
            break
        damaged.append(f"{path} {what}")
    if not damaged:
        return steps, None
    more = f" (and {len(damaged) - 1} newer one{'s' if len(damaged) > 2 else ''})" if len(damaged) > 1 else ""
    then = (
        f"the suite resumes the run from its checkpoint at {steps:,} steps"
        if steps is not None
        else "no checkpoint loads, so the suite trains the run again from the start"
    )
    return steps, f"its checkpoint {damaged[-1]}{more}: {then}"


def _final_model_note(run: RunSpec, folder: str) -> str | None:
    """Why a finished run's final model cannot be evaluated (missing, or a zip that does not read), else ``None``."""
    final = os.path.join(folder, f"{env_name(run.env_id)}.zip")
    # Whether the zip and its tensor archives read, without building the tensors (about 1 ms a model): status stays
    # quick on a suite of hundreds of runs
    what = "is missing" if not os.path.isfile(final) else model_damage(final, load=False)
    if what is None:
        return None
    return f"its final model {final} {what}: the report leaves it out; delete its finished.json to train it again"


def suite_status(runs: list[RunSpec], root: str) -> list[RunStatus]:
    """The status of each run, in the order given."""
    locked = held_lock_inodes()
    recipes: dict[tuple[str, ...], int | None] = {}
    return [run_status(run, root, locked, recipes) for run in runs]


def report_pace(report_folder: str) -> dict[tuple[str, str], list[float]]:
    """
    The pace of the runs a report holds, of any suite and variant: per env and algorithm, each run's training seconds
    per step. ``status --pace-from`` lends it to the runs whose own variant and env have no finished run yet, to plan a
    suite by core-hours before it starts (a study on the table's recipes, say, at the table's pace).

    :param report_folder: The report's folder (``-o`` of ``benchmark report``)
    :return: ``{(env name, algo): [seconds per step, ...]}``; runs without a positive training time and steps are left
        out
    :raises ValueError: When the report cannot be read, names no env or algo for a cell, or has no run to go by
    """
    summary = read_report_summary(report_folder, "--pace-from")
    pace: dict[tuple[str, str], list[float]] = {}
    for cell in summary["cells"]:
        if not isinstance(cell, dict) or not isinstance(cell.get("env"), str) or not isinstance(cell.get("algo"), str):
            raise ValueError(f"--pace-from {report_folder}: a cell of its summary.json names no env and algo: {cell!r:.200}")
        for seed in cell.get("per_seed", []):
            wall_time, steps = seed.get("wall_time_s"), seed.get("timesteps")
            if is_finite_number(wall_time) and wall_time > 0 and is_finite_number(steps) and steps > 0:
                pace.setdefault((env_name(cell["env"]), cell["algo"]), []).append(float(wall_time) / float(steps))
    if not pace:
        raise ValueError(f"--pace-from {report_folder}: its runs have no training time and steps to take a pace from.")
    return pace


def reported_runs(report_folder: str, suite_name: str, recipe_version: str | None) -> dict[tuple[str, str, str, int], dict]:
    """
    The runs a committed report of the suite holds (its ``summary.json``), at the suite's recipe version: on a machine
    where their folders are gone (trained elsewhere, or on a machine since given back), they need no training again.

    :param report_folder: The report's folder (``-o`` of ``benchmark report``)
    :param suite_name: The suite's name (the report must be that suite's)
    :param recipe_version: The suite's recipe version: a run the report holds at another version is not counted
    :return: ``{(*cell, seed): {"wall_time_s": ..., "timesteps": ..., "transfer_wall_time_s": ...,
        "transfer_reference_wall_time_s": {...}}}``, keyed as a run's :attr:`~sb3_icrl.benchmark.suite.RunSpec.cell`
        and seed
    """
    summary = read_report_summary(report_folder, "--reported")
    if summary.get("suite") != suite_name:
        raise ValueError(f"--reported {report_folder}: a report of suite {summary.get('suite')!r}, not of {suite_name!r}.")
    runs: dict[tuple[str, str, str, int], dict] = {}
    for cell in summary.get("cells", []):
        for seed in cell.get("per_seed", []):
            if recipe_version is not None and seed.get("recipe_version", recipe_version) != recipe_version:
                continue
            key = (str(cell["env"]), str(cell["variant"]), str(cell["algo"]), int(seed["seed"]))
            runs[key] = {
                "wall_time_s": seed.get("wall_time_s"),
                "timesteps": seed.get("timesteps"),
                "transfer_wall_time_s": seed.get("transfer_wall_time_s"),
                "transfer_reference_wall_time_s": seed.get("transfer_reference_wall_time_s") or {},
            }
    return runs


def mark_reported(statuses: list[RunStatus], reported: dict[tuple[str, str, str, int], dict]) -> list[RunStatus]:
    """
    A run with no folder here (``"not started"``) that a committed report holds (:func:`reported_runs`) is
    ``"reported"``, with the report's training time and steps; a run with a folder keeps the state its folder gives.

    :param statuses: The runs' statuses (:func:`suite_status`)
    :param reported: The report's runs
    :return: The statuses, those runs marked
    """
    marked = []
    for status in statuses:
        run = status.run
        entry = reported.get((*run.cell, run.seed))
        if status.state == "not started" and entry is not None:
            wall_time = entry.get("wall_time_s")
            steps = entry.get("timesteps")
            status = RunStatus(
                run,
                "reported",
                steps_done=int(steps) if steps is not None else None,
                steps_total=status.steps_total,
                wall_time_s=float(wall_time) if wall_time is not None else None,
                # The suite does not take a reported run up again: none of its transfer tests is left to come
                transfers_due=status.transfers_due,
                transfer_wall_time_s=entry.get("transfer_wall_time_s"),
                transfer_references_s=dict(entry.get("transfer_reference_wall_time_s") or {}),
            )
        marked.append(status)
    return marked


def own_pace(status: RunStatus) -> float | None:
    """
    A running run's own pace so far, in seconds per step (it trains on this machine, at its load, now); ``None`` for
    a run that is not running or whose attempt record and Monitor files tell no time yet.
    """
    if status.state != "running" or not status.wall_time_s or not status.steps_done:
        return None
    return status.wall_time_s / status.steps_done


def seconds_left(statuses: list[RunStatus], lent_pace: dict[tuple[str, str], list[float]] | None = None) -> tuple[float, int]:
    """
    The training time left, at the pace (seconds per step) of the finished runs of the same variant, env and
    algorithm, else of the same variant and env; a running run at its own pace so far (:func:`own_pace`). Variants can
    change the learner (a recipe at another throughput), so another variant's pace is not used.

    :param lent_pace: A pace per env name and algorithm from elsewhere (:func:`report_pace`), for the runs with no
        finished run of their own variant, env and algorithm: before the pace of their variant and env's other runs
    :return: ``(seconds, runs not estimated)``: runs whose steps are unknown or whose variant and env have no finished
        run (nor a lent pace)
    """
    pace: dict[Any, list[float]] = {}
    for status in statuses:
        if status.state in DONE_STATES and status.wall_time_s and status.steps_done:
            rate = status.wall_time_s / status.steps_done
            run = status.run
            pace.setdefault((run.variant, run.env_id, run.algo), []).append(rate)
            pace.setdefault((run.variant, run.env_id), []).append(rate)
    seconds, unknown = 0.0, 0
    for status in statuses:
        if status.state in DONE_STATES:
            continue
        run = status.run
        lent = lent_pace.get((env_name(run.env_id), run.algo)) if lent_pace else None
        # The same algorithm's pace first, this suite's or else the report's; then this variant and env's other runs'
        rates = pace.get((run.variant, run.env_id, run.algo)) or lent or pace.get((run.variant, run.env_id))
        own = own_pace(status)
        if own is not None:
            rates = [own]
        if status.steps_total is None or not rates:
            unknown += 1
            continue
        left = max(status.steps_total - (status.steps_done or 0), 0)
        seconds += left * sum(rates) / len(rates)
    return seconds, unknown


def transfer_seconds(statuses: list[RunStatus]) -> tuple[float, float, int]:
    """
    The transfer tests' compute: spent (the learned-cost learners of the tests done, each reference learner once) and
    left, at the pace of the tests done on the same variant and env: each test to come takes their learned-cost
    learners' mean time, and an env and seed none of whose runs has a test done yet also their references' mean time
    per env and seed (one task's worth).

    :return: ``(seconds spent, seconds left, tests to come not estimated)``: tests whose variant and env have no timed
        test done
    """
    learned_pace: dict[tuple[str, str], list[float]] = {}
    references_by_seed: dict[tuple[str, str, int], dict[str, float]] = {}
    tested_seeds: set[tuple[str, str, int]] = set()
    for status in statuses:
        run = status.run
        done = status.transfers_due - status.transfers_left
        if done > 0:
            tested_seeds.add((run.variant, run.env_id, run.seed))
        if done > 0 and status.transfer_wall_time_s is not None:
            learned_pace.setdefault((run.variant, run.env_id), []).append(status.transfer_wall_time_s / done)
        if status.transfer_references_s:
            references_by_seed.setdefault((run.variant, run.env_id, run.seed), {}).update(status.transfer_references_s)
    spent = transfer_spent_seconds(
        (
            status.transfer_wall_time_s if status.transfers_due > status.transfers_left else None,
            status.transfer_references_s or {},
        )
        for status in statuses
    )
    reference_pace: dict[tuple[str, str], list[float]] = {}
    for (variant, env_id, _), references in references_by_seed.items():
        reference_pace.setdefault((variant, env_id), []).append(sum(references.values()))
    left, unknown = 0.0, 0
    untested: set[tuple[str, str, int]] = set()
    for status in statuses:
        run = status.run
        if not status.transfers_left:
            continue
        pace = learned_pace.get((run.variant, run.env_id))
        if not pace:
            unknown += status.transfers_left
            continue
        left += status.transfers_left * sum(pace) / len(pace)
        if (run.variant, run.env_id, run.seed) not in tested_seeds:
            untested.add((run.variant, run.env_id, run.seed))
    for variant, env_id, _ in untested:
        paces = reference_pace.get((variant, env_id))
        left += sum(paces) / len(paces) if paces else 0.0
    return spent, left, unknown


def status_lines(
    statuses: list[RunStatus], verbose: bool = False, lent_pace: tuple[str, dict[tuple[str, str], list[float]]] | None = None
) -> list[str]:
    """
    One line per run that is neither finished nor reported or has a note (every run with ``verbose``), then the counts,
    the core-hours spent and the estimate of those left.

    :param lent_pace: ``(its source, the pace)``: a pace per env name and algorithm (:func:`report_pace`) for the runs
        whose variant and env have no finished run; the summary says how many runs and hours it estimates
    """
    lines = []
    shown = [status for status in statuses if verbose or status.state not in DONE_STATES or status.note]
    if shown:
        lines.append(f"{'state':12s} {'steps':>21s} {'train time':>10s}  run")
        for status in shown:
            done = "-" if status.steps_done is None else f"{status.steps_done:,}"
            total = "?" if status.steps_total is None else f"{status.steps_total:,}"
            time_text = "-" if status.wall_time_s is None else f"{status.wall_time_s / 60:.1f} min"
            line = f"{status.state:12s} {done + ' / ' + total:>21s} {time_text:>10s}  {status.run.name}"
            pace = own_pace(status)
            if pace is not None and status.steps_total is not None and status.steps_done is not None:
                left = max(status.steps_total - status.steps_done, 0) * pace
                line += f" (about {left / 60:.0f} min of training left at its pace so far)"
            if status.error:
                line += f": {status.error.strip().splitlines()[0] if status.error.strip() else 'unknown error'}"
            if status.note:
                line += f" ({status.note})"
            lines.append(line)
        lines.append("")
    counts = {state: sum(status.state == state for status in statuses) for state in STATES}
    spent = sum(status.wall_time_s or 0.0 for status in statuses if status.state in DONE_STATES) / 3600
    n_done = counts["finished"] + counts["reported"]
    transfers = any(status.transfers_due for status in statuses)  # the suite asks for transfer tests
    tests_left = sum(status.transfers_left for status in statuses)
    summary = " · ".join(f"{counts[state]} {state}" for state in STATES if state != "reported" or counts[state])
    if transfers:
        summary += f" · {tests_left} transfer test{'s' if tests_left != 1 else ''} to come"
    summary += f" · {spent:.1f} core-hours in the finished{' and reported' if counts['reported'] else ''} runs"
    transfer_spent, transfer_left, transfer_unknown = transfer_seconds(statuses)
    if transfers:
        summary += f" and {transfer_spent / 3600:.1f} in their transfer tests"
    if n_done < len(statuses) or tests_left:
        own_left, own_unknown = seconds_left(statuses)
        left, unknown = seconds_left(statuses, lent_pace[1]) if lent_pace else (own_left, own_unknown)
        if n_done < len(statuses) and unknown == len(statuses) - n_done:
            estimate = "time left unknown until a run of an env finishes"
        else:
            lent = own_unknown - unknown  # the runs only the lent pace estimates
            lent_words = f"the pace of the runs of the same env and algorithm in {lent_pace[0]}" if lent_pace else ""
            if lent and own_unknown == len(statuses) - n_done:  # no run left has a pace of its own suite
                estimate = f"about {(left + transfer_left) / 3600:.1f} core-hours left at {lent_words}"
            else:
                estimate = f"about {(left + transfer_left) / 3600:.1f} core-hours left at the finished runs' pace"
            if any(own_pace(status) is not None for status in statuses):
                estimate += ", the running runs' at their own so far"
            parts = [f"{left / 3600:.1f} training, {transfer_left / 3600:.1f} transfer tests"] if transfers else []
            if lent and own_unknown < len(statuses) - n_done:
                parts.append(f"{(left - own_left) / 3600:.1f} of them for {lent} run{'s' if lent > 1 else ''} at {lent_words}")
            skipped = [f"{unknown} run{'s' if unknown > 1 else ''} of unknown pace or steps"] if unknown else []
            if transfer_unknown:
                skipped.append(f"{transfer_unknown} transfer test{'s' if transfer_unknown > 1 else ''} of unknown pace")
            if skipped:
                parts.append(f"not counting {' or '.join(skipped)}")
            if parts:
                estimate += f" ({'; '.join(parts)})"
        summary += f" · {estimate}"
    lines.append(summary)
    return lines
