"""
Constraint figures: the learned grid-world map beside the true one, the paper's partial-dependence plot, and
training curves (violation rate, feasible reward) over seeds.

Every figure is a :class:`matplotlib.figure.Figure` drawn on an Agg canvas: nothing touches pyplot or the global
backend, so plotting works headless and inside training processes. :func:`figure_to_rgb` renders one to an image
array and :func:`save_figure` writes it atomically.
"""

import io
import os
import pathlib
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch as th
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.ticker import EngFormatter, MaxNLocator

from sb3_icrl.common.constraint_spec import get_constraint_spec
from sb3_icrl.common.env_ids import env_name
from sb3_icrl.common.utils import atomic_write_bytes, check_evaluation_rows, read_npz
from sb3_icrl.constraints.networks import BetaFeasibilityNet, _ConstraintNet
from sb3_icrl.envs.grid_world import GridWorldEnv
from sb3_icrl.icrl.tabular import cost_table

#: Metrics of :func:`training_curves_figure`: name -> (key in ``evaluations.npz``, axis label)
CURVE_METRICS: dict[str, tuple[str, str]] = {
    "violation_rate": ("violations", "constraint violation rate"),
    "feasible_reward": ("feasible_rewards", "feasible cumulative reward"),
    "reward": ("results", "cumulative reward"),
}
EVALUATIONS_FILE = "evaluations.npz"


class TrueConstraint(NamedTuple):
    """
    A true constraint on one observation feature: cost 1 when ``obs[obs_index] op threshold``.

    :param name: Name of the constrained quantity (``"x_position"``, ``"ego_speed"``, ...)
    :param obs_index: Index of the quantity in the observation
    :param threshold: Threshold (the env's default, or the one given in its keyword arguments)
    :param op: ``"<="``, ``"<"``, ``">="`` or ``">"``
    """

    name: str
    obs_index: int
    threshold: float
    op: str

    @property
    def unsafe_side(self) -> str:
        """``"below"`` when values under the threshold break the constraint, else ``"above"``."""
        return unsafe_side(self.op)


def unsafe_side(op: str) -> str:
    """
    :param op: A comparison of :class:`TrueConstraint` (``"<="``, ``"<"``, ``">="``, ``">"``), or ``"below"``/``"above"``
    :return: ``"below"`` or ``"above"``: the side of the threshold where the constraint is broken
    """
    if op in ("<=", "<", "below"):
        return "below"
    if op in (">=", ">", "above"):
        return "above"
    raise ValueError(f"Unknown constraint side {op!r}: expected '<=', '<', '>=', '>', 'below' or 'above'.")


def _short_env_name(env_id: str) -> str:
    env_id = env_id.rpartition(":")[2]
    return env_id.split("/", 1)[1] if env_id.startswith("sb3_icrl/") else env_id


def constraint_features(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> tuple[TrueConstraint, ...]:
    """
    The true constraints of an env that are thresholds on one observation feature, as the env declares them
    (:func:`~sb3_icrl.common.constraint_spec.get_constraint_spec`), with the thresholds its keyword arguments set
    (``cost_threshold``, ``speed_limit``, ``min_gap``...).

    :param env_id: Env id, with or without the ``sb3_icrl/`` prefix (or ``MODULE:EnvId``)
    :param env_kwargs: The keyword arguments the env was made with
    :return: One :class:`TrueConstraint` per constraint (two for ``HighwayVelocityDistance-v0``)
    :raises ValueError: For the grid worlds (their constraint is a set of cells: see :func:`grid_cost_map`) and
        envs that declare no feature constraint
    """
    spec = get_constraint_spec(env_id, env_kwargs)
    name = _short_env_name(env_id)
    if spec is not None and spec.features:
        return tuple(TrueConstraint(f.name, f.obs_index, f.threshold, f.op) for f in spec.features)
    if spec is not None and spec.unsafe_states is not None:
        raise ValueError(f"{name}'s constraint is a set of unsafe cells, not a feature threshold: plot it with grid_cost_map.")
    raise ValueError(
        f"No known feature constraint for env {env_id!r}: give it a `constraint_spec` (sb3_icrl.common.constraint_spec), or "
        "for a plot name the feature with --feature INDEX [--threshold X] [--op '<=' or '>=']."
    )


def constraint_feature(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> TrueConstraint:
    """
    The (first) true feature constraint of an env: see :func:`constraint_features`.

    :param env_id: Env id, with or without the ``sb3_icrl/`` prefix
    :param env_kwargs: The keyword arguments the env was made with
    :return: Its constrained feature, threshold and side
    """
    return constraint_features(env_id, env_kwargs)[0]


# ---------------------------------------------------------------------------------------------------- rendering


def new_figure(width: float = 6.4, height: float = 4.8, dpi: int = 100) -> Figure:
    """
    A figure on its own Agg canvas (headless; pyplot and the global backend are left alone).

    :param width: Width in inches
    :param height: Height in inches
    :param dpi: Dots per inch
    :return: The empty figure
    """
    figure = Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def figure_to_rgb(figure: Figure) -> np.ndarray:
    """
    Render a figure to an image array.

    :param figure: The figure
    :return: ``(height, width, 3)`` ``uint8`` RGB pixels
    """
    canvas = figure.canvas if isinstance(figure.canvas, FigureCanvasAgg) else FigureCanvasAgg(figure)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def save_figure(figure: Figure, path: str | os.PathLike, dpi: int | None = None) -> pathlib.Path:
    """
    Save a figure atomically (drawn in memory, then written through a temporary file and a rename): readers never see
    a half-written image. The format follows the suffix (``.png`` by default, ``.pdf``, ``.svg``...).

    :param figure: The figure
    :param path: Destination file (its folder is created if needed)
    :param dpi: Resolution (default: the figure's)
    :return: The path written
    """
    path = pathlib.Path(path)
    image_format = path.suffix[1:].lower() or "png"
    buffer = io.BytesIO()
    figure.savefig(buffer, format=image_format, dpi=dpi if dpi is not None else "figure")
    atomic_write_bytes(path, buffer.getvalue())
    return path


# ---------------------------------------------------------------------------------------------------- grid maps


def grid_cost_map(constraint_net: _ConstraintNet, grid_env: Any) -> np.ndarray:
    """
    The learned cost ``1 - phi`` of every cell of a grid world (VICRL: of the Beta's mean), averaged over the actions
    when the net takes the action.

    :param constraint_net: A constraint net for the grid world's ``Discrete`` spaces
    :param grid_env: A :class:`~sb3_icrl.envs.GridWorldEnv` (or a wrapper of one)
    :return: Costs, shape ``(n_rows, n_cols)``
    """
    grid = getattr(grid_env, "unwrapped", grid_env)
    if not isinstance(grid, GridWorldEnv):
        raise TypeError(f"grid_cost_map needs a GridWorldEnv, got {type(grid).__name__}.")
    if not (constraint_net.discrete_obs and constraint_net.obs_dim == grid.n_states):
        raise ValueError(
            f"The constraint net takes {constraint_net.obs_dim} {'discrete' if constraint_net.discrete_obs else 'Box'} "
            f"observation features; this grid has {grid.n_states} discrete states."
        )
    costs = cost_table(constraint_net, grid.n_states, grid.n_actions)
    return costs.mean(axis=1).reshape(grid.n_rows, grid.n_cols)


def grid_constraint_figure(
    learned_cost: np.ndarray,
    true_unsafe: np.ndarray,
    start: tuple[int, int],
    goal: tuple[int, int],
    visited: np.ndarray | None = None,
    title: str | None = None,
    vmin: float = 0.0,
    vmax: float = 1.0,
    cmap: str = "Reds",
) -> Figure:
    """
    The learned constraint map of a grid world beside the true one.

    :param learned_cost: Learned cost of each cell, ``(n_rows, n_cols)`` (see :func:`grid_cost_map`)
    :param true_unsafe: Boolean mask of the truly unsafe cells, same shape
    :param start: ``(row, col)`` of the start cell (marked S)
    :param goal: ``(row, col)`` of the goal cell (marked G)
    :param visited: Optional boolean mask of the cells the expert walks through (dotted on both panels)
    :param title: Figure title
    :param vmin: Lower end of the colour scale
    :param vmax: Upper end of the colour scale
    :param cmap: Colour map of the learned cost
    :return: The figure
    """
    learned = np.asarray(learned_cost, dtype=float)
    unsafe = np.asarray(true_unsafe, dtype=bool)
    if learned.ndim != 2 or unsafe.shape != learned.shape:
        raise ValueError(
            f"`learned_cost` and `true_unsafe` must be 2-D maps of the same shape, got {learned.shape} and {unsafe.shape}."
        )
    if visited is not None and np.shape(visited) != learned.shape:
        raise ValueError(f"`visited` must have the map's shape {learned.shape}, got {np.shape(visited)}.")
    n_rows, n_cols = learned.shape
    for name, cell in (("start", start), ("goal", goal)):
        if not (0 <= cell[0] < n_rows and 0 <= cell[1] < n_cols):
            raise ValueError(f"The {name} cell {tuple(cell)} is outside the {n_rows}x{n_cols} map.")

    figure = new_figure(9.0, 4.2)
    learned_axis, true_axis = figure.subplots(1, 2)
    image = learned_axis.imshow(learned, cmap=cmap, vmin=vmin, vmax=vmax)
    figure.colorbar(image, ax=learned_axis, label="learned cost 1 - phi", shrink=0.85)
    learned_axis.set_title("learned constraint" + (" (dots: expert cells)" if visited is not None else ""))
    true_axis.imshow(unsafe.astype(float), cmap=ListedColormap(["white", "#d73027"]), vmin=0.0, vmax=1.0)
    true_axis.set_title("true constraint (red: unsafe)")
    for axis in (learned_axis, true_axis):
        axis.set_xticks(np.arange(n_cols))
        axis.set_yticks(np.arange(n_rows))
        # Cell borders
        axis.set_xticks(np.arange(-0.5, n_cols), minor=True)
        axis.set_yticks(np.arange(-0.5, n_rows), minor=True)
        axis.grid(which="minor", color="grey", linewidth=0.5)
        axis.tick_params(which="minor", length=0)
        axis.set_xlabel("column")
        axis.set_ylabel("row")
        if visited is not None:
            rows, cols = np.nonzero(np.asarray(visited, dtype=bool))
            axis.scatter(cols, rows, s=12, color="#2166ac", label="expert")
        for label, (row, col) in (("S", start), ("G", goal)):
            outline = [patheffects.withStroke(linewidth=3, foreground="white")]
            axis.text(
                col,
                row,
                label,
                ha="center",
                va="center",
                fontsize=12,
                fontweight="bold",
                color="#1a9850",
                path_effects=outline,
            )
    if title:
        figure.suptitle(title)
    return figure


# ---------------------------------------------------------------------------------------------------- partial dependence


@dataclass
class PartialDependence:
    """
    :param values: The grid of values of the feature, ``(n_values,)``
    :param mean_cost: Learned cost averaged over the samples at each value, ``(n_values,)`` (VICRL: of the Beta's mean)
    :param lower: Lower quantile of the sampled costs at each value (``None`` without Beta samples)
    :param upper: Upper quantile of the sampled costs at each value (``None`` without Beta samples)
    :param samples: Some sampled costs ``(n_values, n_points)`` to scatter (``None`` without Beta samples)
    """

    values: np.ndarray
    mean_cost: np.ndarray
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    samples: np.ndarray | None = None


def partial_dependence(
    constraint_net: _ConstraintNet,
    observations: np.ndarray,
    actions: np.ndarray | None,
    feature_index: int,
    values: np.ndarray,
    beta_samples: bool = False,
    n_beta_samples: int = 20,
    quantiles: tuple[float, float] = (0.1, 0.9),
    max_points: int = 5,
    max_samples: int | None = 2000,
    seed: int = 0,
) -> PartialDependence:
    """
    Partial dependence of the learned cost on one observation feature: for each value ``v``, set the feature to ``v``
    in every sample and average the learned cost ``1 - phi`` over the samples.

    :param constraint_net: The constraint net (Box observations)
    :param observations: Samples, ``(n_samples, obs_dim)``, raw as the env returns them (e.g. the expert's)
    :param actions: Their actions, ``(n_samples, action_dim)`` (``None`` when the net ignores the action)
    :param feature_index: Index of the feature in the observation
    :param values: Values of the feature to evaluate, ``(n_values,)``
    :param beta_samples: For a :class:`~sb3_icrl.constraints.BetaFeasibilityNet`: also draw ``phi`` from the Beta for
        the spread (quantiles of the sampled costs over samples and draws)
    :param n_beta_samples: Draws per pair for the spread
    :param quantiles: Lower and upper quantiles of the spread
    :param max_points: Sampled costs kept per value for a scatter
    :param max_samples: Average over at most this many samples, drawn at random without replacement (``None``: all)
    :param seed: Seed of the subsampling and the Beta draws
    :return: The curve (and its spread)
    """
    obs = np.asarray(observations, dtype=np.float32)
    if constraint_net.discrete_obs:
        raise ValueError("Partial dependence needs Box observations; for a grid world plot the cell map (grid_cost_map).")
    if obs.ndim != 2 or len(obs) == 0:
        raise ValueError(f"`observations` must be a non-empty batch (n_samples, obs_dim), got shape {obs.shape}.")
    if not 0 <= feature_index < obs.shape[1]:
        raise ValueError(f"`feature_index` {feature_index} is outside the {obs.shape[1]} observation features.")
    grid = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(grid) == 0:
        raise ValueError("`values` is empty.")
    if constraint_net.use_action and actions is None:
        raise ValueError("This constraint net takes the action: pass the samples' actions.")
    rng = np.random.default_rng(seed)
    keep = None
    if max_samples is not None and len(obs) > max_samples:
        keep = np.sort(rng.choice(len(obs), size=max_samples, replace=False))
        obs = obs[keep]
    n_samples = len(obs)
    # One batch of all (value, sample) pairs: row k * n_samples + i is sample i with the feature set to values[k]
    batch_obs = np.repeat(obs[None], len(grid), axis=0)
    batch_obs[:, :, feature_index] = grid[:, None]
    batch_obs = batch_obs.reshape(-1, obs.shape[1])
    batch_actions = None
    if constraint_net.use_action and actions is not None:
        acts = np.asarray(actions)
        if len(acts) != len(observations):
            raise ValueError(f"Got {len(observations)} observations but {len(acts)} actions.")
        acts = acts[keep] if keep is not None else acts
        batch_actions = np.concatenate([acts] * len(grid), axis=0)

    is_beta = isinstance(constraint_net, BetaFeasibilityNet)
    with th.no_grad():
        if is_beta:
            assert isinstance(constraint_net, BetaFeasibilityNet)
            alpha, beta = constraint_net.alpha_beta(batch_obs, batch_actions)
            costs = (beta / (alpha + beta)).cpu().numpy().astype(np.float64)  # 1 - mean of phi
        else:
            costs = 1.0 - constraint_net.predict_feasibility(batch_obs, batch_actions).astype(np.float64)
    result = PartialDependence(grid, costs.reshape(len(grid), n_samples).mean(axis=1))
    if beta_samples and is_beta:
        alphas, betas = alpha.cpu().double().numpy(), beta.cpu().double().numpy()
        phi = rng.beta(alphas, betas, size=(n_beta_samples, len(alphas)))
        sampled = (1.0 - phi).reshape(n_beta_samples, len(grid), n_samples).transpose(1, 0, 2).reshape(len(grid), -1)
        result.lower, result.upper = np.nanquantile(sampled, quantiles, axis=1)
        columns = rng.choice(sampled.shape[1], size=min(max_points, sampled.shape[1]), replace=False)
        result.samples = sampled[:, columns]
    return result


def default_feature_values(visited: np.ndarray, threshold: float, n_values: int = 101, margin: float = 0.1) -> np.ndarray:
    """
    An even grid over the visited values and the threshold, widened by ``margin`` of its span on each side.

    :param visited: Visited values of the feature
    :param threshold: The true threshold (``nan``: unknown, the grid spans the visited values only)
    :param n_values: Number of values
    :param margin: Widening, as a share of the span
    :return: The grid, ``(n_values,)``
    """
    finite = np.asarray(visited, dtype=float).reshape(-1)
    finite = finite[np.isfinite(finite)]
    if not np.isfinite(threshold):
        if len(finite) == 0:
            raise ValueError("No finite visited value and no threshold: cannot choose the values to plot.")
        threshold = float(finite[0])
    low, high = float(min(finite.min(initial=threshold), threshold)), float(max(finite.max(initial=threshold), threshold))
    span = high - low if high > low else max(abs(threshold), 1.0)
    return np.linspace(low - margin * span, high + margin * span, n_values)


def partial_dependence_figure(
    constraint_net: _ConstraintNet,
    observations: np.ndarray,
    actions: np.ndarray | None,
    feature_index: int,
    threshold: float,
    true_side: str,
    visited_values: np.ndarray | Mapping[str, np.ndarray],
    beta_samples: bool = False,
    values: np.ndarray | None = None,
    feature_name: str | None = None,
    title: str | None = None,
    bins: int = 40,
    seed: int = 0,
) -> Figure:
    """
    The paper's constraint plot: the partial dependence of the learned cost on the constrained feature (left; for a
    Beta net with ``beta_samples`` also the 10-90 % band and some samples of the cost), and a histogram of the visited
    values of that feature (right); the true threshold is a vertical line, the truly unsafe side is shaded.

    :param constraint_net: The constraint net
    :param observations: Samples to average over, ``(n_samples, obs_dim)`` (e.g. the expert's)
    :param actions: Their actions (``None`` when the net ignores the action)
    :param feature_index: Index of the constrained feature in the observation
    :param threshold: The true threshold (``nan`` when unknown: no threshold line)
    :param true_side: Where the true constraint is broken: ``"below"``/``"above"`` or an op (``"<="``, ``">"``...)
    :param visited_values: Visited values of the feature (an array, or ``{label: array}`` for several histograms,
        e.g. expert and policy; each normalised to a density so that sets of different sizes compare)
    :param beta_samples: For a Beta net: show the spread of sampled costs
    :param values: Grid of feature values (default: over the visited values and the threshold)
    :param feature_name: Axis label of the feature (default ``obs[<index>]``)
    :param title: Figure title
    :param bins: Histogram bins
    :param seed: Seed of the Beta draws
    :return: The figure
    """
    side = unsafe_side(true_side)
    visited = dict(visited_values) if isinstance(visited_values, Mapping) else {"visited": visited_values}
    visited = {label: np.asarray(array, dtype=float).reshape(-1) for label, array in visited.items()}
    all_visited = np.concatenate([*visited.values(), np.asarray(observations, dtype=float)[:, feature_index]])
    grid = default_feature_values(all_visited, threshold) if values is None else np.asarray(values, dtype=float)
    curve = partial_dependence(
        constraint_net, observations, actions, feature_index, grid, beta_samples=beta_samples, seed=seed
    )
    label = feature_name or f"obs[{feature_index}]"

    figure = new_figure(10.0, 4.0)
    pd_axis, hist_axis = figure.subplots(1, 2, sharex=True)
    if curve.samples is not None:
        points = curve.samples
        pd_axis.scatter(
            np.repeat(curve.values, points.shape[1]),
            points.reshape(-1),
            s=3,
            alpha=0.25,
            color="#2166ac",
            label="Beta samples",
        )
    if curve.lower is not None and curve.upper is not None:
        pd_axis.fill_between(curve.values, curve.lower, curve.upper, color="#f4a582", alpha=0.5, label="10-90 % of samples")
    pd_axis.plot(curve.values, curve.mean_cost, color="#b2182b", linewidth=2, label="partial dependence")
    pd_axis.set_ylim(-0.02, 1.02)
    pd_axis.set_ylabel("learned cost 1 - phi")
    pd_axis.set_title("learned constraint")
    edges = np.histogram_bin_edges(
        np.concatenate(list(visited.values())) if visited else grid, bins=bins, range=(grid[0], grid[-1])
    )
    for name, array in visited.items():
        hist_axis.hist(array[np.isfinite(array)], bins=edges, density=True, alpha=0.6, label=name)
    hist_axis.set_ylabel("density of visited states")
    hist_axis.set_title("visited values")
    for axis in (pd_axis, hist_axis):
        if np.isfinite(threshold):  # nan: an env without a declared constraint, plotted without its threshold
            axis.axvline(threshold, color="black", linestyle="--", linewidth=1.2, label=f"true threshold {threshold:g}")
            if side == "below":
                axis.axvspan(grid[0], threshold, color="grey", alpha=0.12)
            else:
                axis.axvspan(threshold, grid[-1], color="grey", alpha=0.12)
        axis.set_xlim(grid[0], grid[-1])
        axis.xaxis.set_major_locator(MaxNLocator(6))
        axis.set_xlabel(label)
        axis.legend(fontsize=7, loc="best")
    if feature_index not in constraint_net.obs_select_dim:
        pd_axis.text(0.5, 0.5, "feature not an input of the net", transform=pd_axis.transAxes, ha="center", color="grey")
    if title:
        figure.suptitle(title)
    return figure


def methods_partial_dependence_figure(
    curves: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
    threshold: float,
    true_side: str,
    feature_name: str = "constrained feature",
    level: float | None = 0.5,
    title: str | None = None,
) -> Figure:
    """
    The learned cost over the constrained feature for several methods on one env: per method one thin line per seed
    and their mean (each seed's curve interpolated onto the values all seeds cover); the true threshold is a vertical
    line and the truly unsafe side is shaded.

    :param curves: ``{method: [(values, mean learned cost) of each seed]}``, e.g. the ``curve`` of each run's
        identification scores (:func:`~sb3_icrl.metrics.identification.identify_run`)
    :param threshold: The true threshold
    :param true_side: Where the true constraint is broken: ``"below"``/``"above"`` or an op
    :param feature_name: Axis label of the feature
    :param level: A level ``t`` drawn as a dotted horizontal line (``None``: none)
    :param title: Figure title
    :return: The figure
    """
    if not curves or not any(curves.values()):
        raise ValueError("No curve to plot: pass {method: [(values, costs), ...]} with at least one seed.")
    side = unsafe_side(true_side)
    figure = new_figure(7.0, 4.2)
    axis = figure.subplots(1, 1)
    low, high = np.inf, -np.inf
    for method, seeds in curves.items():
        if not seeds:
            continue
        arrays = [(np.asarray(values, dtype=float), np.asarray(costs, dtype=float)) for values, costs in seeds]
        for values, costs in arrays:
            if values.shape != costs.shape or values.ndim != 1:
                raise ValueError(f"{method}: each seed's values and costs must be 1-D arrays of the same length.")
        start, stop = max(v[0] for v, _ in arrays), min(v[-1] for v, _ in arrays)
        grid = np.linspace(start, stop, 201) if stop > start else arrays[0][0]
        colour = None
        for values, costs in arrays:
            (line,) = axis.plot(values, costs, linewidth=0.7, alpha=0.35, color=colour)
            colour = line.get_color()
        mean = np.mean([np.interp(grid, values, costs) for values, costs in arrays], axis=0)
        n_seeds = len(arrays)
        axis.plot(grid, mean, linewidth=2.2, color=colour, label=f"{method} ({n_seeds} seed{'s' if n_seeds != 1 else ''})")
        low, high = min(low, min(v[0] for v, _ in arrays)), max(high, max(v[-1] for v, _ in arrays))
    axis.axvline(threshold, color="black", linestyle="--", linewidth=1.2, label=f"true threshold {threshold:g}")
    if side == "below":
        axis.axvspan(min(low, threshold), threshold, color="grey", alpha=0.12, label="truly unsafe")
    else:
        axis.axvspan(threshold, max(high, threshold), color="grey", alpha=0.12, label="truly unsafe")
    if level is not None:
        axis.axhline(level, color="grey", linestyle=":", linewidth=1.0, label=f"t = {level:g}")
    axis.set_xlim(min(low, threshold), max(high, threshold))
    axis.set_ylim(-0.02, 1.02)
    axis.set_xlabel(feature_name)
    axis.set_ylabel("learned cost (partial dependence)")
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8, loc="best")
    if title:
        axis.set_title(title)
    return figure


# ---------------------------------------------------------------------------------------------------- training curves


def load_evaluations(run_folder: str | os.PathLike, metrics: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """
    The arrays of a run's ``evaluations.npz`` (written by :class:`~sb3_icrl.zoo.callbacks.ConstraintEvalCallback`).

    :param run_folder: A run folder (``logs/<algo>/<EnvName>_<N>``) or the ``.npz`` file itself
    :param metrics: Keys of :data:`CURVE_METRICS` whose arrays the file must hold
    :return: ``timesteps`` (n_evals,) and per-episode arrays ``results``, ``feasible_rewards``, ``violations``... of
        shape (n_evals, n_episodes)
    :raises FileNotFoundError: When the folder or its ``evaluations.npz`` does not exist
    :raises ValueError: When the file is damaged, holds no ``timesteps``, not one row per evaluation in each array, or
        not the arrays of ``metrics`` (each naming the file)
    """
    path = pathlib.Path(run_folder)
    if path.suffix != ".npz":
        if not path.is_dir():
            raise FileNotFoundError(f"No run folder {path}.")
        path = path / EVALUATIONS_FILE
    if not path.is_file():
        raise FileNotFoundError(
            f"No {EVALUATIONS_FILE} in {path.parent}: the run has not been evaluated yet (train with --eval-freq > 0)."
        )
    try:
        arrays = read_npz(path)
    except ValueError as error:
        raise ValueError(f"{error} Train the run again, or delete the file to leave the run out of the curves.") from error
    check_evaluation_rows(arrays, path)
    for metric in metrics:
        _metric_key(arrays, metric, str(path))
    return arrays


def find_runs(log_folder: str | os.PathLike, algo: str, env: str) -> list[pathlib.Path]:
    """
    The rl-zoo run folders ``<log_folder>/<algo>/<EnvName>_<N>`` of one algorithm and env, by run number.

    :param log_folder: The training log folder (``-f`` of the training command)
    :param algo: Algorithm name (``mecl``)
    :param env: Env name or id (``BlockedHalfCheetah-v0`` or ``sb3_icrl/BlockedHalfCheetah-v0``)
    :return: The run folders (at least one)
    :raises FileNotFoundError: When there is none (the message lists what the folder holds)
    """
    algo_folder = pathlib.Path(log_folder) / algo
    name = env_name(env)  # the folder name train.py gives the env
    if not algo_folder.is_dir():
        there = (
            sorted(p.name for p in pathlib.Path(log_folder).iterdir() if p.is_dir())
            if pathlib.Path(log_folder).is_dir()
            else []
        )
        where = f"it holds {', '.join(there)}" if there else "it does not exist or is empty"
        raise FileNotFoundError(f"No runs of {algo!r} in {log_folder} ({where}).")
    runs = []
    for entry in algo_folder.iterdir():
        stem, _, suffix = entry.name.rpartition("_")
        if entry.is_dir() and stem == name and suffix.isdigit():
            runs.append((int(suffix), entry))
    if not runs:
        there = sorted({entry.name.rpartition("_")[0] for entry in algo_folder.iterdir() if entry.is_dir()})
        raise FileNotFoundError(f"No {name}_<N> runs in {algo_folder} (envs there: {', '.join(there) or 'none'}).")
    return [entry for _, entry in sorted(runs)]


def load_runs(
    log_folder: str | os.PathLike, algos: Sequence[str], env: str, skip_missing: bool = False, metrics: Sequence[str] = ()
) -> dict[str, list[dict[str, np.ndarray]]]:
    """
    The ``evaluations.npz`` arrays of every seed of each algorithm, ready for :func:`training_curves_figure`.

    :param log_folder: The training log folder (holds ``<algo>/<EnvName>_<N>``)
    :param algos: Algorithm names (``["mecl", "vicrl"]``)
    :param env: Env name or id
    :param skip_missing: Skip (with a warning) runs without a readable ``evaluations.npz`` instead of raising
    :param metrics: Keys of :data:`CURVE_METRICS` to be drawn: a file without their arrays is named here
    :return: ``{ALGO: [arrays of each run]}``
    :raises FileNotFoundError: For a missing folder, an algorithm without runs, or a run without evaluations
    """
    runs: dict[str, list[dict[str, np.ndarray]]] = {}
    for algo in algos:
        seeds = []
        for folder in find_runs(log_folder, algo, env):
            try:
                seeds.append(load_evaluations(folder, metrics))
            except (FileNotFoundError, ValueError) as error:  # (ValueError: a damaged file)
                if not skip_missing:
                    raise
                warnings.warn(f"{error} Skipped.", stacklevel=2)
        if not seeds:
            raise FileNotFoundError(f"No run of {algo} on {env} in {log_folder} has an {EVALUATIONS_FILE} yet.")
        runs[algo.upper()] = seeds
    return runs


def _metric_key(arrays: Mapping[str, np.ndarray], metric: str, source: str) -> str:
    """The key of ``metric``'s array, once ``arrays`` (of the file ``source``) are known to hold it."""
    if metric not in CURVE_METRICS:
        raise ValueError(f"Unknown metric {metric!r}: choose from {', '.join(CURVE_METRICS)}.")
    key = CURVE_METRICS[metric][0]
    if key not in arrays:
        raise ValueError(
            f"{source} has no {key!r} array (keys: {sorted(arrays)}): it was not written by ConstraintEvalCallback."
        )
    return key


def _metric_series(arrays: dict[str, np.ndarray], metric: str, source: str) -> np.ndarray:
    values = np.asarray(arrays[_metric_key(arrays, metric, source)], dtype=float)
    return values.reshape(len(values), -1).mean(axis=1)


def seed_statistics(runs: Sequence[Mapping[str, np.ndarray]], metric: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Mean and standard deviation of a metric over seeds, on the timesteps all runs cover (each run's curve is
    interpolated onto the union of their evaluation timesteps within the common range).

    :param runs: ``evaluations.npz`` arrays of each seed
    :param metric: A key of :data:`CURVE_METRICS`
    :return: Timesteps, mean and standard deviation, each ``(n_points,)``
    """
    if not runs:
        raise ValueError("No runs to average.")
    series = [
        (np.asarray(run["timesteps"], dtype=float), _metric_series(dict(run), metric, "evaluations.npz")) for run in runs
    ]
    series = [(t, v) for t, v in series if len(t)]
    if not series:
        raise ValueError("The runs hold no evaluation yet.")
    start, stop = max(t[0] for t, _ in series), min(t[-1] for t, _ in series)
    grid = np.unique(np.concatenate([t for t, _ in series]))
    grid = grid[(grid >= start) & (grid <= stop)]
    if len(grid) == 0:
        raise ValueError("The runs' evaluation timesteps do not overlap: they cannot be averaged.")
    curves = np.stack([np.interp(grid, t, v) for t, v in series])
    return grid, curves.mean(axis=0), curves.std(axis=0)


def training_curves_figure(
    runs: Mapping[str, Sequence[Mapping[str, np.ndarray]]],
    metrics: Sequence[str] = ("violation_rate", "feasible_reward"),
    title: str | None = None,
) -> Figure:
    """
    Evaluation metrics over training timesteps, mean +- std over seeds, one line per algorithm.

    :param runs: ``{algorithm label: [evaluations.npz arrays of each seed]}`` (see :func:`load_evaluations`)
    :param metrics: Keys of :data:`CURVE_METRICS`, one panel each
    :param title: Figure title
    :return: The figure
    """
    if not runs:
        raise ValueError("No algorithm to plot.")
    for metric in metrics:
        if metric not in CURVE_METRICS:
            raise ValueError(f"Unknown metric {metric!r}: choose from {', '.join(CURVE_METRICS)}.")
    figure = new_figure(5.0 * len(metrics), 4.0)
    axes = np.atleast_1d(figure.subplots(1, len(metrics)))
    for axis, metric in zip(axes, metrics, strict=True):
        for label, seeds in runs.items():
            timesteps, mean, std = seed_statistics(seeds, metric)
            (line,) = axis.plot(
                timesteps,
                mean,
                marker="o" if len(timesteps) < 20 else None,
                markersize=3,
                label=f"{label} ({len(seeds)} seed{'s' if len(seeds) != 1 else ''})",
            )
            axis.fill_between(timesteps, mean - std, mean + std, color=line.get_color(), alpha=0.2)
        axis.set_xlabel("timesteps")
        axis.xaxis.set_major_formatter(EngFormatter())  # 200k, 1M: long step counts do not overlap
        axis.set_ylabel(CURVE_METRICS[metric][1])
        if metric == "violation_rate":
            axis.set_ylim(-0.02, 1.02)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    if title:
        figure.suptitle(title)
    return figure
