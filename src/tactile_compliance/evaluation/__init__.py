"""Evaluation: metrics (overall, per material / shape / soft-hard) and reference predictors."""

from tactile_compliance.evaluation.metrics import (
    METRIC_NAMES,
    compute_metrics,
    grouped_metrics,
    log10_accuracy,
    mae_decades,
    nmse,
    r2,
    reference_predictions,
    soft_hard_labels,
    within_half_decade,
)

__all__ = [
    "METRIC_NAMES",
    "compute_metrics",
    "grouped_metrics",
    "log10_accuracy",
    "mae_decades",
    "nmse",
    "r2",
    "reference_predictions",
    "soft_hard_labels",
    "within_half_decade",
]
