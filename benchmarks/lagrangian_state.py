"""
Did a learner keep to the constraint it was given? For each finished run of a suite folder whose forward learner is
Lagrangian (BC2L, MECL, VICRL, the oracle; IRL-Plus's multiplier is held at 1), prints the cost budget, the learner's
mean cost per step in its last rollouts (the constraint value the multiplier compares with the budget), their ratio,
and the final Lagrange multiplier; for ICRL runs also the learned cost's mean on the expert's pairs and on the
learner's own evaluation episodes (from the run's ``identification.json``). With ``--through N``, N points of the
multiplier and the constraint value through training, read from the run's log. A learner whose cost ends far over its
budget did not meet the constraint it was given (its forward solver fell short), whatever its learned cost ranks; one
within its budget that still breaks the true constraint was given a cost that does not price the breach::

    python benchmarks/lagrangian_state.py logs/fresh/table3 --env BlockedHalfCheetahReach-v0 --through 6

Nothing here is seen by a learner: it reads finished runs.
"""

import argparse
import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.save_util import load_from_zip_file

from sb3_icrl.benchmark.suite import RunSpec
from sb3_icrl.metrics.transfer import LOG_COMMAND_PREFIX
from sb3_icrl.run_folder import is_finished

#: A line of SB3's logger table: ``|    lagrange_multiplier      | 3.87     |``
_LOG_ROW = re.compile(r"^\|\s+(\w+)\s+\|\s+(\S+)\s+\|$")
#: What the runner's line heading a training command in a run's log holds
_TRAINING_COMMAND = " sb3_icrl.zoo train "


def first(value: Any) -> float | None:
    """The first entry of a scalar or array, as a float (``None`` stays ``None``)."""
    if value is None:
        return None
    return float(np.asarray(value, dtype=float).reshape(-1)[0])


def saved_state(model_file: Path) -> dict[str, Any]:
    """
    The Lagrangian state a model zip saved at the end of its training (of its first constraint, where it has several).

    :param model_file: The run's final model zip
    :return: ``budget`` and ``budget_statistic`` (``"step"`` or ``"episode"``), ``n_costs``, ``step_cost`` (the last
        rollouts' mean cost per step), ``multiplier`` and the PID multiplier's ``proportional`` and ``integral`` terms
        (``None`` where the learner has none)
    """
    data, _, _ = load_from_zip_file(model_file, device="cpu", load_data=True)
    data = data or {}
    multiplier = data.get("lagrange_multiplier")
    return {
        "budget_statistic": data.get("budget_statistic"),
        "n_costs": data.get("n_costs", 1),
        "budget": first(data.get("cost_budget")),
        "step_cost": first(data.get("_rollout_mean_step_cost")),
        "multiplier": first(multiplier.value) if multiplier is not None else None,
        "proportional": first(getattr(multiplier, "delta_p", None)),
        "integral": first(getattr(multiplier, "integral", None)),
    }


def learned_cost_means(identification_file: Path) -> dict[str, float | None]:
    """
    :param identification_file: A run's ``identification.json``
    :return: The learned cost's mean per pair on the expert's demonstrations and on the learner's evaluation episodes
    """
    if not identification_file.is_file():
        return {"expert_cost": None, "learner_cost": None}
    sources = json.loads(identification_file.read_text()).get("scores", {}).get("sources", {})
    return {
        "expert_cost": sources.get("expert", {}).get("mean_cost"),
        "learner_cost": sources.get("learner", {}).get("mean_cost"),
    }


def logged_trajectory(log_file: Path, points: int) -> list[tuple[int, float, float]]:
    """
    The multiplier and the constraint value through training (the first constraint's, where there are several), from
    the logger tables the run's training commands printed. Tables printed by other commands in the log (its transfer
    test) are left out; where a resumed attempt goes back to a checkpoint, its rows replace those of the attempt before
    from that step on.

    :param log_file: The run's log (the suite runner's ``logs/<variant>_<algo>_<env>_<seed>.log``)
    :param points: How many evenly spaced points to keep (the last one always among them)
    :return: ``(total_timesteps, lagrange_multiplier, constraint_value)`` per point kept
    """
    rows: list[tuple[int, float, float]] = []
    table: dict[str, str] = {}
    training = True  # a log without command lines holds one training run
    for line in log_file.read_text(errors="replace").splitlines():
        if line.startswith(LOG_COMMAND_PREFIX):
            training, table = _TRAINING_COMMAND in line, {}
            continue
        match = _LOG_ROW.match(line.strip())
        if match:
            table[match.group(1)] = match.group(2)
        elif line.startswith("---") and table:
            multiplier = table.get("lagrange_multiplier", table.get("lagrange_multiplier_0"))
            value = table.get("constraint_value", table.get("constraint_value_0"))
            if training and "total_timesteps" in table and multiplier is not None and value is not None:
                steps = int(table["total_timesteps"])
                while rows and rows[-1][0] >= steps:
                    rows.pop()
                rows.append((steps, float(multiplier), float(value)))
            table = {}
    if len(rows) <= points:
        return rows
    keep = np.unique(np.linspace(0, len(rows) - 1, points).round().astype(int))
    return [rows[i] for i in keep]


def run_folders(folder: Path, env: str | None) -> list[Path]:
    """
    :param folder: A suite's run folder (``<folder>/<variant>/<algo>/<env>_<seed>/``)
    :param env: Only this env's runs (``None``: every env's)
    :return: The finished runs' folders, sorted
    """
    pattern = f"*/*/{env}_*" if env else "*/*/*_*"
    return sorted(path for path in folder.glob(pattern) if path.is_dir() and is_finished(str(path)))


def describe(run: Path, folder: Path, points: int) -> list[str]:
    """
    :param run: A finished run's folder
    :param folder: The suite's run folder (its ``logs/`` holds the run's log)
    :param points: Points of the trajectory to print (0: none)
    :return: The lines printed for the run (none when its learner is not Lagrangian)
    """
    env, seed = run.name.rsplit("_", 1)
    algo, variant = run.parent.name, run.parent.parent.name
    if not (run / f"{env}.zip").is_file():
        return [f"{variant}/{algo}/{env} seed {seed}: no final model ({env}.zip) in {run}"]
    try:
        state = saved_state(run / f"{env}.zip")
        costs = learned_cost_means(run / "identification.json")
    except (OSError, ValueError, KeyError) as error:  # a damaged zip or JSON: say so, go on with the other runs
        return [f"{variant}/{algo}/{env} seed {seed}: cannot read its model or identification scores ({error})"]
    if state["multiplier"] is None:
        return []

    def number(value: float | None) -> str:
        return "-" if value is None else f"{value:.3g}"

    budget, step_cost, per = state["budget"], state["step_cost"], state["budget_statistic"] or "episode"
    if per == "step":
        ratio = f" ({step_cost / budget:.3g}x the budget)" if budget and step_cost is not None else ""
    else:  # a budget on the episode's cost does not compare with a cost per step
        ratio = ""
    several = f" (the first of {state['n_costs']} constraints)" if state["n_costs"] > 1 else ""
    lines = [
        f"{variant}/{algo}/{env} seed {seed}{several}: budget {number(budget)} per {per}, last cost per step"
        f" {number(step_cost)}{ratio}, multiplier {number(state['multiplier'])} (P {number(state['proportional'])}, I"
        f" {number(state['integral'])}); learned cost on the expert {number(costs['expert_cost'])}, on the learner"
        f" {number(costs['learner_cost'])}"
    ]
    log_file = Path(RunSpec(folder.name, variant, algo, env, int(seed), None).log_file(folder.parent))
    if points and log_file.is_file():
        trajectory = logged_trajectory(log_file, points)
        lines.append(
            f"    through training (steps: multiplier / constraint value per {per}): "
            + ", ".join(f"{steps}: {multiplier:.3g} / {value:.3g}" for steps, multiplier, value in trajectory)
        )
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="A suite's run folder, e.g. logs/fresh/table3")
    parser.add_argument("--env", help="Only this env's runs, e.g. BlockedHalfCheetahReach-v0")
    parser.add_argument("--through", type=int, default=0, help="Points of the multiplier's trajectory to print")
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        parser.error(f"{args.folder} is not a folder; pass a suite's run folder such as logs/fresh/table3")
    if args.through < 0:
        parser.error(f"--through must be >= 0, got {args.through}")
    runs = run_folders(args.folder, args.env)
    if not runs:
        parser.error(f"no finished run under {args.folder}" + (f" for {args.env}" if args.env else ""))
    for run in runs:
        for line in describe(run, args.folder, args.through):
            print(line)


if __name__ == "__main__":
    main()
