"""
Constraint plots (headless matplotlib, Agg canvases): the learned grid map beside the true one, the paper's
partial-dependence plot of the learned cost on the constrained feature, and training curves over seeds.

    from sb3_icrl.plots import grid_constraint_figure, grid_cost_map, save_figure

    figure = grid_constraint_figure(grid_cost_map(model.constraint_net, env), env.unsafe_mask, env.start_cell, env.goal_cell)
    save_figure(figure, "map.png")

Command line: ``python -m sb3_icrl.plots curves|constraint ...``; during training: :class:`ConstraintFigureCallback`.
"""

from sb3_icrl.plots.callbacks import ConstraintFigureCallback
from sb3_icrl.plots.figures import (
    CURVE_METRICS,
    PartialDependence,
    TrueConstraint,
    constraint_feature,
    constraint_features,
    figure_to_rgb,
    find_runs,
    grid_constraint_figure,
    grid_cost_map,
    load_evaluations,
    load_runs,
    new_figure,
    partial_dependence,
    partial_dependence_figure,
    save_figure,
    seed_statistics,
    training_curves_figure,
)

__all__ = [
    "CURVE_METRICS",
    "ConstraintFigureCallback",
    "PartialDependence",
    "TrueConstraint",
    "constraint_feature",
    "constraint_features",
    "figure_to_rgb",
    "find_runs",
    "grid_constraint_figure",
    "grid_cost_map",
    "load_evaluations",
    "load_runs",
    "new_figure",
    "partial_dependence",
    "partial_dependence_figure",
    "save_figure",
    "seed_statistics",
    "training_curves_figure",
]
