"""The constant predictor: the floor every trained model must clear.

It ignores the images and always answers the training set's mean pose: the chordal L2 mean
rotation ``argmin_R sum_i ||R - R_i||_F^2 = proj_SO(3)(mean_i R_i)`` (the SVD projection of the
element-wise mean; unique unless the mean is rank-deficient) and the mean translation. A model
that does not beat it by a wide margin has learned nothing from the images (issue 5, quick
profile).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch
from torch.utils.data import Dataset, Subset

from benchmark.evaluation.metrics import predictions_frame, summarize
from benchmark.geometry import special_orthogonalize

_R_COLUMNS = [f"R{i}{j}" for i in range(3) for j in range(3)]  # row-major, as PairDataset's poses


def dataset_labels(dataset: Dataset) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(R (N, 3, 3), T (N, 3), index (N,))`` float64 labels of ``dataset`` in item order.

    Read from ``PairDataset.poses`` (or a ``Subset`` of one) without decoding images; any other
    dataset is iterated.
    """
    base, idx = dataset, None
    if isinstance(dataset, Subset):
        base, idx = dataset.dataset, list(dataset.indices)
    poses = getattr(base, "poses", None)
    if isinstance(poses, pd.DataFrame) and {*_R_COLUMNS, "dE", "dN", "dU"} <= set(poses):
        rows = np.arange(len(poses)) if idx is None else np.asarray(idx, dtype=np.int64)
        R = torch.from_numpy(poses[_R_COLUMNS].to_numpy(np.float64)[rows].reshape(-1, 3, 3))
        T = torch.from_numpy(poses[["dE", "dN", "dU"]].to_numpy(np.float64)[rows])
        return R, T, torch.from_numpy(rows)
    items = [dataset[i] for i in range(len(dataset))]
    R = torch.stack([torch.as_tensor(it["R"], dtype=torch.float64) for it in items])
    T = torch.stack([torch.as_tensor(it["T"], dtype=torch.float64) for it in items])
    index = torch.stack([torch.as_tensor(it["index"]) for it in items])
    return R, T, index


def mean_rotation(R: torch.Tensor) -> torch.Tensor:
    """Chordal L2 mean of rotations ``(N, 3, 3) -> (3, 3)``."""
    if R.dim() != 3 or R.shape[1:] != (3, 3) or R.shape[0] == 0:
        raise ValueError(f"R must have shape (N >= 1, 3, 3), got {tuple(R.shape)}")
    return special_orthogonalize(R.double().mean(0))


def constant_predictor(
    train_set: Dataset, eval_set: Dataset
) -> tuple[dict[str, float], pd.DataFrame]:
    """Summary and per-sample table of always predicting the mean pose of ``train_set`` on
    ``eval_set`` (same columns and metrics as :func:`benchmark.evaluation.evaluate.evaluate`)."""
    R_train, T_train, _ = dataset_labels(train_set)
    R_gt, T_gt, index = dataset_labels(eval_set)
    n = R_gt.shape[0]
    R_hat = mean_rotation(R_train).expand(n, 3, 3)
    T_hat = T_train.mean(0).expand(n, 3)
    frame = predictions_frame(R_hat, R_gt, T_hat, T_gt, index=index)
    return summarize(frame), frame
