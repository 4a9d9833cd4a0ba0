"""
Apply the rule written before the runs of ``benchmarks/suites/multi_tuning.yml`` (its log entry of 2026-11-27) to
their report, printing every run and each decision::

    python benchmarks/multi_tuning_rule.py benchmarks/results/multi_tuning --json decision.json

On the report's held-out evaluation (each run's final model):

1. VICRL's Beta prior: [9, 1] (variant ``prior-9-1``) replaces [0.9, 0.1] (``base``) when its mean feasible reward over
   the tuning seeds is higher and its mean violation rate no more than 5 points above.
2. GACL's termination reward: a final model ends its episodes on purpose when its held-out episodes are on average
   shorter than half the demonstrations' mean length. ``repeat`` (variant ``repeat``) replaces ``zero`` (``base``)
   when ``zero`` does so on at least 2 of 3 seeds, ``repeat`` on fewer seeds than ``zero``, and ``repeat``'s mean
   feasible reward is higher.
3. The design: when every method of ``base`` has a mean violation rate above 50% or ends its episodes on purpose on at
   least 2 of 3 seeds, the design is reported as not carrying over to two constraints (the study's suite does not run on
   it until that is understood).

The demonstrations' mean length is read from the shipped dataset's sidecar (transitions over trajectories).
"""

import argparse
import json
import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_icrl.common.utils import atomic_write_json
from sb3_icrl.data.registry import DEMONSTRATIONS_DIR, dataset_file_name

ENV = "HighwayVelocityDistance-v0"
#: Rule 1: how many points of mean violation rate [9, 1] may add
PRIOR_MAX_EXTRA_VIOLATION = 0.05
#: Rule 3: a mean violation rate above this fails a method
DESIGN_MAX_VIOLATION = 0.5
#: Rules 2 and 3: on this many seeds or more a recipe "ends its episodes on purpose"
ON_PURPOSE_SEEDS = 2
#: The tuning seeds, the methods of ``base`` and the held-out evaluation the rule was written for
TUNING_SEEDS = (0, 1, 2)
METHODS = ("gacl", "bc2l", "mecl", "vicrl")
EVALUATION = {"eval_episodes": 20, "eval_seed": 100, "eval_budget": "episodes"}


class RuleInputError(ValueError):
    """A report that the rule cannot judge (missing, another env, runs missing)."""


def demonstrations_mean_length(env: str = ENV, directory: str | os.PathLike = DEMONSTRATIONS_DIR) -> float:
    """The shipped demonstrations' mean episode length, from their sidecar: transitions over trajectories."""
    path = os.path.join(directory, dataset_file_name(env).removesuffix(".npz") + ".json")
    try:
        with open(path) as file:
            sidecar = json.load(file)
    except OSError as error:
        raise RuleInputError(f"No sidecar for {env}'s shipped demonstrations at {path}: {error}") from error
    return sidecar["n_transitions"] / sidecar["n_trajectories"]


def read_runs(report: str, env: str = ENV) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """
    Per (variant, algo), the per-seed entries of a report's ``summary.json`` on ``env``.

    :raises RuleInputError: When the report is missing or has no run of ``env``
    """
    path = os.path.join(report, "summary.json")
    try:
        with open(path) as file:
            summary = json.load(file)
    except (OSError, ValueError) as error:
        raise RuleInputError(f"No intact report at {path} ({error}): run `benchmark report` first.") from error
    if summary.get("model", "final") != "final":
        raise RuleInputError(f"{path} evaluates best models: the rule judges final models. Report without --model best.")
    other = {key: summary.get(key) for key in EVALUATION if summary.get(key) != EVALUATION[key]}
    if other:
        raise RuleInputError(f"{path} evaluates otherwise than the rule says ({other}; the rule: {EVALUATION}).")
    runs = {(cell["variant"], cell["algo"]): cell["per_seed"] for cell in summary["cells"] if cell["env"] == env}
    if not runs:
        raise RuleInputError(f"{path} has no run of {env}: pass the report of benchmarks/suites/multi_tuning.yml.")
    for (variant, algo), seeds in runs.items():
        for seed in seeds:
            missing = [key for key in ("feasible_reward", "violation_rate", "episode_length") if seed.get(key) is None]
            if missing:
                raise RuleInputError(
                    f"{path}: {algo} ({variant}) seed {seed.get('seed')} has no {', '.join(missing)}: write the report "
                    "again with the current `benchmark report`."
                )
    return runs


def _means(seeds: list[dict[str, Any]]) -> dict[str, float]:
    return {key: float(np.mean([seed[key] for seed in seeds])) for key in ("feasible_reward", "violation_rate")}


def _on_purpose(seeds: list[dict[str, Any]], threshold: float) -> int:
    """How many seeds' held-out episodes are on average shorter than ``threshold`` steps."""
    return sum(seed["episode_length"] < threshold for seed in seeds)


def _needed(runs: dict[tuple[str, str], list[dict[str, Any]]], key: tuple[str, str], seeds: int) -> list[dict[str, Any]]:
    """A recipe's runs on exactly the tuning seeds (:data:`TUNING_SEEDS`; ``seeds``, their number)."""
    found = sorted(runs.get(key, []), key=lambda seed: seed["seed"])
    if tuple(seed["seed"] for seed in found) != TUNING_SEEDS[:seeds]:
        raise RuleInputError(
            f"{key[1]} ({key[0]}) has seeds {[seed['seed'] for seed in found]} in the report, the rule judges "
            f"{list(TUNING_SEEDS[:seeds])}: finish its runs and report again."
        )
    return found


def decide(runs: dict[tuple[str, str], list[dict[str, Any]]], mean_length: float, seeds: int = 3) -> dict[str, Any]:
    """
    The three decisions of the rule.

    :param runs: Per (variant, algo), its per-seed entries (:func:`read_runs`)
    :param mean_length: The demonstrations' mean episode length (:func:`demonstrations_mean_length`)
    :param seeds: The tuning seeds each recipe must have
    """
    threshold = mean_length / 2
    base_vicrl, prior = _needed(runs, ("base", "vicrl"), seeds), _needed(runs, ("prior-9-1", "vicrl"), seeds)
    base_means, prior_means = _means(base_vicrl), _means(prior)
    prior_ships = (
        prior_means["feasible_reward"] > base_means["feasible_reward"]
        and prior_means["violation_rate"] <= base_means["violation_rate"] + PRIOR_MAX_EXTRA_VIOLATION + 1e-12
    )
    zero, repeat = _needed(runs, ("base", "gacl"), seeds), _needed(runs, ("repeat", "gacl"), seeds)
    zero_on_purpose, repeat_on_purpose = _on_purpose(zero, threshold), _on_purpose(repeat, threshold)
    repeat_ships = (
        zero_on_purpose >= ON_PURPOSE_SEEDS
        and repeat_on_purpose < zero_on_purpose
        and _means(repeat)["feasible_reward"] > _means(zero)["feasible_reward"]
    )
    methods = {}
    for algo in METHODS:  # every method, not those the report happens to hold
        entries = _needed(runs, ("base", algo), seeds)
        means, on_purpose = _means(entries), _on_purpose(entries, threshold)
        fails = means["violation_rate"] > DESIGN_MAX_VIOLATION or on_purpose >= ON_PURPOSE_SEEDS
        methods[algo] = {**means, "seeds_on_purpose": on_purpose, "fails": fails}
    return {
        "on_purpose_threshold": threshold,
        "vicrl_prior": {"base": base_means, "prior-9-1": prior_means, "ships": prior_ships},
        "gacl_termination_reward": {
            "zero": {**_means(zero), "seeds_on_purpose": zero_on_purpose},
            "repeat": {**_means(repeat), "seeds_on_purpose": repeat_on_purpose},
            "ships": repeat_ships,
        },
        "design": {"methods": methods, "carries_over": not all(entry["fails"] for entry in methods.values())},
    }


def report_lines(runs: dict[tuple[str, str], list[dict[str, Any]]], decision: dict[str, Any]) -> list[str]:
    """Every run, then each decision, as plain lines."""
    threshold = decision["on_purpose_threshold"]
    lines = [f"Episodes end on purpose below {threshold:.1f} steps (half the demonstrations' mean length).", ""]
    lines += ["variant | algo | seed | feasible reward | violation rate | episode length"]
    for (variant, algo), entries in sorted(runs.items()):
        for seed in sorted(entries, key=lambda entry: entry["seed"]):
            lines.append(
                f"{variant} | {algo} | {seed['seed']} | {seed['feasible_reward']:.2f} | {100 * seed['violation_rate']:.0f}% "
                f"| {seed['episode_length']:.1f}"
            )
    prior = decision["vicrl_prior"]
    lines += [
        "",
        f"1. VICRL prior: [0.9, 0.1] {prior['base']['feasible_reward']:.2f} / {100 * prior['base']['violation_rate']:.0f}%, "
        f"[9, 1] {prior['prior-9-1']['feasible_reward']:.2f} / {100 * prior['prior-9-1']['violation_rate']:.0f}%: "
        + ("[9, 1] ships." if prior["ships"] else "[0.9, 0.1] stays."),
    ]
    gacl = decision["gacl_termination_reward"]
    lines.append(
        f"2. GACL termination reward: zero {gacl['zero']['feasible_reward']:.2f}, on purpose on "
        f"{gacl['zero']['seeds_on_purpose']} seeds; repeat {gacl['repeat']['feasible_reward']:.2f}, on purpose on "
        f"{gacl['repeat']['seeds_on_purpose']} seeds: " + ("repeat ships." if gacl["ships"] else "zero stays.")
    )
    design = decision["design"]
    parts = [
        f"{algo} {100 * entry['violation_rate']:.0f}% violations, on purpose on {entry['seeds_on_purpose']} seeds"
        + (" (fails)" if entry["fails"] else "")
        for algo, entry in design["methods"].items()
    ]
    lines.append(
        "3. The design (base): "
        + "; ".join(parts)
        + (": it carries over." if design["carries_over"] else ": it does not carry over to two constraints.")
    )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("report", help="The report folder of benchmarks/suites/multi_tuning.yml (its summary.json)")
    parser.add_argument("--json", help="Also write the decisions to this JSON file")
    args = parser.parse_args(argv)
    try:
        runs = read_runs(args.report)
        decision = decide(runs, demonstrations_mean_length())
    except RuleInputError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print("\n".join(report_lines(runs, decision)))
    if args.json:
        atomic_write_json(args.json, decision, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
