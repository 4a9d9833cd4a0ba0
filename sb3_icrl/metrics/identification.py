"""
Does a learned constraint identify the true one? A learner can keep a 0% violation rate with a wrong constraint
(one that forbids far too much, or the right region for the wrong reason), so the violation rate alone does not say.
This module scores the learned cost itself against the true constraint, on a **probe set** of states and actions
built for evaluation only (it never reaches the learner):

- the expert's demonstrations, the learner's own episodes and, when a run of it is at hand, an unconstrained PPO
  agent's episodes (which go where the constraint binds);
- a **sweep** of each constrained feature across its range, the other features taken from visited states.

Scores (:func:`identification_scores`): the AUROC of the learned cost against the true cost label; precision,
recall and IoU of "learned cost > t" for ``t = 0.5`` and ``t`` = the learner's budget; the **threshold error**, where
the learned cost's partial dependence over the constrained feature crosses ``t``, less the true threshold, in the
feature's units (``inf`` or ``nan`` with a reason when it never crosses, see :func:`learned_threshold`); and the
expected calibration error of the learned cost read as a probability of violation. Grid worlds
(:func:`grid_identification`): precision, recall and IoU of the unsafe cells, over the cell map.

The true label of a pair ``(s, a)`` is the true constraint evaluated on the state ``s`` it is taken in.
"""

import json
import math
import os
import pathlib
from collections.abc import Callable, Mapping, Sequence
from copy import deepcopy
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.stats
import torch as th

from sb3_icrl.common.utils import atomic_write_json
from sb3_icrl.common.vec_env import load_vec_normalize
from sb3_icrl.constraints.networks import _ConstraintNet, reset_linear_layers
from sb3_icrl.data import load_demonstrations
from sb3_icrl.envs.wrappers import recorded_transition_noise, transition_noise_wrapper
from sb3_icrl.icrl.tabular import precision_recall
from sb3_icrl.plots.figures import (
    constraint_features,
    default_feature_values,
    grid_cost_map,
    methods_partial_dependence_figure,
    unsafe_side,
)
from sb3_icrl.registry import ALGOS, ICRL_ALGOS, env_name, import_gym_packages, resolve_env_id
from sb3_icrl.run_folder import find_vecnormalize, is_finished, load_run_args

#: Identification results cached in each run folder (keyed by their settings)
IDENTIFICATION_FILE = "identification.json"
#: The same for ``best_model.zip`` (``model="best"``), so that the final model's scores stay cached beside it
IDENTIFICATION_BEST_FILE = "identification_best.json"


def identification_file(model: str) -> str:
    """
    :param model: ``"final"``, ``"best"`` or a path to a model zip
    :return: The file in the run folder that caches that model's scores (for a path: ``identification_<stem>.json``,
        so that scoring a checkpoint does not replace the final model's cache)
    """
    if model == "final":
        return IDENTIFICATION_FILE
    if model == "best":
        return IDENTIFICATION_BEST_FILE
    return f"identification_{pathlib.Path(model).stem}.json"


#: Bumped when the scores change meaning, so that cached results are computed again (2: the untrained baseline is the
#: median of several initialisations, not one; 3: an untrained CostNet starts at cost 0, as a fresh one does)
IDENTIFICATION_VERSION = 3
#: Initialisations of the untrained baseline: on a probe set whose label is a threshold on one feature, any roughly
#: monotone random net scores near 0 or near 1, so a single draw says nothing
UNTRAINED_DRAWS = 10
#: Default bins of the expected calibration error
DEFAULT_CALIBRATION_BINS = 10

CostFn = Callable[[np.ndarray, np.ndarray | None], np.ndarray]


# ---------------------------------------------------------------------------------------------------- scores


def _binary_labels(labels: np.ndarray | Sequence[float], name: str = "labels") -> np.ndarray:
    array = np.asarray(labels, dtype=float).reshape(-1)
    if not np.all((array == 0.0) | (array == 1.0)):
        raise ValueError(f"`{name}` must hold 0/1 (or False/True) true cost labels, got values {np.unique(array)[:5]}.")
    return array.astype(bool)


def _scores(scores: np.ndarray | Sequence[float], n_expected: int, name: str = "scores") -> np.ndarray:
    array = np.asarray(scores, dtype=float).reshape(-1)
    if array.shape != (n_expected,):
        raise ValueError(f"`{name}` has {array.size} values for {n_expected} labels: pass one per labelled pair.")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"`{name}` holds non-finite values: a learned cost must be a finite number per pair.")
    return array


def auroc(scores: np.ndarray | Sequence[float], labels: np.ndarray | Sequence[float]) -> float:
    """
    Area under the ROC curve of ``scores`` as a detector of ``labels``: the probability that a random positive pair
    scores higher than a random negative one, ties counting one half (the Mann-Whitney statistic).

    :param scores: Learned cost per pair
    :param labels: True cost label per pair (0 or 1)
    :return: The AUROC in ``[0, 1]`` (0.5: no better than chance); ``nan`` when the labels hold one class only
    """
    truth = _binary_labels(labels)
    values = _scores(scores, truth.size)
    n_positive, n_negative = int(truth.sum()), int((~truth).sum())
    if n_positive == 0 or n_negative == 0:
        return float("nan")
    ranks = scipy.stats.rankdata(values)  # ties get their mean rank
    rank_sum = float(ranks[truth].sum())
    return (rank_sum - n_positive * (n_positive + 1) / 2.0) / (n_positive * n_negative)


def overlap_scores(predicted: np.ndarray | Sequence[bool], truth: np.ndarray | Sequence[bool]) -> dict[str, float]:
    """
    How well a predicted unsafe set matches the true one.

    :param predicted: Whether each item (pair, cell) is predicted unsafe
    :param truth: Whether each item is truly unsafe
    :return: ``precision`` (0 when nothing is predicted, as :func:`~sb3_icrl.icrl.tabular.precision_recall`),
        ``recall`` (``nan`` when nothing is truly unsafe) and ``iou`` (intersection over union; ``nan`` when both sets
        are empty)
    """
    guess = _binary_labels(predicted, "predicted")
    true = _binary_labels(truth, "truth")
    if guess.shape != true.shape:
        raise ValueError(f"`predicted` has {guess.size} items and `truth` {true.size}: pass one flag per item in both.")
    hits, n_guess, n_true = int(np.sum(guess & true)), int(guess.sum()), int(true.sum())
    union = int(np.sum(guess | true))
    return {
        "precision": hits / n_guess if n_guess else 0.0,
        "recall": hits / n_true if n_true else float("nan"),
        "iou": hits / union if union else float("nan"),
    }


def expected_calibration_error(
    probabilities: np.ndarray | Sequence[float], labels: np.ndarray | Sequence[float], n_bins: int = DEFAULT_CALIBRATION_BINS
) -> float:
    """
    Expected calibration error of the learned cost read as a probability of violation: the pairs are binned by their
    cost into ``n_bins`` equal bins of ``[0, 1]`` (the last one closed), and ECE is the mean over bins, weighted by the
    bin's share of pairs, of ``|mean cost in the bin - share of truly violating pairs in the bin|``.

    :param probabilities: Learned cost per pair, in ``[0, 1]``
    :param labels: True cost label per pair (0 or 1)
    :param n_bins: Number of bins
    :return: The ECE in ``[0, 1]`` (0: perfectly calibrated)
    """
    if n_bins < 1:
        raise ValueError(f"`n_bins` must be >= 1, got {n_bins}.")
    truth = _binary_labels(labels)
    values = _scores(probabilities, truth.size, "probabilities")
    if truth.size == 0:
        raise ValueError("No pairs to calibrate: pass at least one learned cost and label.")
    if values.min() < 0.0 or values.max() > 1.0:
        raise ValueError(
            f"The learned costs span [{values.min():g}, {values.max():g}]: calibration needs probabilities in [0, 1]."
        )
    bins = np.minimum((values * n_bins).astype(int), n_bins - 1)
    error = 0.0
    for index in np.unique(bins):
        members = bins == index
        error += members.mean() * abs(values[members].mean() - truth[members].mean())
    return float(error)


#: How a learned cost curve meets a level, read from the safe end of the feature's range (see :func:`crossing_kind`)
CROSSING_KINDS = ("crosses", "everywhere", "reversed", "both ends", "nowhere")
#: The crossings of a cost at or above the level at the safe end (no finite threshold), with ``"safe end"`` for one
#: whose curve is not at hand to tell which (:func:`headline`)
SAFE_END_CROSSINGS = ("everywhere", "reversed", "both ends", "safe end")


def _from_safe_end(values: np.ndarray, curve: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """The grid and curve as checked arrays, mirrored where needed so that index 0 is the safe end of the range."""
    grid, costs = np.asarray(values, dtype=float).reshape(-1), np.asarray(curve, dtype=float).reshape(-1)
    if grid.shape != costs.shape or grid.size < 2:
        raise ValueError(f"`values` and `curve` must be two arrays of the same length >= 2, got {grid.size} and {costs.size}.")
    if not np.all(np.diff(grid) > 0):
        raise ValueError("`values` must be strictly increasing.")
    if unsafe_side(side) == "below":  # read from the safe end (right) towards the unsafe one: mirror the grid
        return -grid[::-1], costs[::-1]
    return grid, costs


def crossing_kind(values: np.ndarray, curve: np.ndarray, level: float, side: str) -> str:
    """
    How a learned cost curve over a constrained feature meets ``level``, read from the safe end of the range:

    - ``"crosses"``: below the level at the safe end, at or above it somewhere toward the unsafe end (a finite
      learned threshold, :func:`learned_threshold`);
    - ``"everywhere"``: at or above the level over the whole range (the learned constraint forbids all of it);
    - ``"reversed"``: at or above it at the safe end, below it at the unsafe end (the cost rises toward the safe side);
    - ``"both ends"``: at or above it at both ends, below it somewhere between;
    - ``"nowhere"``: below the level over the whole range (nothing learned at that level).

    The last four have no finite learned threshold: ``inf`` for the three that reach the safe end, ``nan`` for
    ``"nowhere"``.

    :param values: Increasing grid of feature values
    :param curve: Learned cost at each value (a partial dependence)
    :param level: The level ``t``
    :param side: ``"below"`` or ``"above"`` (or an op: ``"<="``, ``">"``...), the truly unsafe side
    :return: One of :data:`CROSSING_KINDS`
    """
    _, costs = _from_safe_end(values, curve, side)
    return _kind_from_safe_end(costs >= level)


def _kind_from_safe_end(above_level: np.ndarray) -> str:
    """:func:`crossing_kind` of where a curve, read from the safe end (index 0), is at or above the level."""
    if not above_level.any():
        return "nowhere"
    if not above_level[0]:
        return "crosses"
    if above_level.all():
        return "everywhere"
    return "both ends" if above_level[-1] else "reversed"


@dataclass(frozen=True)
class ThresholdCrossing:
    """
    Where a learned cost curve over a constrained feature crosses a level.

    :param value: The learned threshold in the feature's units; ``inf`` (``-inf`` for an ``"above"`` constraint) when
        the curve stays at or above the level up to the safe end of the range, ``nan`` when it never reaches the level
    :param reason: Why there is no finite crossing (``None`` when there is one)
    """

    value: float
    reason: str | None = None


def learned_threshold(values: np.ndarray, curve: np.ndarray, level: float, side: str) -> ThresholdCrossing:
    """
    The learned threshold: the edge of the region where the curve is at or above ``level`` that reaches furthest into
    the safe side. For a constraint broken below the threshold (``side="below"``) it is the largest value where the
    curve, read left to right, falls from ``>= level`` to ``< level`` (linearly interpolated between grid values); for
    ``side="above"``, the smallest value where it rises to ``>= level``.

    :param values: Increasing grid of feature values
    :param curve: Learned cost at each value (a partial dependence)
    :param level: The level ``t``
    :param side: ``"below"`` or ``"above"`` (or an op: ``"<="``, ``">"``...), the truly unsafe side
    :return: The crossing, or ``inf``/``nan`` with the reason there is none
    """
    grid, costs = _from_safe_end(values, curve, side)
    below = unsafe_side(side) == "below"
    above_level = costs >= level
    span = f"[{min(values[0], values[-1]):g}, {max(values[0], values[-1]):g}]"
    kind = _kind_from_safe_end(above_level)
    if kind == "nowhere":
        return ThresholdCrossing(float("nan"), f"the learned cost never reaches {level:g} over {span}")
    first = int(np.argmax(above_level))
    if first == 0:
        sign = 1.0 if below else -1.0
        end = "right" if below else "left"
        shape = {
            "everywhere": f"over the whole of {span}",
            "reversed": f"at the safe ({end}) end of {span}, below it at the unsafe end (it rises toward the safe side)",
            "both ends": f"at both ends of {span} and below it between",
        }[kind]
        return ThresholdCrossing(sign * float("inf"), f"the learned cost is >= {level:g} {shape}: no crossing")
    # Between grid[first - 1] (below the level) and grid[first] (at or above it)
    low_cost, high_cost = costs[first - 1], costs[first]
    fraction = (level - low_cost) / (high_cost - low_cost)
    crossing = grid[first - 1] + fraction * (grid[first] - grid[first - 1])
    return ThresholdCrossing(float(-crossing if below else crossing))


def threshold_error(
    values: np.ndarray, curve: np.ndarray, level: float, true_threshold: float, side: str
) -> tuple[float, ThresholdCrossing]:
    """
    Learned threshold (:func:`learned_threshold`) less the true one, in the feature's units.

    :param values: Increasing grid of feature values
    :param curve: Learned cost at each value
    :param level: The level ``t``
    :param true_threshold: The true threshold
    :param side: The truly unsafe side (``"below"``, ``"above"`` or an op)
    :return: The signed error (``inf`` or ``nan`` when there is no crossing) and the crossing
    """
    crossing = learned_threshold(values, curve, level, side)
    return crossing.value - float(true_threshold), crossing


# ---------------------------------------------------------------------------------------------------- probe set


def violates(values: np.ndarray, threshold: float, op: str) -> np.ndarray:
    """
    :param values: Values of a constrained feature
    :param threshold: The true threshold
    :param op: ``"<="``, ``"<"``, ``">="`` or ``">"``: the constraint is broken when ``value op threshold``
    :return: Whether each value breaks the constraint
    """
    array = np.asarray(values, dtype=float)
    operations: dict[str, Callable[[np.ndarray, float], np.ndarray]] = {
        "<=": np.less_equal,
        "<": np.less,
        ">=": np.greater_equal,
        ">": np.greater,
    }
    if op not in operations:
        raise ValueError(f"Unknown constraint op {op!r}: expected one of {', '.join(operations)}.")
    return operations[op](array, threshold)


def true_cost_labels(observations: np.ndarray, constraints: Sequence[Any]) -> np.ndarray:
    """
    True cost label of each observation: 1 when any constraint is broken (evaluation only).

    :param observations: ``(n, obs_dim)`` raw observations
    :param constraints: :class:`~sb3_icrl.plots.figures.TrueConstraint` of the env
    :return: ``(n,)`` booleans
    """
    obs = np.asarray(observations, dtype=float)
    labels = np.zeros(len(obs), dtype=bool)
    for constraint in constraints:
        labels |= violates(obs[:, constraint.obs_index], constraint.threshold, constraint.op)
    return labels


@dataclass
class ProbeSet:
    """
    States and actions on which a learned cost is scored (built for evaluation only: the arrays are read-only copies,
    and nothing here is handed to a learner).

    :param observations: ``(n, obs_dim)`` raw observations
    :param actions: ``(n, ...)`` actions as sent to the env
    :param sources: ``(n,)`` where each pair comes from: ``"expert"``, ``"learner"``, ``"unconstrained"``,
        ``"sweep:<feature>"``
    """

    observations: np.ndarray
    actions: np.ndarray
    sources: np.ndarray

    def __len__(self) -> int:
        return len(self.observations)

    def counts(self) -> dict[str, int]:
        """Pairs per source."""
        names, counts = np.unique(self.sources, return_counts=True)
        return {str(name): int(count) for name, count in zip(names, counts, strict=True)}


def _read_only(array: np.ndarray) -> np.ndarray:
    copy = np.array(array, copy=True)
    copy.setflags(write=False)
    return copy


def _subsample(obs: np.ndarray, acts: np.ndarray, limit: int | None, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    if limit is not None and len(obs) > limit:
        keep = np.sort(rng.choice(len(obs), size=limit, replace=False))
        return obs[keep], acts[keep]
    return obs, acts


def feature_grid(visited: np.ndarray, threshold: float, n_values: int = 51, margin: float = 0.1) -> np.ndarray:
    """
    An even grid of a constrained feature over its visited values and the true threshold, widened by ``margin``.

    :param visited: Visited values of the feature
    :param threshold: The true threshold
    :param n_values: Number of values
    :param margin: Widening, as a share of the span
    :return: ``(n_values,)``
    """
    return default_feature_values(visited, threshold, n_values=n_values, margin=margin)


def build_probe_set(
    constraints: Sequence[Any],
    sources: Mapping[str, tuple[np.ndarray, np.ndarray]],
    n_sweep_values: int = 51,
    n_sweep_states: int = 100,
    max_per_source: int | None = 5000,
    seed: int = 0,
) -> ProbeSet:
    """
    The probe set: the pairs of each source, then for each constrained feature a sweep of that feature over
    :func:`feature_grid` of its visited values, each value set in ``n_sweep_states`` visited pairs drawn at random.

    :param constraints: The env's :class:`~sb3_icrl.plots.figures.TrueConstraint` (features to sweep)
    :param sources: ``{name: (observations, actions)}``, e.g. ``expert``, ``learner``, ``unconstrained``
    :param n_sweep_values: Values per swept feature
    :param n_sweep_states: Visited pairs each value is set in
    :param max_per_source: Keep at most this many pairs of each source, drawn at random (``None``: all)
    :param seed: Seed of the draws
    :return: The probe set
    """
    if not sources:
        raise ValueError("No source of probe pairs: pass at least the expert's (observations, actions).")
    if n_sweep_values < 2 or n_sweep_states < 1:
        raise ValueError(f"A sweep needs >= 2 values and >= 1 state, got {n_sweep_values} and {n_sweep_states}.")
    rng = np.random.default_rng(seed)
    observations, actions, names = [], [], []
    for name, (obs, acts) in sources.items():
        obs, acts = np.asarray(obs), np.asarray(acts)
        if obs.ndim != 2 or len(obs) == 0 or len(acts) != len(obs):
            raise ValueError(
                f"Source {name!r}: expected a non-empty (n, obs_dim) batch and one action per observation, "
                f"got observations {obs.shape} and actions {acts.shape}."
            )
        obs, acts = _subsample(obs, acts, max_per_source, rng)
        observations.append(obs.astype(np.float64))
        actions.append(acts)
        names += [name] * len(obs)
    visited_obs, visited_acts = np.concatenate(observations), np.concatenate(actions)
    for constraint in constraints:
        grid = feature_grid(visited_obs[:, constraint.obs_index], constraint.threshold, n_sweep_values)
        # Each value gets its own draw of distinct visited pairs (with replacement only when there are too few)
        n_visited = len(visited_obs)
        rows = np.stack([rng.choice(n_visited, size=n_sweep_states, replace=n_visited < n_sweep_states) for _ in grid])
        swept = visited_obs[rows].copy()  # (n_values, n_states, obs_dim)
        swept[:, :, constraint.obs_index] = grid[:, None]
        observations.append(swept.reshape(-1, visited_obs.shape[1]))
        actions.append(visited_acts[rows.reshape(-1)])
        names += [f"sweep:{constraint.name}"] * rows.size
    return ProbeSet(_read_only(np.concatenate(observations)), _read_only(np.concatenate(actions)), _read_only(np.array(names)))


def partial_dependence_curve(
    cost_fn: CostFn,
    observations: np.ndarray,
    actions: np.ndarray | None,
    feature_index: int,
    values: np.ndarray,
    max_samples: int | None = 500,
    seed: int = 0,
) -> np.ndarray:
    """
    Partial dependence of a learned cost on one feature: for each value, set the feature to it in every sample and
    average the cost over the samples.

    :param cost_fn: ``cost_fn(observations, actions) -> costs``
    :param observations: ``(n, obs_dim)`` samples (visited states)
    :param actions: Their actions
    :param feature_index: Index of the feature
    :param values: ``(n_values,)`` values of the feature
    :param max_samples: Average over at most this many samples drawn at random (``None``: all)
    :param seed: Seed of the draw
    :return: ``(n_values,)`` mean costs
    """
    obs = np.asarray(observations, dtype=np.float64)
    acts = None if actions is None else np.asarray(actions)
    if obs.ndim != 2 or len(obs) == 0 or not 0 <= feature_index < obs.shape[1]:
        raise ValueError(f"Need a non-empty (n, obs_dim) batch with feature {feature_index}, got shape {obs.shape}.")
    if max_samples is not None and len(obs) > max_samples:
        keep = np.sort(np.random.default_rng(seed).choice(len(obs), size=max_samples, replace=False))
        obs, acts = obs[keep], None if acts is None else acts[keep]
    grid = np.asarray(values, dtype=np.float64).reshape(-1)
    batch = np.repeat(obs[None], len(grid), axis=0)
    batch[:, :, feature_index] = grid[:, None]
    batch_acts = None if acts is None else np.concatenate([acts] * len(grid), axis=0)
    costs = np.asarray(cost_fn(batch.reshape(-1, obs.shape[1]), batch_acts), dtype=np.float64).reshape(len(grid), len(obs))
    return costs.mean(axis=1)


def _level_key(name: str) -> str:
    return f"at_{name}"


def identification_scores(
    cost_fn: CostFn,
    probes: ProbeSet,
    constraints: Sequence[Any],
    budget: float | None = None,
    n_bins: int = DEFAULT_CALIBRATION_BINS,
    n_curve_values: int = 101,
    seed: int = 0,
) -> dict[str, Any]:
    """
    Score a learned cost against the true constraint on a probe set.

    :param cost_fn: The learned cost, ``cost_fn(observations, actions) -> costs`` in ``[0, 1]``
    :param probes: The probe set (:func:`build_probe_set`)
    :param constraints: The env's :class:`~sb3_icrl.plots.figures.TrueConstraint` (evaluation only)
    :param budget: The learner's budget on the learned cost (per step); ``None``: only ``t = 0.5`` is scored
    :param n_bins: Bins of the calibration error
    :param n_curve_values: Grid values of each feature's partial dependence
    :param seed: Seed of the partial dependence's sample draw
    :return: A JSON-ready dict: ``auroc``, ``ece``, ``n_probes``, ``sources`` (pairs, mean learned cost and true
        violation share per source), ``levels`` (``{"0.5": t, "budget": t}``), and per level ``at_<level>`` with
        ``precision``, ``recall``, ``iou``; ``features``: per constrained feature its own ``auroc``, the true
        ``threshold`` and ``op``, the partial dependence ``curve`` (``values``, ``mean_cost``) and per level the
        ``threshold_error``, ``learned_threshold`` and ``reason`` (``None`` unless there is no crossing)
    """
    if not constraints:
        raise ValueError("No true constraint to score against.")
    # Writable copies: the probe set stays read-only, and torch refuses to wrap read-only arrays quietly
    costs = np.asarray(cost_fn(np.array(probes.observations), np.array(probes.actions)), dtype=np.float64).reshape(-1)
    if costs.shape != (len(probes),):
        raise ValueError(f"The cost function returned {costs.size} costs for {len(probes)} probe pairs.")
    labels = true_cost_labels(probes.observations, constraints)
    levels = {"0.5": 0.5}
    if budget is not None:
        if not np.isfinite(budget):
            raise ValueError(f"`budget` must be a finite float, got {budget!r}.")
        levels["budget"] = float(budget)
    result: dict[str, Any] = {
        "auroc": auroc(costs, labels),
        "ece": expected_calibration_error(np.clip(costs, 0.0, 1.0), labels, n_bins),
        "n_probes": len(probes),
        "levels": levels,
        "sources": {},
    }
    for name in probes.counts():
        members = probes.sources == name
        result["sources"][name] = {
            "n_pairs": int(members.sum()),
            "mean_cost": float(costs[members].mean()),
            "violation_share": float(labels[members].mean()),
        }
    for name, level in levels.items():
        result[_level_key(name)] = overlap_scores(costs > level, labels)

    visited = ~np.char.startswith(probes.sources.astype(str), "sweep:")
    visited_obs, visited_acts = np.asarray(probes.observations)[visited], np.asarray(probes.actions)[visited]
    result["features"] = {}
    for constraint in constraints:
        feature_labels = violates(
            np.asarray(probes.observations)[:, constraint.obs_index], constraint.threshold, constraint.op
        )
        values = feature_grid(visited_obs[:, constraint.obs_index], constraint.threshold, n_curve_values)
        curve = partial_dependence_curve(cost_fn, visited_obs, visited_acts, constraint.obs_index, values, seed=seed)
        entry: dict[str, Any] = {
            "auroc": auroc(costs, feature_labels),
            "threshold": float(constraint.threshold),
            "op": constraint.op,
            "curve": {"values": values.tolist(), "mean_cost": curve.tolist()},
        }
        for name, level in levels.items():
            error, crossing = threshold_error(values, curve, level, constraint.threshold, constraint.op)
            entry[_level_key(name)] = {
                **overlap_scores(costs > level, feature_labels),
                "threshold_error": error,
                "learned_threshold": crossing.value,
                "reason": crossing.reason,
            }
        result["features"][constraint.name] = entry
    return result


def grid_identification(
    cost_map: np.ndarray, unsafe_mask: np.ndarray, budget: float | None = None, n_bins: int = DEFAULT_CALIBRATION_BINS
) -> dict[str, Any]:
    """
    Score a grid world's learned cost map against its unsafe cells (every cell is a probe; no threshold error: the
    constraint is a set of cells, not a threshold on a feature).

    :param cost_map: Learned cost per cell, ``(n_rows, n_cols)`` (see :func:`~sb3_icrl.plots.figures.grid_cost_map`)
    :param unsafe_mask: Whether each cell is truly unsafe, same shape
    :param budget: The learner's budget; ``None``: only ``t = 0.5`` is scored
    :param n_bins: Bins of the calibration error
    :return: ``auroc``, ``ece``, ``n_probes``, ``levels`` and per level ``at_<level>`` with ``precision``, ``recall``
        (those of :func:`~sb3_icrl.icrl.tabular.precision_recall`) and ``iou``
    """
    costs, unsafe = np.asarray(cost_map, dtype=float), np.asarray(unsafe_mask, dtype=bool)
    if costs.shape != unsafe.shape:
        raise ValueError(f"`cost_map` {costs.shape} and `unsafe_mask` {unsafe.shape} must have the same shape.")
    if not unsafe.any():
        raise ValueError("The grid has no unsafe cell: there is no constraint to identify.")
    levels = {"0.5": 0.5, **({"budget": float(budget)} if budget is not None else {})}
    result: dict[str, Any] = {
        "auroc": auroc(costs.reshape(-1), unsafe.reshape(-1)),
        "ece": expected_calibration_error(np.clip(costs, 0.0, 1.0).reshape(-1), unsafe.reshape(-1), n_bins),
        "n_probes": int(costs.size),
        "levels": levels,
        "features": {},
    }
    for name, level in levels.items():
        recovered = costs > level
        precision, recall = precision_recall(recovered, unsafe)
        result[_level_key(name)] = {"precision": precision, "recall": recall, "iou": overlap_scores(recovered, unsafe)["iou"]}
    return result


# ---------------------------------------------------------------------------------------------------- models and runs


def learned_cost_fn(model: Any) -> CostFn:
    """
    The learned cost of an ICRL model, a constraint net or a plain function, as ``cost_fn(observations, actions)``.

    :param model: An ICRL algorithm (``constraint_cost``), a constraint net (``cost``) or a callable
    :return: The cost function
    """
    if hasattr(model, "constraint_cost") and getattr(model, "constraint_net", None) is not None:
        return model.constraint_cost
    if hasattr(model, "cost") and callable(model.cost):
        return model.cost
    if callable(model):
        return model
    raise TypeError(
        f"{type(model).__name__} holds no learned cost: pass an ICRL model (BC2L, MECL, VICRL, GACL), a constraint "
        "net or a function cost_fn(observations, actions) -> costs."
    )


def policy_pairs(
    policy: Any,
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    n_episodes: int = 3,
    seed: int = 0,
    vecnormalize_path: str | None = None,
    transition_noise: float = 0.0,
    max_steps: int = 20_000,
    transition_noise_model: str = "component",
) -> tuple[np.ndarray, np.ndarray]:
    """
    Raw observations and actions of a policy's deterministic episodes (with its saved ``VecNormalize`` statistics).

    :param policy: Anything with SB3's ``predict``
    :param env_id: Env id
    :param env_kwargs: Env keyword arguments
    :param n_episodes: Episodes to run
    :param seed: Seed of the env
    :param vecnormalize_path: The policy's ``VecNormalize`` statistics, if it was trained with them
    :param transition_noise: Transition noise of the env the policy was trained on
    :param max_steps: Stop after this many steps even if the episodes have not ended
    :param transition_noise_model: How that noise is drawn (see :class:`~sb3_icrl.envs.wrappers.TransitionNoiseWrapper`)
    :return: ``(observations, actions)``, one row per step
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    wrapper = transition_noise_wrapper(transition_noise, transition_noise_model)
    venv: Any = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=dict(env_kwargs or {}), wrapper_class=wrapper)
    if vecnormalize_path is not None:
        venv = load_vec_normalize(vecnormalize_path, venv)
        venv.training, venv.norm_reward = False, False
    observations, actions = [], []
    obs = venv.reset()
    finished = steps = 0
    while finished < n_episodes and steps < max_steps:
        raw = venv.get_original_obs() if isinstance(venv, VecNormalize) else obs
        action, _ = policy.predict(obs, deterministic=True)
        observations.append(np.asarray(raw).reshape(1, -1))
        actions.append(np.asarray(action).reshape(1, *np.shape(action)[1:]))
        obs, _, dones, _ = venv.step(action)
        finished += int(dones.sum())
        steps += 1
    venv.close()
    return np.concatenate(observations), np.concatenate(actions)


def identify_model(
    model: Any,
    env_id: str,
    expert: tuple[np.ndarray, np.ndarray],
    env_kwargs: Mapping[str, Any] | None = None,
    other_sources: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
    budget: float | None = None,
    n_sweep_values: int = 51,
    n_sweep_states: int = 100,
    seed: int = 0,
    n_untrained: int = UNTRAINED_DRAWS,
) -> dict[str, Any]:
    """
    Identification scores of a learned constraint (an ICRL model, a constraint net or a cost function) on an env.
    For a constraint net, ``untrained_auroc`` is what its shape and input scaling alone give on the same probes: the
    median AUROC of ``n_untrained`` fresh initialisations (seeds ``seed``, ``seed + 1``, ...), with their range in
    ``untrained_auroc_range`` and each draw in ``untrained_draws``.

    :param model: The learned constraint
    :param env_id: The env it was learned on (gives the true constraint, for evaluation only)
    :param expert: The expert's ``(observations, actions)``
    :param env_kwargs: The env's keyword arguments (thresholds)
    :param other_sources: More probe pairs, e.g. ``{"learner": ..., "unconstrained": ...}``
    :param budget: The learner's budget (default: the model's ``cost_budget`` when it has one)
    :param n_sweep_values: Values per swept feature
    :param n_sweep_states: Visited pairs each swept value is set in
    :param seed: Seed of the draws
    :param n_untrained: Initialisations of the untrained baseline (a net's only)
    :return: See :func:`identification_scores` (grid worlds: :func:`grid_identification`)
    """
    import gymnasium as gym

    if n_untrained < 1:
        raise ValueError(f"`n_untrained` must be at least 1 (initialisations of the untrained baseline), got {n_untrained}.")
    cost_fn = learned_cost_fn(model)
    if budget is None and getattr(model, "cost_budget", None) is not None:
        budget = float(np.asarray(model.cost_budget).reshape(-1)[0])
    net = getattr(model, "constraint_net", model)
    if getattr(net, "discrete_obs", False):
        grid = gym.make(env_id, **dict(env_kwargs or {})).unwrapped
        return grid_identification(grid_cost_map(net, grid), grid.unsafe_mask, budget)  # type: ignore[attr-defined]

    constraints = constraint_features(env_id, env_kwargs)
    probes = build_probe_set(
        constraints, {"expert": expert, **dict(other_sources or {})}, n_sweep_values, n_sweep_states, seed=seed
    )
    scores = identification_scores(cost_fn, probes, constraints, budget=budget, seed=seed)
    if isinstance(net, th.nn.Module) and hasattr(net, "cost"):
        # What the net's shape and input scaling alone give on these probes: a learned cost should beat it
        labels = true_cost_labels(probes.observations, constraints)
        observations, actions = np.array(probes.observations), np.array(probes.actions)
        draws = []
        for draw_seed in range(seed, seed + n_untrained):
            untrained_cost = learned_cost_fn(untrained_copy(net, draw_seed))
            costs = np.asarray(untrained_cost(observations, actions), dtype=np.float64)
            draws.append(auroc(costs.reshape(-1), labels))
        scores["untrained_auroc"] = float(np.median(draws))
        scores["untrained_auroc_range"] = [float(np.min(draws)), float(np.max(draws))]
        scores["untrained_draws"] = [float(value) for value in draws]
    return scores


def untrained_copy(net: "th.nn.Module", seed: int = 0) -> "th.nn.Module":
    """
    A constraint net of the same shape and input normalisation as ``net``, initialised afresh (seeded) as a new net of
    its class starts (``reinitialise``: a :class:`~sb3_icrl.constraints.CostNet` at cost 0 everywhere; other modules:
    every linear layer drawn again): the baseline a learned constraint's identification scores are read against (on
    a HalfCheetah probe set an untrained net can rank the pairs far above 0.5, from the input scaling alone).

    :param net: The learned constraint net
    :param seed: Seed of the initial weights
    :return: The untrained copy (``net`` is left as it is)
    """
    copy = deepcopy(net)
    with th.random.fork_rng():
        th.manual_seed(seed)
        if isinstance(copy, _ConstraintNet):
            copy.reinitialise()
        else:
            reset_linear_layers(copy)
    return copy


#: Where a log root keeps the final policies of unconstrained PPO runs brought from a report rather than trained there
#: (``<root>/<suite>/<variant>/probe_policies/ppo/<EnvName>_<N>``): the identification reads them as it reads the runs
PROBE_POLICIES_FOLDER = "probe_policies"


def find_unconstrained_run(run_folder: str | os.PathLike) -> pathlib.Path | None:
    """
    A finished unconstrained PPO run on the same env, near an ICRL run, the run's own seed first (a suite's ``ppo``
    row of that seed, so that a run's probes do not depend on which other seeds have finished): ``<folder>/ppo/
    <EnvName>_<N>`` beside it, else that row's policy kept from a report (``<folder>/probe_policies/ppo/<EnvName>_<N>``,
    :data:`PROBE_POLICIES_FOLDER`), else another seed's, else an ``experts`` suite run
    (``<root>/experts/<variant>/ppo/<EnvName>_*``) when the run belongs to a suite.

    :param run_folder: The ICRL run folder ``<folder>/<algo>/<EnvName>_<N>``
    :return: The run folder, or ``None`` when there is none
    """
    run = pathlib.Path(run_folder).resolve()
    name = run.name.rpartition("_")[0]
    suite_folder = run.parent.parent / "ppo"
    candidates = [suite_folder / run.name, run.parent.parent / PROBE_POLICIES_FOLDER / "ppo" / run.name]
    candidates += [path for path in sorted(suite_folder.glob(f"{name}_*")) if path != candidates[0]]
    if len(run.parents) > 4:
        for folder in sorted((run.parents[3] / "experts").glob("*/ppo")):
            same_seed = folder / run.name
            candidates += [same_seed, *(path for path in sorted(folder.glob(f"{name}_*")) if path != same_seed)]
    return next((candidate for candidate in candidates if candidate.is_dir() and is_finished(str(candidate))), None)


def read_icrl_run(run_folder: str | os.PathLike) -> tuple[pathlib.Path, dict[str, Any]]:
    """
    The folder and saved arguments of an ICRL run, checked.

    :param run_folder: A run folder (``logs/<algo>/<EnvName>_<N>``)
    :return: The folder and its ``args.yml``
    :raises FileNotFoundError: When it is not a run folder
    :raises ValueError: When the run is not an ICRL run
    """
    run = pathlib.Path(run_folder)
    _, args = load_run_args(run)  # (names a missing folder)
    import_gym_packages(args.get("gym_packages"))  # a user's method registers itself on import
    if args.get("algo") not in ICRL_ALGOS:
        raise ValueError(f"{run} is a {args.get('algo')} run: only ICRL runs ({', '.join(ICRL_ALGOS)}) learn a constraint.")
    return run, args


def run_model_path(run: pathlib.Path, args: dict[str, Any], which: str = "final") -> pathlib.Path:
    """
    :param run: A run folder
    :param args: Its saved arguments (``args.yml``)
    :param which: ``"final"``, ``"best"`` or a path
    :return: The file of that model
    """
    candidates = {"final": run / f"{env_name(resolve_env_id(args['env']))}.zip", "best": run / "best_model.zip"}
    return candidates.get(which, pathlib.Path(which))


def _load_run_policy(run: pathlib.Path, which: str = "final") -> tuple[Any, dict[str, Any], str | None]:
    """The model saved in a run folder, its arguments and its VecNormalize statistics."""
    _, args = load_run_args(run)
    import_gym_packages(args.get("gym_packages"))
    name = env_name(resolve_env_id(args["env"]))
    path = run_model_path(run, args, which)
    if not path.is_file():
        raise FileNotFoundError(f"No model {path} (saved models there: {sorted(p.name for p in run.glob('*.zip'))}).")
    model = ALGOS[args["algo"]].load(str(path), device="cpu")
    return model, args, find_vecnormalize(str(path), name)


def run_demonstration_pairs(args: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """
    :param args: A run's saved arguments (``args.yml``)
    :return: The ``(observations, actions)`` pairs of the demonstrations the run learned from
    """
    env_id = resolve_env_id(args["env"])
    demonstrations = load_demonstrations(
        args.get("demonstrations") or env_id.split("/")[-1], violating_fraction=args.get("violating_fraction")
    )
    transitions = demonstrations.transitions
    return np.asarray(transitions.obs), np.asarray(transitions.acts)


@dataclass
class RunProbes:
    """
    What a finished ICRL run's constraint is scored on (:func:`run_probes`).

    :param learner: The run's model (its learned constraint)
    :param env_id: The env it was learned on
    :param env_kwargs: The env's keyword arguments
    :param expert: The run's demonstrations, ``(observations, actions)``
    :param other: More probe pairs: ``"learner"`` (and ``"unconstrained"``) episodes; none on grid worlds
    :param args: The run's saved arguments (``args.yml``)
    """

    learner: Any
    env_id: str
    env_kwargs: dict[str, Any]
    expert: tuple[np.ndarray, np.ndarray]
    other: dict[str, tuple[np.ndarray, np.ndarray]]
    args: dict[str, Any]


def run_probes(
    run_folder: str | os.PathLike,
    model: str = "final",
    n_episodes: int = 3,
    unconstrained_run: str | os.PathLike | None = None,
    seed: int = 0,
) -> RunProbes:
    """
    The model of a finished ICRL run and its probe pairs: its demonstrations, ``n_episodes`` of the learner's own
    deterministic episodes and, given an unconstrained PPO run, as many of that agent's (grid worlds: none of these).

    :param run_folder: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :param model: ``"final"``, ``"best"`` or a path to a model zip
    :param n_episodes: Episodes of the learner (and of the unconstrained agent)
    :param unconstrained_run: A PPO run folder on the same env, or ``None`` for no such episodes
    :param seed: Seed of the episodes
    :return: The probes (:class:`RunProbes`)
    """
    run, args = read_icrl_run(run_folder)
    learner, _, stats = _load_run_policy(run, model)
    env_id = resolve_env_id(args["env"])
    env_kwargs = dict(args.get("env_kwargs") or {})
    noise, noise_model = recorded_transition_noise(args)
    expert = run_demonstration_pairs(args)
    other: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if not getattr(learner.constraint_net, "discrete_obs", False):
        other["learner"] = policy_pairs(
            learner, env_id, env_kwargs, n_episodes, seed, stats, noise, transition_noise_model=noise_model
        )
        if unconstrained_run is not None:
            agent, agent_args, agent_stats = _load_run_policy(pathlib.Path(unconstrained_run))
            agent_noise, agent_noise_model = recorded_transition_noise(agent_args)
            other["unconstrained"] = policy_pairs(
                agent, env_id, env_kwargs, n_episodes, seed, agent_stats, agent_noise, transition_noise_model=agent_noise_model
            )
    return RunProbes(learner, env_id, env_kwargs, expert, other, args)


def identification_cached(run_folder: str | os.PathLike, model: str = "final") -> bool:
    """
    Whether a run has identification scores cached by this version of the scores (what progress lines say before
    :func:`identify_run` scores a run; it checks the other settings and the model's age itself).

    :param run_folder: The run folder
    :param model: ``"final"`` or ``"best"``
    :return: Whether ``identification.json`` (``identification_best.json``) is there, reads, and has this version
    """
    try:
        with open(pathlib.Path(run_folder) / identification_file(model)) as file:
            saved = json.load(file)
    except (OSError, ValueError):
        return False
    return isinstance(saved, dict) and (saved.get("settings") or {}).get("version") == IDENTIFICATION_VERSION


def identify_run(
    run_folder: str | os.PathLike,
    model: str = "final",
    n_episodes: int = 3,
    unconstrained_run: str | os.PathLike | None = None,
    seed: int = 0,
    use_cache: bool = True,
    save: bool = True,
) -> dict[str, Any]:
    """
    Identification scores of a finished ICRL run's learned constraint, cached in ``<run>/identification.json``
    (another file for the best model or a given zip: :func:`identification_file`).

    The probe set: the run's demonstrations, ``n_episodes`` of the learner's own episodes, ``n_episodes`` of an
    unconstrained PPO run's (``unconstrained_run``, or :func:`find_unconstrained_run`) and the sweep; the budget is
    the learner's as the run ended. Grid worlds: the cell map.

    :param run_folder: The run folder ``<folder>/<algo>/<EnvName>_<N>``
    :param model: ``"final"``, ``"best"`` or a path to a model zip
    :param n_episodes: Episodes of the learner (and of the unconstrained agent)
    :param unconstrained_run: A PPO run folder on the same env (default: one found near the run, if any)
    :param seed: Seed of the episodes and draws
    :param use_cache: Return the cached result when its settings match and it is newer than the run's models and the
        unconstrained run's
    :param save: Write the result to the cache
    :return: ``{"settings": ..., "scores": ...}`` (scores: see :func:`identification_scores`)
    """
    run, args = read_icrl_run(run_folder)
    unconstrained = pathlib.Path(unconstrained_run) if unconstrained_run is not None else find_unconstrained_run(run)
    settings = {
        "version": IDENTIFICATION_VERSION,
        "model": model,
        "n_episodes": n_episodes,
        "seed": seed,
        "unconstrained_run": None if unconstrained is None else os.path.relpath(unconstrained.resolve(), run.resolve()),
    }
    cache = run / identification_file(model)
    if use_cache and cache.is_file():
        with open(cache) as file:
            saved = json.load(file)
        models = [*run.glob("*.zip"), *(unconstrained.glob("*.zip") if unconstrained is not None else [])]
        # (the probe agent's models too: a PPO row trained again in the same folder gives other episodes)
        newest_model = max((path.stat().st_mtime for path in models), default=0.0)
        if saved.get("settings") == settings and cache.stat().st_mtime >= newest_model:
            return saved

    probes = run_probes(run, model, n_episodes, unconstrained, seed)
    scores = identify_model(probes.learner, probes.env_id, probes.expert, probes.env_kwargs, probes.other, seed=seed)
    result = {"settings": settings, "run": str(run), "algo": args["algo"], "env": probes.env_id, "scores": scores}
    if save:
        atomic_write_json(cache, result, indent=2)
    return result


def headline(scores: Mapping[str, Any]) -> dict[str, float | str]:
    """
    The identification numbers a table shows: AUROC, and the threshold error at ``t = 0.5`` of the first constrained
    feature with how the learned cost meets that level (left out on grid worlds, whose constraint has no threshold).

    :param scores: Scores of :func:`identification_scores` or :func:`grid_identification`
    :return: ``{"identification_auroc": ..., "threshold_error": ..., "threshold_crossing": ...}`` (and
        ``untrained_auroc``, the median of untrained nets' of the same shape on the same probes, where scored, with
        ``untrained_auroc_low`` and ``untrained_auroc_high``, their range), the crossing
        (:func:`crossing_kind`) ``"crosses"`` (a finite error), ``"everywhere"``, ``"reversed"`` or ``"both ends"``
        (the cost at or above 0.5 at the safe end of the range: an infinite error; ``"safe end"`` where the scores
        keep no curve to tell which) or ``"nowhere"`` (it never reaches 0.5: NaN). Strict JSON writes both non-finite
        errors as ``null``; the crossing keeps them apart. Where the probe set has them, also ``learner_cost`` (the
        mean learned cost per step on the learner's own pairs) and ``cost_budget`` (the learner's budget as the run
        ended): a learner far over its budget wherever it goes tends to end its episodes early.
    """
    row: dict[str, float | str] = {"identification_auroc": float(scores["auroc"])}
    if "untrained_auroc" in scores:
        row["untrained_auroc"] = float(scores["untrained_auroc"])
    if "untrained_auroc_range" in scores:
        row["untrained_auroc_low"], row["untrained_auroc_high"] = (float(value) for value in scores["untrained_auroc_range"])
    learner = scores.get("sources", {}).get("learner")
    if learner is not None:
        row["learner_cost"] = float(learner["mean_cost"])
    if "budget" in scores.get("levels", {}):
        row["cost_budget"] = float(scores["levels"]["budget"])
    features = list(scores.get("features", {}).values())
    if features:  # grid worlds have no threshold: no column rather than a NaN
        error = float(features[0][_level_key("0.5")]["threshold_error"])
        row["threshold_error"] = error
        row["threshold_crossing"] = headline_crossing(scores["features"]) or (
            "safe end" if math.isinf(error) else "nowhere" if math.isnan(error) else "crosses"
        )
    return row


def headline_crossing(features: Mapping[str, Any], level: float = 0.5) -> str | None:
    """
    How the learned cost over the first constrained feature meets ``level`` (:func:`crossing_kind`), from the curve
    that identification scores (and a report's figure data) keep under ``features``.

    :param features: ``{feature: {"curve": {"values": ..., "mean_cost": ...}, "op": ...}}``
    :param level: The level ``t``
    :return: The crossing, or ``None`` where there is no curve to read (or one with a value that is not finite)
    """
    if not features:
        return None
    entry = next(iter(features.values()))
    curve, op = entry.get("curve"), entry.get("op")
    if not curve or op is None:
        return None
    # (dtype float: a curve read back from strict JSON has None where a value was not finite)
    values, costs = np.asarray(curve["values"], dtype=float), np.asarray(curve["mean_cost"], dtype=float)
    if values.size < 2 or not (np.isfinite(values).all() and np.isfinite(costs).all()):
        return None
    return crossing_kind(values, costs, level, op)


def methods_figure(
    run_folders: Sequence[str | os.PathLike],
    feature: str | None = None,
    level: float | None = 0.5,
    title: str | None = None,
    n_episodes: int = 3,
    model: str = "final",
) -> Any:
    """
    Per method, the learned cost over the constrained feature of one env (one line per seed, their mean), the true
    threshold marked: :func:`~sb3_icrl.plots.figures.methods_partial_dependence_figure` of the partial dependence
    curves of :func:`identify_run` (computed once, then read from each run's cache).

    :param run_folders: ICRL run folders, all on one env
    :param feature: The constrained feature to plot (its name) when the env has several (default: the first)
    :param level: A level ``t`` drawn as a dotted line
    :param title: Figure title (default: the env)
    :param n_episodes: Learner episodes of the probe set, for runs not scored yet
    :param model: ``"final"`` or ``"best"``: whose learned constraint
    :return: The figure
    """
    if not run_folders:
        raise ValueError("No run folder given: pass the ICRL runs to compare.")
    results = [identify_run(folder, model=model, n_episodes=n_episodes) for folder in run_folders]
    return learned_cost_figure([learned_cost_curves(result) for result in results], feature, level, title)


def learned_cost_curves(result: Mapping[str, Any]) -> dict[str, Any]:
    """
    What :func:`learned_cost_figure` draws of one run: its env, algorithm and, per constrained feature, the true
    threshold and the learned cost's partial dependence curve (a few KB, kept in a report so that its figure can be
    drawn again once the run folder is gone).

    :param result: A result of :func:`identify_run`
    :return: ``{"run", "env", "algo", "features": {name: {"threshold", "op", "curve": {"values", "mean_cost"}}}}``
    """
    features = result["scores"].get("features", {})
    return {
        "run": str(result.get("run", "")),
        "env": result["env"],
        "algo": result["algo"],
        "features": {
            name: {
                "threshold": entry["threshold"],
                "op": entry["op"],
                "curve": {"values": list(entry["curve"]["values"]), "mean_cost": list(entry["curve"]["mean_cost"])},
            }
            for name, entry in features.items()
        },
    }


def learned_cost_figure(
    runs: Sequence[Mapping[str, Any]], feature: str | None = None, level: float | None = 0.5, title: str | None = None
) -> Any:
    """
    :func:`methods_figure` from each run's :func:`learned_cost_curves`.

    :param runs: The runs' curves, all on one env
    :param feature: The constrained feature to plot (default: the first)
    :param level: A level ``t`` drawn as a dotted line
    :param title: Figure title (default: the env)
    :return: The figure
    :raises ValueError: With no run, runs on several envs, or an env whose constraint is no threshold on a feature
    """
    if not runs:
        raise ValueError("No run given: pass the ICRL runs to compare.")
    curves: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    envs: set[str] = set()
    chosen, threshold, op = feature, float("nan"), "<="
    for run in runs:
        envs.add(run["env"])
        features = run["features"]
        if not features:
            raise ValueError(f"{run['run']}: the env's constraint is not a threshold on a feature (a grid world?): no curve.")
        chosen = chosen or next(iter(features))
        if chosen not in features:
            raise ValueError(f"Unknown feature {chosen!r} for {run['run']}: its env constrains {', '.join(features)}.")
        entry = features[chosen]
        threshold, op = entry["threshold"], entry["op"]
        # (dtype float: a curve read back from strict JSON has None where a value was not finite)
        curve = (np.asarray(entry["curve"]["values"], dtype=float), np.asarray(entry["curve"]["mean_cost"], dtype=float))
        curves.setdefault(str(run["algo"]).upper(), []).append(curve)
    if len(envs) > 1:
        raise ValueError(f"The runs trained on different envs ({sorted(envs)}): plot one env at a time.")
    env = envs.pop().split("/")[-1]
    return methods_partial_dependence_figure(curves, threshold, op, str(chosen), level=level, title=title or env)
