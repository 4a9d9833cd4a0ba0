"""
What a zoo run prints: one line per evaluation, and at the end of an ICRL run the constraint it recovered, next to
the true one (grid worlds: the learned cost map against the true unsafe cells, with precision and recall; envs
constrained on one observation feature: the learned cost at the true threshold and at the start). The true constraint
is read here only to report.
"""

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_icrl.envs.grid_world import GridWorldEnv
from sb3_icrl.icrl.tabular import precision_recall
from sb3_icrl.plots.figures import constraint_features, grid_cost_map

#: A cell whose learned cost exceeds this is recovered as unsafe (a feasibility ``phi`` below 1/2)
UNSAFE_COST = 0.5


def evaluation_line(num_timesteps: int, metrics: Mapping[str, float], multiplier: float | None = None) -> str:
    """
    The one line an evaluation prints by default.

    :param num_timesteps: Steps trained so far
    :param metrics: The evaluation's metrics (``mean_reward``, ``violation_rate``, ``feasible_reward``...)
    :param multiplier: The learner's Lagrange multiplier, when it has one
    :return: ``step 4000: return 1.00, violation rate 0.00 (true), feasible reward 1.00, multiplier 0.35``
    """
    parts = [
        f"step {num_timesteps}: return {metrics['mean_reward']:.2f}",
        f"violation rate {metrics['violation_rate']:.2f} (true)",
        f"feasible reward {metrics['feasible_reward']:.2f}",
    ]
    if multiplier is not None:
        parts.append(f"multiplier {multiplier:.3g}")
    return ", ".join(parts)


def model_multiplier(model: Any) -> float | None:
    """
    :param model: A learner
    :return: Its (first) Lagrange multiplier, or ``None`` when it has none
    """
    multiplier = getattr(model, "lagrange_multiplier", None)
    if multiplier is None:
        return None
    return float(np.asarray(multiplier.value).reshape(-1)[0])


def grid_constraint_report(
    learned_cost: np.ndarray,
    unsafe_mask: np.ndarray,
    start_cell: tuple[int, int],
    goal_cell: tuple[int, int],
    expert_cells: np.ndarray,
    threshold: float = UNSAFE_COST,
) -> tuple[str, float, float]:
    """
    The learned cost map of a grid world beside the true one, as text: ``#`` unsafe, ``.`` safe, ``E`` a cell of the
    expert's path (recovered as safe; ``e`` if recovered as unsafe), ``S`` start, ``G`` goal; then each cell's cost.
    Precision and recall compare the cells recovered as unsafe (cost above ``threshold``, start and goal aside) with
    the truly unsafe ones; a second pair does the same for the cells dearer than every cell of the expert's path, the
    ones a planner on the learned cost avoids. Cells no trajectory comes near are among those: nothing in the data
    says they are safe.

    :param learned_cost: Learned cost per cell, ``(n_rows, n_cols)``
    :param unsafe_mask: True unsafe cells (evaluation only)
    :param start_cell: Start ``(row, col)``
    :param goal_cell: Goal ``(row, col)``
    :param expert_cells: Cells the demonstrations walk through
    :param threshold: Cost above which a cell is recovered as unsafe
    :return: The text, precision and recall
    """
    endpoints = np.zeros_like(unsafe_mask)
    endpoints[start_cell] = endpoints[goal_cell] = True
    recovered = (learned_cost > threshold) & ~endpoints
    precision, recall = precision_recall(recovered, unsafe_mask)
    # What a cost-minimising planner avoids: the cells dearer than every cell of the expert's path
    avoided = (learned_cost > learned_cost[expert_cells & ~endpoints].max(initial=0.0)) & ~endpoints
    avoided_precision, avoided_recall = precision_recall(avoided, unsafe_mask)

    def symbol(cell: tuple[int, int], unsafe: bool, expert: bool) -> str:
        if cell == start_cell:
            return "S"
        if cell == goal_cell:
            return "G"
        if expert:
            return "e" if unsafe else "E"
        return "#" if unsafe else "."

    n_rows, n_cols = unsafe_mask.shape
    width = max(n_cols, len("true"))
    lines = [f"{'true':<{width}}  {'learned':<{max(n_cols, len('learned'))}}  learned cost of each cell"]
    for row in range(n_rows):
        true_row = "".join(symbol((row, col), bool(unsafe_mask[row, col]), False) for col in range(n_cols))
        learned_row = "".join(
            symbol((row, col), bool(recovered[row, col]), bool(expert_cells[row, col])) for col in range(n_cols)
        )
        costs = " ".join(f"{cost:.2f}" for cost in learned_cost[row])
        lines.append(f"{true_row:<{width}}  {learned_row:<{max(n_cols, len('learned'))}}  {costs}")
    lines.append("# unsafe, . safe, E expert path (e: on it, yet learned unsafe), S start, G goal")
    lines.append(
        f"Learned unsafe (cost > {threshold:g}) against the true unsafe cells: precision {precision:.2f}, recall {recall:.2f}"
    )
    lines.append(
        f"Dearer than the whole expert path (what the planner avoids): precision {avoided_precision:.2f}, "
        f"recall {avoided_recall:.2f}"
    )
    return "\n".join(lines), precision, recall


def demonstration_cells(demonstrations: Any, n_rows: int, n_cols: int) -> np.ndarray:
    """
    :param demonstrations: Grid-world demonstrations (states as cell indices)
    :param n_rows: Rows of the grid
    :param n_cols: Columns of the grid
    :return: Boolean map of the cells the expert steps from (the goal, where episodes end, excluded)
    """
    visited = np.zeros(n_rows * n_cols, dtype=bool)
    visited[np.concatenate([np.asarray(t.obs[:-1]) for t in demonstrations]).astype(int)] = True
    return visited.reshape(n_rows, n_cols)


def feature_constraint_summary(
    model: Any, env_id: str, env_kwargs: Mapping[str, Any] | None, expert_obs: np.ndarray, expert_acts: np.ndarray
) -> list[str]:
    """
    One line per true constraint of a feature-constrained env: the learned cost at the true threshold and at the
    expert's start, each with the other features and the action of the expert's first pair.

    :param model: An ICRL model (its ``constraint_cost``)
    :param env_id: The env id
    :param env_kwargs: The env's keyword arguments (thresholds)
    :param expert_obs: Expert observations (raw)
    :param expert_acts: Expert actions
    :return: The lines
    """
    lines = []
    start_obs, start_act = np.asarray(expert_obs[:1], dtype=np.float64), np.asarray(expert_acts[:1])
    for feature in constraint_features(env_id, env_kwargs):
        at_threshold = start_obs.copy()
        at_threshold[0, feature.obs_index] = feature.threshold
        cost_start = float(np.asarray(model.constraint_cost(start_obs, start_act)).reshape(-1)[0])
        cost_threshold = float(np.asarray(model.constraint_cost(at_threshold, start_act)).reshape(-1)[0])
        lines.append(
            f"Recovered constraint on {feature.name} (unsafe where {feature.name} {feature.op} {feature.threshold:g}): "
            f"learned cost {cost_threshold:.2f} at the true threshold, {cost_start:.2f} at the start "
            f"({feature.name} = {start_obs[0, feature.obs_index]:.3g})"
        )
    return lines


def recovered_constraint(model: Any, env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> str | None:
    """
    What an ICRL model recovered, as text for the end of a run (``None`` when there is nothing to say: no learned
    constraint, no demonstrations, or an env whose true constraint is not a grid or a feature threshold).

    :param model: The trained model
    :param env_id: The registered env id
    :param env_kwargs: The env's keyword arguments
    :return: The text
    """
    if getattr(model, "constraint_net", None) is None or getattr(model, "demonstrations", None) is None:
        return None
    env = gym.make(env_id, **dict(env_kwargs or {}))
    try:
        grid = env.unwrapped
        if isinstance(grid, GridWorldEnv):
            costs = grid_cost_map(model.constraint_net, grid)
            expert = demonstration_cells(model.demonstrations, grid.n_rows, grid.n_cols)
            text, _, _ = grid_constraint_report(costs, grid.unsafe_mask, grid.start_cell, grid.goal_cell, expert)
            return f"Recovered constraint ({type(model).__name__} on {grid.map_name or env_id}):\n{text}"
    finally:
        env.close()
    try:
        lines = feature_constraint_summary(model, env_id, env_kwargs, model.expert_obs, model.expert_acts)
    except ValueError:
        return None
    return "\n".join(lines) or None


def print_lines(lines: Sequence[str]) -> None:
    """Print ``lines``, flushed (a run's log file shows them as they come)."""
    print("\n".join(lines), flush=True)


def print_recovered_constraint(model: Any, env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> None:
    """
    Print :func:`recovered_constraint` at the end of a run (nothing for a model without a learned constraint).

    :param model: The trained model
    :param env_id: The registered env id
    :param env_kwargs: The env's keyword arguments
    """
    text = recovered_constraint(model, env_id, env_kwargs)
    if text is not None:
        print_lines([text])


def show_progress_bar(verbose: int) -> bool:
    """
    Whether a run shows a progress bar without being asked (``--progress``): at the default verbosity, when its output
    goes to a terminal (not into a log file), and when SB3's progress bar can be drawn (tqdm and rich installed).

    :param verbose: The run's verbosity
    """
    import importlib.util
    import sys

    if verbose != 0 or not (sys.stdout.isatty() and sys.stderr.isatty()):
        return False
    return all(importlib.util.find_spec(module) is not None for module in ("tqdm", "rich"))
