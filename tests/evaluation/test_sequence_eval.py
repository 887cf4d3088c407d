"""fuse_estimates: point estimates without a density of their own (the constant predictor, the
non-learned references) fused along the flights of a rendered split, on the smoke dataset."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from benchmark.data import PairDataset, odometry_noise
from benchmark.evaluation.sequence_eval import fuse_estimates


def estimates(poses: pd.DataFrame, yaw_sd_deg: float, pos_sd_m: float, seed: int) -> pd.DataFrame:
    """A per-frame table around the truth: yaw and position off by Gaussian noise, pitch and
    roll exact; the error columns the calibration reads."""
    rng = np.random.default_rng(seed)
    n = len(poses)
    dyaw = rng.normal(0.0, yaw_sd_deg, n)
    d_en = rng.normal(0.0, pos_sd_m, (n, 2))
    return pd.DataFrame(
        {
            "index": np.arange(n),
            "yaw_hat_deg": np.degrees(poses["yaw"].to_numpy()) + dyaw,
            "pitch_hat_deg": np.degrees(poses["pitch"].to_numpy()),
            "roll_hat_deg": np.degrees(poses["roll"].to_numpy()),
            "E_hat_m": poses["dE"].to_numpy() + d_en[:, 0],
            "N_hat_m": poses["dN"].to_numpy() + d_en[:, 1],
            "dphi_deg": np.abs(dyaw),
            "dE_m": d_en[:, 0],
            "dN_m": d_en[:, 1],
        }
    )


@pytest.mark.slow
class TestFuseEstimates:
    def fuse(self, root, yaw_sd=3.0, val_split="standard/val", **kw):
        data, val = PairDataset(root, "long/standard"), PairDataset(root, "standard/val")
        area = float(np.prod(data.manifest["profile"]["sat_footprint_m"]))
        return fuse_estimates(
            estimates(data.poses, yaw_sd, 20.0, 1), estimates(val.poses, yaw_sd, 20.0, 2),
            data.poses, data.sat_table, odometry_noise(data.manifest["profile"]),
            split="long/standard", val_split=val_split, seed=0, area_m2=area, **kw,
        )  # fmt: skip

    def test_smoothing_noisy_estimates_beats_them(self, smoke_dataset):
        summary, table = self.fuse(smoke_dataset, stress_scale=None)
        assert set(table["mode"]) == {"frame", "filter", "smooth"}
        # 3 deg white noise per frame, odometry far better: averaged along the flight
        assert summary["seq_smooth_dpsi_deg"] < 0.8 * summary["seq_frame_dpsi_deg"]
        assert summary["seq_frame_dpsi_deg"] == pytest.approx(3.0 * np.sqrt(2 / np.pi), rel=0.5)

    def test_the_calibration_must_come_from_a_validation_split(self, smoke_dataset):
        with pytest.raises(ValueError, match="standard/test"):
            self.fuse(smoke_dataset, val_split="standard/test")
