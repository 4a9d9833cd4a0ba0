"""
Compare finished zoo runs over seeds, as the benchmark reports them::

    sb3-icrl compare logs/s6/mecl*/mecl/BlockedHalfCheetah-v0_1 logs/s6/vicrl*/vicrl/BlockedHalfCheetah-v0_1 -n 20000
    python -m sb3_icrl.zoo compare RUN [RUN ...] --reference vicrl --json results.json

Each ``RUN`` is a run folder ``<folder>/<algo>/<EnvName>_<N>`` of ``train.py``, or one that rl_zoo3 made (its
``<EnvName>`` is the env id with ``/`` turned into ``-``). Its final model (or ``--model best``)
is run on held-out env seeds, deterministically, as ``enjoy.py`` does (for ``-n`` steps, or on exactly
``--n-episodes`` complete episodes as the benchmark's reports do); the table gives per run the training seed, the
steps trained, the training wall time (from the run's ``finished.json``; the monitor's clock for runs without one),
the true violation rate and the feasible reward (and, for
the driving envs, a second table of how the held-out episodes ended: collision, off road, time out, goal reached). Per
algorithm it then gives the mean and std (``ddof=0``) over seeds and, against ``--reference``, the Wilcoxon
signed-rank test of the per-seed feasible rewards (pairs: runs with the same training seed). The true constraint is
read here only to report.

Variants of one algorithm (two recipes, say, trained with ``-f logs/a`` and ``-f logs/b``) compare as their own rows
when the same seed comes twice: each is labelled by the part of its folder that tells them apart (``mecl (a)``,
``mecl (b)``), and ``--reference`` takes such a label.
"""

import argparse
import os
import sys
from dataclasses import asdict
from typing import Any

from sb3_icrl.common.evaluation import OUTCOME_KEYS, OUTCOME_RATE_KEYS
from sb3_icrl.common.statistics import MIN_PAIRS_FOR_WILCOXON
from sb3_icrl.common.utils import atomic_write_json, plain_docstring, write_error_message
from sb3_icrl.registry import import_gym_packages, resolve_env_id
from sb3_icrl.run_evaluation import (
    OUTCOME_TITLES,
    RunFolderError,
    RunResult,
    describe_run,
    episode_step_cap,
    evaluate_run,
    format_outcome_rate,
    outcome_rate_means,
    read_training_wall_time,
    same_seed_error,
    summarise,
    training_wall_time,
)
from sb3_icrl.run_folder import (
    FINISHED_FILE,
    failure,
    is_finished,
    load_run_yaml,
    made_by_rl_zoo3,
    run_env_name,
    unreadable_finished,
)
from sb3_icrl.zoo.arguments import non_negative_int, positive_int


def check_runs(runs: list[str]) -> dict[str, float]:
    """
    Fail before any evaluation unless the runs trained on one env, with at most one run per algorithm and seed.

    :param runs: Run folders
    :return: Each run's training wall time in minutes (:func:`training_wall_time`), read here with its warnings so that
        the evaluation need not read the run's monitor file again
    """
    described = [(run, *describe_run(run)[:3]) for run in runs]
    envs = {env_id for _, _, env_id, _ in described}
    if len(envs) > 1:
        raise RunFolderError(f"The runs trained on different envs ({sorted(envs)}): compare one env at a time.")
    labels = run_labels(runs)
    seen: dict[tuple[str, int], str] = {}
    wall_times: dict[str, float] = {}
    for run, _, _, seed in described:
        label = labels[run]
        if (label, seed) in seen:
            raise same_seed_error(label, seed, seen[label, seed], run)
        seen[label, seed] = run
        reason = failure(run)
        if reason is not None:
            raise RunFolderError(f"{run} failed ({reason}): finish it with train.py --resume, or leave it out.")
        if made_by_rl_zoo3(run, os.path.basename(os.path.normpath(run)).rpartition("_")[0]):
            print(
                f"note: {run} is an rl_zoo3 run, which records no end of training: its final model is compared as it "
                "stands",
                file=sys.stderr,
            )
        elif not is_finished(run):
            why = unreadable_finished(run) or f"no {FINISHED_FILE}"
            print(f"warning: {run} did not finish its training ({why}): it is compared as it stands", file=sys.stderr)
        wall_times[run], notes = read_training_wall_time(run)
        for note in notes:
            print(f"warning: {note}", file=sys.stderr)
    return wall_times


def check_reference(runs: list[str], reference: str | None) -> None:
    """
    Fail before any evaluation unless ``reference`` is the algorithm of one of ``runs``.

    :param runs: Run folders
    :param reference: ``--reference`` (``None``: no test)
    """
    if reference is None:
        return
    algos = sorted(set(run_labels(runs).values()))
    if reference not in algos:
        raise RunFolderError(f"--reference {reference!r} has no run among the runs given ({', '.join(algos)}).")


#: Fewest pairs with which a two-sided Wilcoxon signed-rank test can reach p < 0.05 (its smallest p is 2 / 2**n)
WILCOXON_MIN_PAIRS = MIN_PAIRS_FOR_WILCOXON


def wilcoxon_warnings(summary: dict[str, dict[str, Any]], reference: str | None) -> list[str]:
    """
    The tests with too few pairs to mean anything (one pair gives p = 1 whatever the difference).

    :param summary: From :func:`summarise`
    :param reference: The reference algorithm
    :return: One warning per such test
    """
    messages = []
    for algo, entry in sorted(summary.items()):
        pairs = entry.get("wilcoxon_pairs")
        if pairs is None:
            continue
        ranked = entry.get("wilcoxon_ranked_pairs", pairs)  # tied seeds carry no sign
        if ranked < WILCOXON_MIN_PAIRS:
            tied = f" ({pairs - ranked} tied, which the test does not rank)" if ranked < pairs else ""
            messages.append(
                f"{algo} vs {reference}: {pairs} seed pair(s){tied}; a two-sided Wilcoxon test needs at least "
                f"{WILCOXON_MIN_PAIRS} ranked to reach p < 0.05 (its smallest p with {ranked} is "
                f"{2 / 2**ranked if ranked else 1:.3g}): train more seeds before reading the p-value."
            )
    return messages


def _distinct_parts(paths: list[str]) -> list[str]:
    """Each path less the leading and trailing components all ``paths`` share (``.`` when nothing is left)."""
    parts = [os.path.normpath(os.path.abspath(path)).split(os.sep) for path in paths]
    prefix = 0
    while all(len(p) > prefix for p in parts) and len({p[prefix] for p in parts}) == 1:
        prefix += 1
    suffix = 0
    while all(len(p) - prefix > suffix for p in parts) and len({p[len(p) - 1 - suffix] for p in parts}) == 1:
        suffix += 1
    return ["/".join(p[prefix : len(p) - suffix]) or "." for p in parts]


def run_labels(runs: list[str]) -> dict[str, str]:
    """
    The row label of each run: its algorithm, or, for an algorithm that comes with the same seed more than once
    (variants), ``"<algo> (<folder>)"`` where ``<folder>`` is the part of the run's log folder (``train.py -f``) that
    differs between them (its run folder's name when they share the log folder).

    :param runs: Run folders
    :return: ``{run: label}``
    """
    described = {run: describe_run(run) for run in runs}
    labels = {run: algo for run, (algo, _, _, _) in described.items()}
    for algo in sorted(set(labels.values())):
        mine = [run for run in runs if described[run][0] == algo]
        seeds = [described[run][2] for run in mine]
        if len(set(seeds)) == len(seeds) or len({os.path.abspath(run) for run in mine}) < len(mine):
            continue  # no variants, or one run given twice (an error for check_runs)
        folders = [described[run][3] for run in mine]
        by_folder = dict(zip(mine, _distinct_parts(folders), strict=True))
        if len({(by_folder[run], described[run][2]) for run in mine}) < len(mine):  # same log folder: by run folder
            by_folder = dict(zip(mine, _distinct_parts([os.path.normpath(run) for run in mine]), strict=True))
        for run in mine:
            labels[run] = f"{algo} ({by_folder[run]})"
    return labels


def recipe_differences(runs: list[str]) -> dict[str, dict[str, list[str]]]:
    """
    Per algorithm, the hyper-parameters (``config.yml``, ``n_timesteps`` aside) on which its runs disagree: runs of one
    algorithm summarised together should share a recipe.

    :param runs: Run folders
    :return: ``{algo: {key: [value of each run, as text]}}``, only for keys that differ
    """
    configs: dict[str, list[dict[str, Any]]] = {}
    labels = run_labels(runs)  # variants of an algorithm differ on purpose
    for run in runs:
        _, env_id, _, _ = describe_run(run)
        config = load_run_yaml(os.path.join(run, run_env_name(run, env_id), "config.yml"))
        config.pop("n_timesteps", None)
        configs.setdefault(labels[run], []).append(config)
    differences: dict[str, dict[str, list[str]]] = {}
    for algo, entries in configs.items():
        keys = sorted(set().union(*entries))
        values = {key: [repr(entry.get(key)) for entry in entries] for key in keys}
        differing = {key: listed for key, listed in values.items() if len(set(listed)) > 1}
        if differing:
            differences[algo] = differing
    return differences


def format_table(results: list[RunResult], summary: dict[str, dict[str, Any]], reference: str | None) -> str:
    """The per-run and per-algorithm tables, in Markdown."""
    lines = [
        "| algo | seed | steps | wall time (min) | violation rate | feasible reward | reward | episodes | run |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda result: (result.name, result.seed)):
        lines.append(
            f"| {r.name} | {r.seed} | {r.timesteps} | {r.wall_time_min:.1f} | {r.violation_rate:.0%} | "
            f"{r.feasible_reward:.0f} | {r.reward:.0f} | {r.n_episodes} | {r.run} |"
        )
    test_column = f" Wilcoxon p vs {reference} (pairs) |" if reference else ""
    lines += ["", "| algo | seeds | violation rate, mean +- std | feasible reward, mean +- std |" + test_column]
    lines.append("|---|---|---|---|" + ("---|" if reference else ""))
    for algo, entry in sorted(summary.items()):
        row = (
            f"| {algo} | {', '.join(map(str, entry['seeds']))} | {entry['violation_rate_mean']:.0%} +- "
            f"{entry['violation_rate_std']:.0%} | {entry['feasible_reward_mean']:.0f} +- {entry['feasible_reward_std']:.0f} |"
        )
        if reference:
            row += f" {entry['wilcoxon_p']:.3g} ({entry['wilcoxon_pairs']}) |" if "wilcoxon_p" in entry else " |"
        lines.append(row)
    lines += outcome_table(results)
    return "\n".join(lines)


def outcome_table(results: list[RunResult]) -> list[str]:
    """
    The driving outcome rates per run (how the held-out episodes ended), as Markdown lines after a blank line; no
    lines when no run has them.
    """
    keys = [key for key in OUTCOME_KEYS if any(OUTCOME_RATE_KEYS[key] in result.outcome_rates for result in results)]
    if not keys:
        return []
    lines = ["", "| algo | seed | " + " | ".join(OUTCOME_TITLES[key] for key in keys) + " |", "|---|---|" + "---|" * len(keys)]
    for r in sorted(results, key=lambda result: (result.name, result.seed)):
        rates = [format_outcome_rate(r.outcome_rates.get(OUTCOME_RATE_KEYS[key])) for key in keys]
        lines.append(f"| {r.name} | {r.seed} | " + " | ".join(rates) + " |")
    return lines


#: Evaluation steps per run when neither -n nor --n-episodes is given
DEFAULT_EVAL_STEPS = 20000


def evaluation_budget(run: str, n_timesteps: int | None, n_episodes: int | None) -> tuple[int, int | None]:
    """
    ``(steps, episodes)`` of a run's held-out evaluation: by steps (``n_timesteps``, default :data:`DEFAULT_EVAL_STEPS`)
    without ``n_episodes``; else exactly ``n_episodes`` complete episodes within ``n_timesteps`` steps (default
    :func:`~sb3_icrl.run_evaluation.episode_step_cap` of the run's env).

    :param run: The run folder
    :param n_timesteps: ``-n``
    :param n_episodes: ``--n-episodes``
    """
    if n_episodes is None:
        return (n_timesteps or DEFAULT_EVAL_STEPS), None
    if n_timesteps is not None:
        return n_timesteps, n_episodes
    _, env_id, _, _ = describe_run(run)
    return episode_step_cap(resolve_env_id(env_id), n_episodes), n_episodes


def _check_json_path(path: str) -> None:
    """Fail before the evaluations when ``--json`` cannot be written (its folder missing, a file, or read-only)."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder) or os.path.isdir(path):
        raise RunFolderError(
            f"--json {path!r} cannot be written: {folder} must be an existing folder and the path a file name."
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise RunFolderError(f"--json {path!r} cannot be written: {folder} is not writable.")


def get_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """
    The command-line parser.

    :param prog: Program name in the usage line
    """
    parser = argparse.ArgumentParser(
        prog=prog, description=plain_docstring(__doc__), formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", help="Run folders <folder>/<algo>/<EnvName>_<N>")
    parser.add_argument(
        "-n",
        "--n-timesteps",
        type=positive_int,
        default=None,
        help="Evaluation steps per run (default 20000); with --n-episodes, the most steps they may take (default: twice "
        "the steps of as many full-length episodes)",
    )
    parser.add_argument(
        "-e",
        "--n-episodes",
        type=positive_int,
        default=None,
        help="Evaluate exactly this many complete episodes per run, as the benchmark's reports do (default: every "
        "episode that ends within -n steps)",
    )
    parser.add_argument("--seed", type=non_negative_int, default=100, help="Seed of the held-out evaluation episodes")
    parser.add_argument("--model", choices=["final", "best"], default="final", help="Model to evaluate")
    parser.add_argument(
        "--reference",
        type=str,
        default=None,
        help="Algorithm (or variant label, e.g. 'mecl (a)') to test the others against (Wilcoxon)",
    )
    parser.add_argument("--json", type=str, default=None, help="Also write the runs and the summary to this JSON file")
    parser.add_argument(
        "--gym-packages",
        type=str,
        nargs="+",
        default=[],
        help="Modules to import first: they register your own envs (those in each run's args.yml are imported too)",
    )
    return parser


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """
    Command-line entry point (``sb3-icrl compare``).

    :param argv: Arguments (default: ``sys.argv[1:]``)
    :param prog: Program name in the usage line
    :return: Exit status: 0, or 2 after a clear error
    """
    args = get_parser(prog).parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        import_gym_packages(args.gym_packages)
        wall_times = check_runs(args.runs)
        check_reference(args.runs, args.reference)
        if args.json:
            _check_json_path(args.json)
        for algo, differing in recipe_differences(args.runs).items():
            listed = "; ".join(f"{key}: {', '.join(values)}" for key, values in differing.items())
            print(f"warning: the {algo} runs do not share one recipe ({listed})", file=sys.stderr)
        results = []
        labels = run_labels(args.runs)
        for run in args.runs:
            print(f"Evaluating {run}")
            steps, budget = evaluation_budget(run, args.n_timesteps, args.n_episodes)
            result = evaluate_run(
                run, steps, args.seed, args.model == "best", wall_time_min=wall_times[run], n_episodes=budget
            )
            result.label = labels[run] if labels[run] != result.algo else ""
            results.append(result)
        summary = summarise(results, args.reference)
    except (FileNotFoundError, RunFolderError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted: no table (every run is evaluated first); run it again, with a smaller -n.", file=sys.stderr)
        return 130
    print(format_table(results, summary, args.reference))
    for warning in wilcoxon_warnings(summary, args.reference):
        print(f"warning: {warning}", file=sys.stderr)
    if args.json:
        payload = {
            "runs": [asdict(result) for result in results],
            "summary": summary,
            "eval_seed": args.seed,
            "eval_episodes": args.n_episodes,
        }
        try:
            atomic_write_json(args.json, payload, indent=2)
        except OSError as error:
            message = write_error_message(error)  # a disk that filled up during the evaluations
            if message is None:
                raise
            print(f"error: {message}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())


# The run evaluation lives in sb3_icrl.run_evaluation (the benchmark engine uses it too); its names stay importable here
__all__ = [
    "OUTCOME_TITLES",
    "WILCOXON_MIN_PAIRS",
    "RunFolderError",
    "RunResult",
    "check_reference",
    "check_runs",
    "describe_run",
    "evaluate_run",
    "format_outcome_rate",
    "format_table",
    "get_parser",
    "main",
    "outcome_rate_means",
    "outcome_table",
    "recipe_differences",
    "run_labels",
    "summarise",
    "training_wall_time",
    "wilcoxon_warnings",
]
