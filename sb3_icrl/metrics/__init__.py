"""
Metrics of learned constraints beyond the violation rate: whether a learned constraint identifies the true one
(:mod:`sb3_icrl.metrics.identification`: AUROC, precision, recall and IoU, threshold error, calibration error on a
probe set built for evaluation only), and whether it transfers to new tasks (:mod:`sb3_icrl.metrics.transfer`,
``sb3-icrl transfer``).
"""

from sb3_icrl.metrics.identification import (
    IDENTIFICATION_BEST_FILE,
    IDENTIFICATION_FILE,
    ProbeSet,
    ThresholdCrossing,
    auroc,
    build_probe_set,
    crossing_kind,
    expected_calibration_error,
    grid_identification,
    identification_scores,
    identify_model,
    identify_run,
    learned_threshold,
    overlap_scores,
    partial_dependence_curve,
    threshold_error,
    true_cost_labels,
)
from sb3_icrl.metrics.transfer import DYNAMICS_NOISE, TASKS, read_transfers, run_transfer, transfer_env

__all__ = [
    "DYNAMICS_NOISE",
    "IDENTIFICATION_BEST_FILE",
    "IDENTIFICATION_FILE",
    "TASKS",
    "ProbeSet",
    "ThresholdCrossing",
    "auroc",
    "build_probe_set",
    "crossing_kind",
    "expected_calibration_error",
    "grid_identification",
    "identification_scores",
    "identify_model",
    "identify_run",
    "learned_threshold",
    "overlap_scores",
    "partial_dependence_curve",
    "read_transfers",
    "run_transfer",
    "threshold_error",
    "transfer_env",
    "true_cost_labels",
]
