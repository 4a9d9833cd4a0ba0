"""
Decide between two recipes by pooled means over methods and seeds, from the ``runs.csv`` files of benchmark reports::

    python benchmarks/pooled_rule.py --env BlockedHalfCheetah-v0 \
        --before benchmarks/results/gacl_halfcheetah/runs.csv:shipped \
                 benchmarks/results/throughput_halfcheetah/runs.csv:today \
                 benchmarks/results/halfcheetah_tuning_n4-e10/runs.csv \
                 benchmarks/results/halfcheetah_tuning_n4-e10-match05/runs.csv \
        --after benchmarks/results/throughput_halfcheetah/runs.csv:family

Each source is ``CSV[:VARIANT[:ALGO]]`` (no variant or algo: every row of that env in the file). The rule is the one the
throughput family was judged by: the new recipe ("after") ships if its mean feasible reward over all (method, seed)
runs is at least the old one's and its mean violation rate at most the old one's; every run is printed either way.
Both sides must hold the same (method, seed) pairs and have been evaluated the same way (episodes and held-out seed,
read from each report's ``summary.json``).
"""

import argparse
import csv
import json
import os
import sys
from dataclasses import dataclass

import numpy as np

from sb3_icrl.common.utils import atomic_write_json


@dataclass(frozen=True)
class RunRow:
    """One run's held-out result, as a report's ``runs.csv`` gives it."""

    algo: str
    seed: int
    feasible_reward: float
    violation_rate: float
    source: str


class RuleInputError(ValueError):
    """A source that cannot be read or does not match the other side."""


def read_source(source: str, env: str) -> tuple[list[RunRow], tuple[int | str, ...] | None]:
    """
    The rows of one ``CSV[:VARIANT[:ALGO]]`` source for ``env``, and how the report evaluated its runs.

    :param source: A ``runs.csv`` path, optionally followed by ``:variant`` and ``:algo``
    :param env: The env whose rows to keep
    :return: The rows, and ``(eval_episodes, eval_seed)`` from the ``summary.json`` beside the file, with
        ``"episodes"`` added for a report that ran exactly that many episodes per run (``eval_budget``; a report by
        steps, as every report before the key, has none) (``None``: no summary)
    """
    path, *filters = source.split(":")
    if len(filters) > 2:
        raise RuleInputError(f"{source!r}: write a source as CSV[:VARIANT[:ALGO]].")
    variant = filters[0] if filters else None
    algo = filters[1] if len(filters) > 1 else None
    if not os.path.isfile(path):
        raise RuleInputError(f"{path}: no such file (a report's runs.csv, written by `python -m sb3_icrl.benchmark report`).")
    with open(path, newline="") as file:
        rows = [
            RunRow(row["algo"], int(row["seed"]), float(row["feasible_reward"]), float(row["violation_rate"]), source)
            for row in csv.DictReader(file)
            if row["env"] == env and (variant is None or row["variant"] == variant) and (algo is None or row["algo"] == algo)
        ]
    if not rows:
        raise RuleInputError(f"{source}: no run of {env} (check the variant and algo names in the file's first columns).")
    summary_path = os.path.join(os.path.dirname(path), "summary.json")
    evaluation = None
    if os.path.isfile(summary_path):
        with open(summary_path) as file:
            summary = json.load(file)
        if "eval_episodes" in summary and "eval_seed" in summary:
            budget = () if summary.get("eval_budget", "steps") == "steps" else (str(summary["eval_budget"]),)
            evaluation = (int(summary["eval_episodes"]), int(summary["eval_seed"]), *budget)
    return rows, evaluation


def collect(sources: list[str], env: str, side: str) -> tuple[dict[tuple[str, int], RunRow], set[tuple[int | str, ...]]]:
    """
    The runs of one side by (algo, seed), refusing a pair found in two sources.

    :param sources: The side's sources
    :param env: The env whose rows to keep
    :param side: ``"before"`` or ``"after"``, for the messages
    :return: The runs by (algo, seed) and the evaluation settings the side's reports used
    """
    runs: dict[tuple[str, int], RunRow] = {}
    evaluations = set()
    for source in sources:
        rows, evaluation = read_source(source, env)
        if evaluation is not None:
            evaluations.add(evaluation)
        for row in rows:
            key = (row.algo, row.seed)
            if key in runs and runs[key].source == source:
                raise RuleInputError(
                    f"{side}: {row.algo} seed {row.seed} appears more than once in {source} (several variants?): "
                    "pick one with :VARIANT."
                )
            if key in runs:
                raise RuleInputError(
                    f"{side}: {row.algo} seed {row.seed} is in both {runs[key].source} and {source}: narrow one of them "
                    "with :VARIANT or :ALGO."
                )
            runs[key] = row
    return runs, evaluations


def decide(before: dict[tuple[str, int], RunRow], after: dict[tuple[str, int], RunRow]) -> dict:
    """
    The pooled-means rule: "after" ships if its mean feasible reward is >= before's and its mean violation rate <=.

    :param before: The old recipe's runs by (algo, seed)
    :param after: The new recipe's runs by (algo, seed)
    :return: The means of each side, the per-method means and the decision
    """
    if set(before) != set(after):
        missing_after = sorted(set(before) - set(after))
        missing_before = sorted(set(after) - set(before))
        raise RuleInputError(
            f"The sides hold different runs: only before {missing_after or 'none'}, only after {missing_before or 'none'}."
            " Compare like with like (same methods and seeds)."
        )
    keys = sorted(before)

    def means(runs: dict[tuple[str, int], RunRow], subset: list[tuple[str, int]]) -> tuple[float, float]:
        return (
            float(np.mean([runs[key].feasible_reward for key in subset])),
            float(np.mean([runs[key].violation_rate for key in subset])),
        )

    before_reward, before_violation = means(before, keys)
    after_reward, after_violation = means(after, keys)
    per_method = {}
    for algo in sorted({algo for algo, _ in keys}):
        subset = [key for key in keys if key[0] == algo]
        per_method[algo] = {"before": means(before, subset), "after": means(after, subset)}
    return {
        "n_runs": len(keys),
        "before": {"feasible_reward": before_reward, "violation_rate": before_violation},
        "after": {"feasible_reward": after_reward, "violation_rate": after_violation},
        "per_method": per_method,
        "ships": after_reward >= before_reward and after_violation <= before_violation,
    }


def format_markdown(before: dict[tuple[str, int], RunRow], after: dict[tuple[str, int], RunRow], decision: dict) -> str:
    """Per-run rows, per-method means and the pooled decision as Markdown."""
    lines = [
        "| method | seed | before: feasible reward / violations | after: feasible reward / violations |",
        "|---|---|---|---|",
    ]
    for key in sorted(before):
        old, new = before[key], after[key]
        lines.append(
            f"| {key[0]} | {key[1]} | {old.feasible_reward:.2f} / {old.violation_rate:.0%} "
            f"| {new.feasible_reward:.2f} / {new.violation_rate:.0%} |"
        )
    for algo, sides in decision["per_method"].items():
        (old_reward, old_violation), (new_reward, new_violation) = sides["before"], sides["after"]
        lines.append(f"| {algo} | mean | {old_reward:.2f} / {old_violation:.1%} | {new_reward:.2f} / {new_violation:.1%} |")
    old, new = decision["before"], decision["after"]
    lines.append(
        f"| all | mean of {decision['n_runs']} | {old['feasible_reward']:.2f} / {old['violation_rate']:.1%} "
        f"| {new['feasible_reward']:.2f} / {new['violation_rate']:.1%} |"
    )
    verdict = "ships (no worse on both means)" if decision["ships"] else "does not ship (worse on at least one mean)"
    lines.append("")
    lines.append(f"The new recipe {verdict}.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", required=True, help="The env whose runs to compare")
    parser.add_argument("--before", nargs="+", required=True, help="The old recipe's sources, CSV[:VARIANT[:ALGO]]")
    parser.add_argument("--after", nargs="+", required=True, help="The new recipe's sources, CSV[:VARIANT[:ALGO]]")
    parser.add_argument("--json", default=None, help="Also write the decision and every run to this JSON file")
    args = parser.parse_args(argv)
    try:
        before, before_evaluations = collect(args.before, args.env, "before")
        after, after_evaluations = collect(args.after, args.env, "after")
        evaluations = before_evaluations | after_evaluations
        if len(evaluations) > 1:
            raise RuleInputError(
                f"The reports were evaluated differently (episodes, held-out seed, and 'episodes' where exactly that many "
                f"were run): {sorted(evaluations, key=str)}; re-report them with the same eval_episodes, eval_seed and "
                "eval_budget."
            )
        decision = decide(before, after)
    except RuleInputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(format_markdown(before, after, decision))
    if args.json:
        payload = {
            **decision,
            "evaluation": sorted(evaluations),
            "runs": {
                side: [row.__dict__ for row in sorted(runs.values(), key=lambda row: (row.algo, row.seed))]
                for side, runs in (("before", before), ("after", after))
            },
        }
        atomic_write_json(args.json, payload, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
