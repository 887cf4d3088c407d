"""Evaluation: the paper's metrics (``metrics``) and running a model over a split (``evaluate``)."""

from benchmark.evaluation.metrics import (
    ACCURACY_THRESHOLDS_DEG,
    ERROR_COLUMNS,
    PoseErrors,
    SeedInterval,
    pose_errors,
    predictions_frame,
    relative_to_uav_attitude,
    seed_interval,
    spearman,
    summarize,
    write_predictions_csv,
)
from benchmark.evaluation.reference import constant_predictor, dataset_labels, mean_rotation

__all__ = [
    "ACCURACY_THRESHOLDS_DEG",
    "ERROR_COLUMNS",
    "PoseErrors",
    "SeedInterval",
    "constant_predictor",
    "dataset_labels",
    "mean_rotation",
    "pose_errors",
    "predictions_frame",
    "relative_to_uav_attitude",
    "seed_interval",
    "spearman",
    "summarize",
    "write_predictions_csv",
]
