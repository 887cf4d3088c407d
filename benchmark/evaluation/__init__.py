"""Evaluation: the paper's metrics (``metrics``), running a model over a split (``evaluate``) and
the constant predictor, the floor every model must clear (``constant``)."""

from benchmark.evaluation.beliefs import (
    AttitudeCalibration,
    PositionCalibration,
    calibrate_from_predictions,
    gives_density,
    position_beliefs,
    yaw_beliefs,
)
from benchmark.evaluation.constant import constant_predictor, dataset_labels, mean_rotation
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

__all__ = [
    "ACCURACY_THRESHOLDS_DEG",
    "ERROR_COLUMNS",
    "AttitudeCalibration",
    "PoseErrors",
    "PositionCalibration",
    "SeedInterval",
    "calibrate_from_predictions",
    "constant_predictor",
    "dataset_labels",
    "gives_density",
    "mean_rotation",
    "pose_errors",
    "position_beliefs",
    "predictions_frame",
    "relative_to_uav_attitude",
    "seed_interval",
    "spearman",
    "summarize",
    "write_predictions_csv",
    "yaw_beliefs",
]
