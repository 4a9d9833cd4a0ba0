"""
``sb3-icrl benchmark``: run a suite of training runs, then report it::

    sb3-icrl benchmark run table3 -f logs/ --jobs 2
    sb3-icrl benchmark run table3 -f logs/ --only env=BlockedHalfCheetah-v0 algo=mecl,vicrl
    sb3-icrl benchmark run table3 -f logs/ --start-within 2h30m
    sb3-icrl benchmark run table3 -f logs/ --backend ray --address auto
    sb3-icrl benchmark run table3 -f /shared/logs --backend ray --runtime-env runtime_env.yml
    sb3-icrl benchmark status table3 -f logs/
    sb3-icrl benchmark run table3 -f logs/ --reported benchmarks/results/table3 --order seed --start-within 2h
    sb3-icrl benchmark report table3 -f logs/ -o results/table3
    sb3-icrl benchmark report table3 -f logs/ --only env=BlockedHalfCheetah-v0 -o results/table3 --update
    sb3-icrl benchmark pack table3 -f logs/ --only env=BlockedHalfCheetah-v0 -o pack/ --max-mib 15
    sb3-icrl benchmark unpack pack/ -f logs/
    sb3-icrl benchmark list

Every run is a ``train.py`` run in ``<folder>/<suite>/<variant>/<algo>/<EnvName>_<seed>/`` (an rl-zoo run folder, so
enjoy, plots, compare and TensorBoard work on it), its output in ``<folder>/<suite>/logs/``. Running the same command
again skips the finished runs and resumes the others from their last checkpoint.
"""

import argparse
import contextlib
import dataclasses
import json
import os
import re
import sys
import time
from typing import Any

from sb3_icrl.benchmark.report import (
    REPORT_MODELS,
    constraint_metrics,
    evaluate_finished,
    keep_probe_policies,
    keep_transfer_references,
    kept_probe_policy_folder,
    previous_results,
    probe_policy_folder,
    probe_rows_unlike_report,
    reported_runs_trained_again,
    restore_probe_policies,
    restore_transfer_references,
    summarise_suite,
    write_report,
)
from sb3_icrl.benchmark.report_figures import kept_figure_data, refresh_crossings, write_figures
from sb3_icrl.benchmark.report_text import markdown_table
from sb3_icrl.benchmark.runner import BACKENDS, RunOutcome, load_runtime_env, make_backend, run_all
from sb3_icrl.benchmark.status import RunStatus, mark_reported, report_pace, reported_runs, status_lines, suite_status
from sb3_icrl.benchmark.study import STUDY_AXES, read_report_summary, study_axis, study_baseline
from sb3_icrl.benchmark.suite import SUITES_DIR, RunSpec, Suite, SuiteError, load_suite
from sb3_icrl.benchmark.transport import pack_runs, pack_summary, unpack_bundles
from sb3_icrl.common.utils import check_writable_folder, plain_docstring, sigterm_interrupts, write_error_message
from sb3_icrl.registry import import_gym_packages
from sb3_icrl.run_evaluation import RunResult
from sb3_icrl.run_folder import is_finished

#: The orders ``run`` can start a suite's runs in (``--order``)
RUN_ORDERS = ("suite", "seed")


def _only(values: list[str] | None) -> dict[str, list[str]]:
    only: dict[str, list[str]] = {}
    for item in values or []:
        key, sep, value = item.partition("=")
        if not sep or not key or not value:
            raise SuiteError(f"--only takes key=value[,value...] (env, algo, seed, variant), got {item!r}.")
        only.setdefault(key, []).extend(part for part in value.split(",") if part)
    return only


def duration_seconds(text: str) -> float:
    """
    A duration such as ``2h30m``, ``90m``, ``1.5h``, ``600s`` or ``600`` (seconds), in seconds (argparse type).

    :raises argparse.ArgumentTypeError: On anything else, or a duration that is not positive
    """
    match = re.fullmatch(r"\s*(?:(\d+(?:\.\d+)?)h)?\s*(?:(\d+(?:\.\d+)?)m)?\s*(?:(\d+(?:\.\d+)?)(s?))?\s*", text.lower())
    # (a bare number after a unit, "1h30", is ambiguous: refused)
    if match is not None and match.group(3) and not match.group(4) and (match.group(1) or match.group(2)):
        match = None
    if not text.strip() or match is None or not any(match.groups()[:3]):
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration: write it as 2h30m, 90m, 1.5h, 600s or 600 (seconds)")
    hours, minutes, seconds = (float(group or 0) for group in match.groups()[:3])
    total = 3600 * hours + 60 * minutes + seconds
    if total <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the duration must be more than zero")
    return total


def get_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, description=plain_docstring(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="train every run of a suite (resumes)")
    status = commands.add_parser(
        "status", help="which runs finished, run now, stopped part-way, failed or never started; core-hours left"
    )
    report = commands.add_parser("report", help="evaluate the finished runs and write the tables and figures")
    pack = commands.add_parser(
        "pack", help="write the selected runs' folders into size-capped tarballs, to resume or report them elsewhere"
    )
    for sub in (run, status, report, pack):
        sub.add_argument(
            "suite", help="a shipped suite (table3, table3_dev, noise, imperfect, multi, experts, smoke) or a .yml path"
        )
        sub.add_argument("-f", "--log-folder", default="logs", help="log root (runs go to <root>/<suite>/...)")
        sub.add_argument("--only", nargs="+", default=None, help="filters key=value[,value]: env, algo, seed, variant")
        sub.add_argument(
            "--gym-packages",
            nargs="+",
            default=[],
            help="modules to import first: they register your own envs (added to the suite's gym_packages)",
        )
    run.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="runs at a time (default: one per core); with --backend ray, the CPUs of the Ray instance started here "
        "(a cluster's own CPUs decide there)",
    )
    run.add_argument("--backend", choices=BACKENDS, default="local", help="local process pool, or Ray tasks")
    run.add_argument(
        "--address", default=None, help="Ray cluster address (--backend ray; default: $RAY_ADDRESS, else start one here)"
    )
    run.add_argument(
        "--runtime-env",
        default=None,
        help="Ray runtime_env for the workers (--backend ray): a JSON object or a YAML file, e.g. "
        '\'{"working_dir": "."}\' to ship this clone to every node',
    )
    run.add_argument(
        "--start-within",
        type=duration_seconds,
        default=None,
        metavar="DURATION",
        help="start no run (nor a failed run's second try) later than this after the command starts, e.g. 2h30m, 90m, "
        "600s: the runs under way go on to their end, the others are left for the next call (a job's time limit less "
        "a run's length)",
    )
    run.add_argument(
        "--order",
        choices=RUN_ORDERS,
        default="suite",
        help="the order runs start in: the suite's (env by env, then variant, algorithm, seed), or seed by seed, the "
        "lowest first (each seed's PPO rows, whose episodes its ICRL runs' identification reads, then its other runs in "
        "the suite's order), so that every selected cell gains its next seed before any gains the one after",
    )
    run.add_argument("--no-report", action="store_true", help="do not write the report once the runs are done")
    for sub in (run, status):
        sub.add_argument(
            "--reported",
            default=None,
            metavar="REPORT",
            help="a committed report of the suite (the -o of `benchmark report`): the runs it holds at the suite's recipe "
            "version, with no folder under -f, count as done (trained on another machine, say): `run` does not train "
            "them again, `status` lists them as reported; `run` also restores the transfer references and the PPO rows' "
            "policies (read by the identification of their seeds' ICRL runs) the report keeps",
        )
    status.add_argument("-v", "--verbose", action="store_true", help="list the finished and reported runs too")
    status.add_argument(
        "--pace-from",
        default=None,
        metavar="REPORT",
        help="a report of any suite (the -o of `benchmark report`): runs whose variant and env have no finished run yet "
        "are estimated at the pace of its runs of the same env and algorithm, to plan a suite by core-hours before it "
        "starts (a study on the table's recipes at the table's pace: --pace-from benchmarks/results/table3)",
    )
    report.add_argument(
        "-o", "--output", default=None, help="report folder (default: <root>/<suite>/report, report_best with --model best)"
    )
    report.add_argument(
        "--model",
        choices=REPORT_MODELS,
        default="final",
        help="evaluate each run's final model (default) or the best_model.zip its training chose on learned quantities",
    )
    report.add_argument("--no-figures", action="store_true", help="tables only")
    report.add_argument(
        "--baseline",
        default=None,
        metavar="REPORT",
        help="for a study (noise, imperfect): the report folder of the runs it extends (benchmarks/results/table3): its "
        "runs of the study's envs, methods and seeds, at the same recipe version, are the figure's level 0 (kept "
        "through --update)",
    )
    report.add_argument(
        "--update",
        action="store_true",
        help="update the report in -o with these runs: their cells' seeds replace the ones it has, its other cells stay, "
        "and so do selected runs with no folder under -f (with no finished run, the report is written again from its "
        "summary, with the current statistics)",
    )
    report.add_argument(
        "--replace",
        action="store_true",
        help="with --update: let selected runs trained again here (not finished, or another training time or git "
        "revision than the report's row) replace the rows the report holds; without it they stop the update",
    )
    report.add_argument(
        "--withdraw",
        action="store_true",
        help="with --update: take the runs --only selects out of the report (trained by code since fixed, say) and list "
        "them as not finished, so that `run --reported` trains them again; their folders must not be under -f",
    )
    pack.add_argument("-o", "--output", required=True, help="folder for the bundles and manifest.json (new or empty)")
    pack.add_argument(
        "--max-mib",
        type=float,
        default=15.0,
        help="largest bundle in MiB (a run larger than this is split into parts); default 15",
    )
    pack.add_argument(
        "--all-checkpoints",
        action="store_true",
        help="carry every checkpoint (default: none of a finished run, the one an interrupted run resumes from)",
    )
    unpack = commands.add_parser("unpack", help="put packed runs under this machine's log root (run resumes them)")
    unpack.add_argument("paths", nargs="+", help="the pack's manifest.json and bundles, or the folders they came in")
    unpack.add_argument("-f", "--log-folder", default="logs", help="log root here (the runs go to <root>/<suite>/...)")
    unpack.add_argument("--replace", action="store_true", help="replace run folders that are already here")
    commands.add_parser("list", help="the shipped suites")
    return parser


class Display:
    """
    Progress of a suite: a live line (rich) of runs done / running / failed / left with an ETA on a terminal, one
    line per event otherwise (logs, CI).
    """

    def __init__(self, total: int):
        self.total = total
        self.start = time.time()
        self.ended = 0
        self.trained_seconds: list[float] = []
        self.live: Any = None
        if sys.stdout.isatty():
            from rich.live import Live

            self.live = Live("", refresh_per_second=2, transient=False)
            self.live.start()

    def line(self, counts: dict[str, int]) -> str:
        finished = counts["done"] + counts["skipped"]
        left = counts["left"] + counts["running"] + counts.get("deferred", 0)
        eta = ""
        if self.trained_seconds and left:
            per_run = sum(self.trained_seconds) / len(self.trained_seconds)
            parallel = max(counts["running"], 1)
            eta = f" · ETA {time.strftime('%H:%M', time.localtime(time.time() + per_run * left / parallel))}"
        return (
            f"{finished}/{self.total} done ({counts['skipped']} from before) · {counts['running']} running · "
            f"{counts['failed']} failed · {counts['busy']} busy elsewhere · {counts['left']} left"
            + (f" · {counts['deferred']} deferred" if counts.get("deferred") else "")
            + eta
        )

    def __call__(self, event: str, outcome: RunOutcome | None, counts: dict[str, int]) -> None:
        if outcome is not None and event == "end" and outcome.status == "done":
            self.trained_seconds.append(outcome.seconds)
        if self.live is not None:
            self.live.update(self.line(counts))
            if outcome is not None and event == "end" and outcome.status in ("done", "failed", "deferred"):
                self.live.console.print(f"{outcome.status}: {outcome.run.name} ({outcome.seconds / 60:.1f} min)")
            return
        if outcome is not None:
            what = {"start": f"start (attempt {outcome.attempts})"}.get(event, outcome.status)
            print(f"[{time.strftime('%H:%M:%S')}] {what}: {outcome.run.name} | {self.line(counts)}", flush=True)

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()


def _load_suite(args: argparse.Namespace, dry_build: bool = False) -> Suite:
    """
    The suite, with the modules of ``--gym-packages`` imported first and passed on to every run.

    :param args: The parsed command line
    :param dry_build: Also make the model of each run whose variant sets hyper-parameters (see
        :func:`~sb3_icrl.benchmark.suite.load_suite`): ``run`` does, before any run starts; status and report, which
        start none, do not wait for it
    """
    packages = list(getattr(args, "gym_packages", None) or [])
    import_gym_packages(packages)
    suite = load_suite(args.suite, dry_build=dry_build)
    extra = tuple(package for package in packages if package not in suite.gym_packages)
    return dataclasses.replace(suite, gym_packages=(*suite.gym_packages, *extra)) if extra else suite


def run_command(args: argparse.Namespace) -> int:
    suite = _load_suite(args, dry_build=True)
    runs = suite.select(_only(args.only))
    # Before any run starts: each would fail on its own, and be tried again, on a folder it cannot write
    check_writable_folder(args.log_folder, "-f/--log-folder")
    backend = make_backend(args.backend, args.jobs, args.address, load_runtime_env(args.runtime_env))
    where = (
        f"ray cluster at {backend.address}, {backend.capacity} CPUs"
        if backend.address
        else f"{args.backend}, {backend.capacity} at a time"
    )
    print(f"suite {suite.name}: {len(runs)} runs in {os.path.join(args.log_folder, suite.name)} ({where})", flush=True)
    statuses = _statuses(args, suite, runs)
    print(f"before this run: {status_lines(statuses)[-1]}", flush=True)
    if args.order == "seed":
        runs = _seed_by_seed(suite, runs)
    reported = {status.run for status in statuses if status.state == "reported"}
    if reported:
        runs = [run for run in runs if run not in reported]
        many = len(reported) > 1
        print(f"not trained again: {len(reported)} run{'s' if many else ''} that {args.reported} holds", flush=True)
    if args.reported is not None:
        why = "reported PPO rows whose episodes the identification of their seed's ICRL runs reads, not trained again for it"
        _say_restored("probe policies", restore_probe_policies(args.reported, args.log_folder, suite), args.reported, why)
        why = "not trained again by the transfer tests that read them"
        _say_restored(
            "transfer references", restore_transfer_references(args.reported, args.log_folder, suite), args.reported, why
        )
    probe_runs, missing = _probe_runs_by_state(args, suite, runs)
    if args.reported is not None and probe_runs:
        runs = _before_their_seed(probe_runs, runs)
        print(f"trained again: {_probe_runs_text(probe_runs)}", flush=True)
    if missing:
        print(_missing_probe_runs_text(missing), flush=True)
    start_until = None if args.start_within is None else time.time() + args.start_within
    if start_until is not None:
        print(f"no run starts after {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(start_until))}", flush=True)
    display = Display(len(runs))
    try:
        outcomes = run_all(runs, args.log_folder, backend, on_event=display, start_until=start_until)
    finally:
        display.close()
    failed = [outcome for outcome in outcomes if outcome.status in ("failed", "busy")]
    for outcome in failed:
        print(f"\n{outcome.status.upper()}: {outcome.run.name} ({outcome.run.log_file(args.log_folder)})")
        for line in outcome.log_tail:
            print(f"    {line}")
    left = [outcome for outcome in outcomes if outcome.status == "left"]
    if left:
        print(
            f"\nNOT STARTED: {len(left)} run{'s' if len(left) > 1 else ''}, the --start-within time having passed "
            f"(the same command starts {'them' if len(left) > 1 else 'it'}): " + _run_names([outcome.run for outcome in left])
        )
    if not args.no_report:
        report_command(argparse.Namespace(**{**vars(args), "output": None, "no_figures": False}))
    return 1 if failed else 0


def _say_restored(what: str, restored: list[str], report: str, why: str) -> None:
    """One line for what ``run --reported`` copied from the report into the log folder, when it copied anything."""
    if restored:
        print(f"{what}: {len(restored)} restored from {report} ({why})", flush=True)


#: States of a probe run that nothing brings: neither finished, running elsewhere nor reported (and not selected)
UNBROUGHT_STATES = ("not started", "interrupted", "failed")


def _probe_runs_by_state(args: argparse.Namespace, suite: Suite, runs: list[RunSpec]) -> tuple[list[RunSpec], list[RunSpec]]:
    """
    The PPO runs whose episodes the identification of ``runs``' ICRL runs reads
    (:meth:`~sb3_icrl.benchmark.suite.Suite.probe_runs`), those among ``runs`` left out, in the suite's order, from one
    read of where they stand: those a report holds with no folder here and no policy kept from it (trained again by
    ``run --reported``: without them here, the report would score the ICRL runs on another seed's episodes or none),
    and those nothing brings
    (:data:`UNBROUGHT_STATES`).
    """
    selected = set(runs)
    probes = {probe for probe in suite.probe_runs(runs).values() if probe not in selected}
    statuses = _statuses(args, suite, [run for run in suite.runs() if run in probes]) if probes else []
    reported = [status.run for status in statuses if status.state == "reported" and not _has_probe_policy(args, status.run)]
    return reported, [status.run for status in statuses if status.state in UNBROUGHT_STATES]


def _has_probe_policy(args: argparse.Namespace, run: RunSpec) -> bool:
    """Whether a reported PPO row's policy is in the log folder or kept by the ``--reported`` report (restored by ``run``)."""
    folders = [probe_policy_folder(args.log_folder, run)]
    if getattr(args, "reported", None) is not None:
        folders.append(kept_probe_policy_folder(args.reported, run))
    return any(is_finished(folder) for folder in folders)


def _run_names(runs: list[RunSpec], shown: int = 5) -> str:
    """The first ``shown`` runs' names, and how many more there are."""
    return ", ".join(run.name for run in runs[:shown]) + (f" and {len(runs) - shown} more" if len(runs) > shown else "")


def _missing_probe_runs_text(missing: list[RunSpec]) -> str:
    return (
        f"note: the identification of the selected ICRL runs reads their seed's PPO episodes, and {len(missing)} of "
        f"those PPO runs {'are' if len(missing) > 1 else 'is'} neither selected nor finished here ({_run_names(missing)}): "
        "add algo=ppo to --only, or the report scores those ICRL runs on another seed's episodes or none."
    )


def _probe_runs_text(probe_runs: list[RunSpec]) -> str:
    many = len(probe_runs) > 1
    return (
        f"{len(probe_runs)} reported PPO run{'s' if many else ''} with no folder here, whose episodes the identification "
        f"probes of {'their' if many else 'its'} seed's ICRL runs read ({_run_names(probe_runs)})"
    )


def _seed_by_seed(suite: Suite, runs: list[RunSpec]) -> list[RunSpec]:
    """
    ``runs`` seed by seed, the lowest first; within a seed the selected PPO rows whose episodes that seed's ICRL runs'
    identification reads (:meth:`~sb3_icrl.benchmark.suite.Suite.probe_runs`) first, then the suite's order, so that a
    seed reported run by run scores each ICRL run on its own seed's episodes.
    """
    probes = set(suite.probe_runs(runs).values()).intersection(runs)
    return sorted(runs, key=lambda run: (run.seed, run not in probes))  # a stable sort: otherwise the suite's order


def _before_their_seed(first: list[RunSpec], runs: list[RunSpec]) -> list[RunSpec]:
    """``runs`` with each of ``first`` put before the first run of its variant, env and seed."""
    ordered = list(runs)
    for run in first:
        key = (run.variant, run.env_id, run.seed)
        at = next(index for index, other in enumerate(ordered) if (other.variant, other.env_id, other.seed) == key)
        ordered.insert(at, run)
    return ordered


def status_command(args: argparse.Namespace) -> int:
    """Print where the selected runs stand; reads the run folders only, so it is safe while the suite runs."""
    suite = _load_suite(args)
    runs = suite.select(_only(args.only))
    lent_pace = (args.pace_from, report_pace(args.pace_from)) if args.pace_from else None
    folder = os.path.join(args.log_folder, suite.name)
    print(f"suite {suite.name}: {len(runs)} runs in {folder}")
    statuses = _statuses(args, suite, runs)
    print("\n".join(status_lines(statuses, verbose=args.verbose, lent_pace=lent_pace)))
    probe_runs, missing = _probe_runs_by_state(args, suite, [status.run for status in statuses if status.state != "reported"])
    if probe_runs:
        print(f"`run --reported` also trains again {_probe_runs_text(probe_runs)}")
    if missing:
        print(_missing_probe_runs_text(missing))
    if not os.path.isdir(folder):  # last, where it is read: every run above is "not started"
        print(f"note: {_no_suite_folder(args.log_folder, suite.name)}: no run has started there; check -f")
    return 0


def _statuses(args: argparse.Namespace, suite: Suite, runs: list[RunSpec]) -> list[RunStatus]:
    """The runs' statuses, those a report given with ``--reported`` holds marked (:func:`mark_reported`)."""
    statuses = suite_status(runs, args.log_folder)
    if getattr(args, "reported", None) is None:
        return statuses
    return mark_reported(statuses, reported_runs(args.reported, suite.name, suite.recipe_version))


def _no_suite_folder(log_folder: str, name: str) -> str:
    """Why ``<log_folder>/<name>`` holds no run: the log folder does not exist, or it holds other things (named)."""
    if not os.path.isdir(log_folder):
        return f"-f/--log-folder {log_folder} does not exist"
    there = sorted(entry for entry in os.listdir(log_folder) if not entry.startswith("."))
    shown = ", ".join(there[:8]) + (f" and {len(there) - 8} more" if len(there) > 8 else "")
    holds = f"it holds {shown}" if there else "it is empty"
    return f"-f/--log-folder {log_folder} has no folder {name} of this suite ({holds})"


def _earlier_summary_path(output: str) -> str:
    """
    :param output: The report folder that ``--update`` updates
    :return: Its ``summary.json``
    :raises SuiteError: When there is none
    """
    path = os.path.join(output, "summary.json")
    if not os.path.isfile(path):
        raise SuiteError(f"--update: no report in {output!r} (no summary.json): pass its folder with -o, or drop --update.")
    return path


def _earlier_summary(output: str) -> dict[str, Any]:
    """The ``summary.json`` of the report that ``--update`` updates, with a clear error when it is not one."""
    path = _earlier_summary_path(output)
    try:
        with open(path) as file:
            earlier = json.load(file)
    except ValueError as error:
        earlier = error
    if not isinstance(earlier, dict):
        raise SuiteError(
            f"--update: {path} is not a report's summary (cut short or overwritten): write the report anew without "
            "--update, or pass the folder of an intact report with -o."
        )
    return earlier


def _with_earlier_report(
    suite: Suite,
    runs: list[RunSpec],
    results: list[tuple[RunSpec, RunResult]],
    metrics: dict[str, dict[str, Any]],
    output: str,
    root: str,
    model: str,
    withdraw: bool = False,
) -> tuple[list[RunSpec], list[tuple[RunSpec, RunResult]], dict[str, dict[str, Any]]]:
    """
    ``report --update``: the selected ``runs`` (finished or not) replace their seeds in the report in ``output``; its
    other runs are added to the fresh ``results`` and ``metrics``, and the runs it listed as not finished stay listed.

    :param withdraw: ``report --update --withdraw``: the selected runs leave the report and are listed as not finished
    :return: The runs (to list the unfinished ones), the results and the metrics of the whole updated report
    """
    earlier = _earlier_summary(output)
    earlier_model = earlier.get("model", "final")
    if earlier_model != model:
        raise SuiteError(
            f"--update: the report in {output!r} evaluated the {earlier_model} models, this one the {model} models: "
            f"pass --model {earlier_model}, or another -o folder."
        )
    earlier_budget = earlier.get("eval_budget", "steps")  # a report written before the key was evaluated by steps
    if earlier_budget != suite.eval_budget:
        raise SuiteError(
            f"--update: the report in {output!r} evaluated its runs by {earlier_budget}, suite {suite.name!r} evaluates "
            f"them by {suite.eval_budget} (eval_budget): its cells would mix the two. Pass another -o folder."
        )
    kept, kept_metrics, missing = previous_results(earlier, suite, root)
    refresh_crossings(kept, kept_metrics, kept_figure_data(output, suite.name, model))
    chosen = set(runs)
    withdrawn: list[RunSpec] = []
    if withdraw:  # (no fresh results: the earlier report less the selected runs, which are listed as not finished)
        withdrawn = [run for run, _ in kept if run in chosen]
        if not withdrawn:
            raise SuiteError(
                f"--withdraw: the report in {output!r} holds none of the runs --only selects: nothing to take out "
                "(check --only against the report's table)."
            )
        print(f"--withdraw: {len(withdrawn)} runs taken out of the report in {output!r}, now listed as not finished")
        kept = [(run, result) for run, result in kept if run not in chosen]
    # A selected run that has not finished (again) loses its old result: its cell must not mix two recipes. One with
    # no folder under the log root is not being trained again here (the report's runs may have trained elsewhere):
    # it keeps its result. With no fresh result at all, nothing is mixed: the report is written again as it was
    selected = {run for run in runs if os.path.isdir(run.run_folder(root))} | {run for run, _ in results} if results else set()
    elsewhere = [run for run, _ in kept if run in chosen and run not in selected]
    if results and elsewhere:
        print(
            f"--update: {len(elsewhere)} runs of the report in {output!r} have no folder under {root!r}: kept as it "
            "reported them (write the report without --update to leave them out)"
        )
    kept = [(run, result) for run, result in kept if run not in selected]
    metrics = {**metrics, **{result.run: kept_metrics[result.run] for _, result in kept}}
    if not results:  # the earlier report's runs, no more: a report of part of a suite stays one
        return [run for run, _ in kept] + missing + withdrawn, kept, metrics
    # (a selected run the earlier report listed as not finished is listed once)
    return runs + [run for run in missing if run not in chosen], kept + results, metrics


def _check_withdrawal(args: argparse.Namespace, runs: list[RunSpec], update: bool) -> None:
    """``report --withdraw``: only from a report being updated, only of runs named by ``--only``, with no folder here."""
    if not update:
        raise SuiteError("--withdraw takes runs out of an existing report: add --update and pass the report's folder with -o.")
    if not args.only:
        raise SuiteError("--withdraw: name the runs to take out of the report with --only (env=..., algo=..., seed=...).")
    here = [run.name for run in runs if os.path.isdir(run.run_folder(args.log_folder))]
    if here:
        shown = ", ".join(here[:4]) + (f" and {len(here) - 4} more" if len(here) > 4 else "")
        raise SuiteError(
            f"--withdraw: {len(here)} of the selected runs have a folder under {args.log_folder!r} ({shown}): `run` would "
            "count them as finished. Move those folders out of the log root first."
        )


def _check_trained_again(args: argparse.Namespace, suite: Suite, runs: list[RunSpec], output: str) -> None:
    """
    ``report --update``: none of the selected runs the report holds was trained again here
    (:func:`~sb3_icrl.benchmark.report.reported_runs_trained_again`), unless ``--replace`` says to put the new training
    in its place.
    """
    if getattr(args, "replace", False):
        return
    try:
        lines = reported_runs_trained_again(_earlier_summary(output), suite, runs, args.log_folder)
    except ValueError as error:
        raise SuiteError(str(error)) from error
    if lines:
        shown = "; ".join(lines[:4]) + (f"; and {len(lines) - 4} more" if len(lines) > 4 else "")
        raise SuiteError(
            f"--update: {len(lines)} of the selected runs that the report in {output!r} holds were trained again here "
            f"({shown}): updating would replace the reported rows. A PPO row that `run --reported` trained again for the "
            "identification probes must stay as reported: leave it out of --only (algo=...). To put the new training "
            "in the report's place, add --replace."
        )


def _study_baseline(args: argparse.Namespace, suite: Suite, output: str, model: str, update: bool) -> dict[str, Any] | None:
    """
    The study's level 0: from the report ``--baseline`` names, or with ``--update`` and no ``--baseline`` the one the
    updated report kept; ``None`` without either.

    :raises SuiteError: When ``--baseline`` is given for a suite that is no study, or names no suitable report
    """
    source = getattr(args, "baseline", None)
    if source is None:
        return _earlier_summary(output).get("study_baseline") if update else None
    if study_axis(suite) is None:
        raise SuiteError(
            f"--baseline: suite {suite.name!r} is no study (its variants do not all set one of "
            f"{', '.join(STUDY_AXES)} to a number): a baseline is the level 0 of a study's figure. Drop --baseline."
        )
    return study_baseline(read_report_summary(source), suite, source, model)


def report_command(args: argparse.Namespace) -> int:
    suite = _load_suite(args)
    runs = suite.select(_only(args.only))
    model = getattr(args, "model", "final")  # (``benchmark run`` reports the final models)
    output = args.output or os.path.join(args.log_folder, suite.name, "report" if model == "final" else "report_best")
    if args.output or os.path.isdir(os.path.join(args.log_folder, suite.name)):
        check_writable_folder(output, "-o/--output")  # before the evaluations, which take minutes
    update = getattr(args, "update", False)  # (``benchmark run`` writes a report of its own runs)
    withdraw = getattr(args, "withdraw", False)
    if getattr(args, "replace", False) and not update:
        raise SuiteError("--replace lets runs trained again replace rows of an existing report: add --update.")
    if update:
        _earlier_summary_path(output)  # before the evaluations too
    if withdraw:
        _check_withdrawal(args, runs, update)
    elif update:
        _check_trained_again(args, suite, runs, output)  # before the evaluations as well
    baseline = _study_baseline(args, suite, output, model, update)  # before the evaluations as well
    results = [] if withdraw else evaluate_finished(runs, args.log_folder, suite, model=model)
    # With --update and no finished run, the earlier report is written again from its summary with today's statistics
    if not results and args.command == "report" and not update:
        raise SuiteError(
            f"No finished run of suite {suite.name!r} in {os.path.join(args.log_folder, suite.name)}: train them first with "
            f"`sb3-icrl benchmark run {args.suite} -f {args.log_folder}` (or check -f and --only)."
        )
    metrics = constraint_metrics(results, args.log_folder, model=model)
    if update:
        scored = [run for run, _ in results]
        runs, results, metrics = _with_earlier_report(suite, runs, results, metrics, output, args.log_folder, model, withdraw)
        for line in probe_rows_unlike_report(suite, scored, results, metrics, args.log_folder):
            print(f"note: {line}")
    summary = summarise_suite(suite, runs, results, metrics, model=model)
    if baseline is not None:
        summary["study_baseline"] = baseline
    written = write_report(summary, output)
    if model == "final":
        written += keep_transfer_references([run for run, _ in results], args.log_folder, output)
        written += keep_probe_policies(suite, results, metrics, args.log_folder, output)
    if not args.no_figures:
        written += write_figures(summary, suite, args.log_folder, output)
    print(markdown_table(summary))
    print("wrote " + ", ".join(written))
    return 0


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """
    :param argv: Arguments (default: ``sys.argv[1:]``)
    :param prog: Program name in the usage line
    :return: Exit status: 0, 1 when a run failed, 2 after a clear error
    """
    args = get_parser(prog).parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if args.command == "list":
            for path in sorted(SUITES_DIR.glob("*.yml")):
                suite = load_suite(path, dry_build=False)
                print(f"{suite.name:10s} {len(suite.runs()):4d} runs  {suite.description}")
            return 0
        if os.path.exists(args.log_folder) and not os.path.isdir(args.log_folder):
            raise SuiteError(f"-f/--log-folder {args.log_folder!r} is a file, not a folder: pass the log root folder.")
        if args.command == "run":
            with sigterm_interrupts():
                return run_command(args)
        if args.command == "status":
            return status_command(args)
        if args.command == "pack":
            suite = _load_suite(args)
            manifest = pack_runs(
                suite.select(_only(args.only)), args.log_folder, args.output, int(args.max_mib * 2**20), args.all_checkpoints
            )
            print(pack_summary(manifest))
            return 0
        if args.command == "unpack":
            unpack_bundles(args.paths, args.log_folder, replace=args.replace)
            return 0
        return report_command(args)
    except (SuiteError, ValueError, RuntimeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader of the output left (`status ... | head`): the rest is not wanted. Stdout goes to /dev/null so that
        # Python's own flush at exit finds no broken pipe either
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as error:
        message = write_error_message(error)  # a report or log that cannot be written
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # The runs stop with the engine (their processes die with it); each resumes from its checkpoint next time
        print(
            f"\ninterrupted: the runs resume from their last checkpoints with the same `sb3-icrl benchmark {args.command}`.",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())
