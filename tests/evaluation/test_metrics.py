"""Metrics against independent references: scipy Rotation ('ZXY' intrinsic = Rz Rx Ry, paper
Eq. 1), closed-form wraps, scipy.stats for rank correlation and t intervals."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import torch
from scipy import stats
from scipy.spatial.transform import Rotation

from benchmark.evaluation.metrics import (
    ERROR_COLUMNS,
    pose_errors,
    predictions_frame,
    relative_to_uav_attitude,
    seed_interval,
    spearman,
    summarize,
    write_predictions_csv,
)

DEG = math.pi / 180
# Satellite camera, built independently of benchmark.geometry: pitch -90 deg, heading 0 (Eq. 5).
SAT = Rotation.from_euler("ZXY", [0.0, -90.0, 0.0], degrees=True).as_matrix()


def uav_rotations(yaw_pitch_roll_deg: np.ndarray) -> np.ndarray:
    """(N, 3) degrees (yaw, pitch, roll) -> (N, 3, 3) R_uav^n = Rz(yaw) Rx(pitch) Ry(roll)."""
    return Rotation.from_euler("ZXY", yaw_pitch_roll_deg, degrees=True).as_matrix()


def relative(R_uav: np.ndarray) -> torch.Tensor:
    """R_uav^sat = R_uav^n (R_sat^n)^T (Eq. 2)."""
    return torch.from_numpy(R_uav @ SAT.T)


def random_attitudes(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack(
        [rng.uniform(-180, 180, n), rng.uniform(-50, 0, n), rng.uniform(-10, 10, n)], axis=1
    )


def zeros_T(n: int) -> torch.Tensor:
    return torch.zeros(n, 3, dtype=torch.float64)


class TestRelativeToUavAttitude:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_inverse_of_eq2(self, batch):
        R_uav = uav_rotations(random_attitudes(batch, batch))
        got = relative_to_uav_attitude(relative(R_uav))
        np.testing.assert_allclose(got.numpy(), R_uav, atol=1e-12)

    def test_float32(self):
        R_uav = uav_rotations(random_attitudes(3, 0))
        got = relative_to_uav_attitude(relative(R_uav).float())
        assert got.dtype == torch.float32
        np.testing.assert_allclose(got.numpy(), R_uav, atol=1e-6)


class TestPoseErrors:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_euler_errors_are_uav_pitch_roll_yaw(self, batch):
        # Perturb each UAV angle by a known amount; the errors must come back per angle.
        gt = random_attitudes(batch, 10 + batch)
        delta = np.tile([3.0, -2.0, 1.5], (batch, 1))  # yaw, pitch, roll offsets, degrees
        err = pose_errors(
            relative(uav_rotations(gt + delta)),
            relative(uav_rotations(gt)),
            zeros_T(batch),
            zeros_T(batch),
        )
        np.testing.assert_allclose(err.d_yaw.numpy() / DEG, 3.0, atol=1e-9)
        np.testing.assert_allclose(err.d_pitch.numpy() / DEG, -2.0, atol=1e-9)
        np.testing.assert_allclose(err.d_roll.numpy() / DEG, 1.5, atol=1e-9)

    def test_euler_matches_scipy_decomposition(self):
        gt = random_attitudes(8, 1)
        pred = random_attitudes(8, 2)
        err = pose_errors(
            relative(uav_rotations(pred)), relative(uav_rotations(gt)), zeros_T(8), zeros_T(8)
        )
        # scipy's intrinsic ZXY decomposition of the UAV attitudes; wraps in closed form.
        ref_p = Rotation.from_matrix(uav_rotations(pred)).as_euler("ZXY", degrees=True)
        ref_g = Rotation.from_matrix(uav_rotations(gt)).as_euler("ZXY", degrees=True)
        wrapped = (ref_p - ref_g + 180.0) % 360.0 - 180.0
        got = np.stack([err.d_yaw, err.d_pitch, err.d_roll], axis=1) / DEG
        np.testing.assert_allclose(got, wrapped, atol=1e-8)

    def test_convention_wrap_to_180(self):
        gt = np.array([[179.0, -20.0, 0.0], [-170.0, -10.0, 9.0]])
        pred = np.array([[-179.0, -20.0, 0.0], [175.0, -10.0, -9.0]])
        err = pose_errors(
            relative(uav_rotations(pred)), relative(uav_rotations(gt)), zeros_T(2), zeros_T(2)
        )
        np.testing.assert_allclose(err.d_yaw.numpy() / DEG, [2.0, -15.0], atol=1e-9)
        np.testing.assert_allclose(err.d_yaw_nowrap.numpy() / DEG, [-358.0, 345.0], atol=1e-9)
        np.testing.assert_allclose(err.d_roll.numpy() / DEG, [0.0, -18.0], atol=1e-9)

    def test_geodesic_matches_scipy(self):
        R_p, R_g = uav_rotations(random_attitudes(8, 3)), uav_rotations(random_attitudes(8, 4))
        err = pose_errors(relative(R_p), relative(R_g), zeros_T(8), zeros_T(8))
        ref = (Rotation.from_matrix(R_p) * Rotation.from_matrix(R_g).inv()).magnitude()
        np.testing.assert_allclose(err.geodesic.numpy(), ref, atol=1e-9)

    def test_translation_errors(self):
        T_gt = torch.tensor([[10.0, -5.0, 100.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
        T_hat = torch.tensor([[12.0, -9.0, 99.5], [-1.0, 2.0, 3.0]], dtype=torch.float64)
        R = relative(uav_rotations(random_attitudes(2, 5)))
        err = pose_errors(R, R, T_hat, T_gt)
        np.testing.assert_allclose(err.d_translation.numpy(), [[2.0, -4.0, -0.5], [-1.0, 2.0, 3.0]])
        np.testing.assert_allclose(err.geodesic.numpy(), 0.0, atol=1e-7)

    def test_bad_shapes(self):
        R = relative(uav_rotations(random_attitudes(2, 5)))
        with pytest.raises(ValueError, match=r"T_hat must have shape \(N, 3\)"):
            pose_errors(R, R, torch.zeros(2, 2), torch.zeros(2, 3))
        with pytest.raises(ValueError, match="same N"):
            pose_errors(R, R[:1], zeros_T(2), zeros_T(2))
        with pytest.raises(ValueError, match="non-finite"):
            pose_errors(R * float("nan"), R, zeros_T(2), zeros_T(2))


class TestPredictionsFrame:
    def test_columns_and_units(self, tmp_path):
        gt = np.array([[179.0, -20.0, 5.0], [0.0, -45.0, 0.0], [90.0, 0.0, -5.0]])
        pred = gt + np.array([[2.0, 1.0, 0.0], [0.0, 0.0, 0.0], [-4.0, 0.0, 0.0]])
        T_gt = torch.tensor([[1.0, 2.0, 3.0]] * 3, dtype=torch.float64)
        frame = predictions_frame(
            relative(uav_rotations(pred)),
            relative(uav_rotations(gt)),
            T_gt + torch.tensor([1.0, -1.0, 0.5], dtype=torch.float64),
            T_gt,
            index=[7, 8, 9],
            uncertainty=torch.tensor([0.2, 0.1, 0.3]),
            extra={"city": ["oxford", "oxford", "london"]},
        )
        assert set(ERROR_COLUMNS) <= set(frame.columns)
        np.testing.assert_allclose(frame["dpsi_deg"], [2.0, 0.0, 4.0], atol=1e-8)
        np.testing.assert_allclose(frame["dpsi_nowrap_deg"], [358.0, 0.0, 4.0], atol=1e-8)
        np.testing.assert_allclose(frame["dtheta_deg"], [1.0, 0.0, 0.0], atol=1e-8)
        np.testing.assert_allclose(frame["yaw_deg"], [179.0, 0.0, 90.0], atol=1e-8)
        np.testing.assert_allclose(frame["dE_m"], 1.0)
        np.testing.assert_allclose(frame["dU_m"], 0.5)
        assert list(frame["index"]) == [7, 8, 9] and list(frame["city"])[2] == "london"
        path = write_predictions_csv(frame, tmp_path / "p" / "pred.csv")
        back = pd.read_csv(path)
        np.testing.assert_allclose(back["dphi_deg"], frame["dphi_deg"], rtol=1e-9, atol=1e-9)
        R_back = (
            back[[f"Rhat{i}{j}" for i in range(3) for j in range(3)]].to_numpy().reshape(3, 3, 3)
        )
        np.testing.assert_allclose(R_back, relative(uav_rotations(pred)).numpy(), atol=1e-9)
        # Deterministic bytes.
        assert (
            write_predictions_csv(frame, tmp_path / "again.csv").read_bytes() == path.read_bytes()
        )


class TestSummarize:
    def make_frame(self, dphi: list[float], **cols) -> pd.DataFrame:
        data = {c: np.zeros(len(dphi)) for c in ERROR_COLUMNS}
        data["dphi_deg"] = np.asarray(dphi, dtype=float)
        data.update(cols)
        return pd.DataFrame(data)

    def test_means_medians_accuracy(self):
        frame = self.make_frame([1.0, 4.0, 5.0, 9.0, 20.0, 40.0], dE_m=np.arange(6.0))
        s = summarize(frame)
        assert s["n"] == 6
        assert s["dphi_deg"] == pytest.approx(79.0 / 6)
        assert s["median_dphi_deg"] == pytest.approx(7.0)
        assert s["dE_m"] == pytest.approx(2.5)
        # <= threshold counts: 5 deg -> {1, 4, 5}; 10 -> +9; 30 -> +20.
        assert (s["acc5"], s["acc10"], s["acc30"]) == (3 / 6, 4 / 6, 5 / 6)
        assert "loglik" not in s and "spearman_unc_err" not in s

    def test_probabilistic_columns(self):
        dphi = [1.0, 3.0, 2.0, 10.0, 7.0]
        unc = [0.1, 0.5, 0.2, 0.4, 0.3]
        s = summarize(
            self.make_frame(dphi, uncertainty=unc, log_likelihood=[1.0, 2.0, 3.0, 4.0, 5.0])
        )
        assert s["loglik"] == pytest.approx(3.0)
        # Closed form without ties: rho = 1 - 6 sum d^2 / (n (n^2 - 1)).
        rank_u, rank_e = stats.rankdata(unc), stats.rankdata(dphi)
        rho = 1 - 6 * np.sum((rank_u - rank_e) ** 2) / (5 * (25 - 1))
        assert s["spearman_unc_err"] == pytest.approx(rho)
        assert 0 <= s["spearman_unc_err_pvalue"] <= 1

    def test_empty(self):
        with pytest.raises(ValueError, match="empty"):
            summarize(self.make_frame([]))

    def test_horizontal_error_is_the_distance_on_the_ground(self):
        # Pythagorean triples: horizontal errors 5, 13, 25, 0 m (the vertical error is ignored).
        frame = self.make_frame(
            [1.0] * 4, dE_m=[3.0, 5.0, 7.0, 0.0], dN_m=[4.0, 12.0, 24.0, 0.0], dU_m=[9.0] * 4
        )
        s = summarize(frame)
        assert s["horizontal_m"] == pytest.approx(43.0 / 4)
        assert s["median_horizontal_m"] == pytest.approx(9.0)  # between 5 and 13


class TestSpearman:
    def test_monotone(self):
        x = np.arange(10.0)
        assert spearman(x, x**3)[0] == pytest.approx(1.0)
        assert spearman(x, -np.exp(x))[0] == pytest.approx(-1.0)

    def test_undefined_is_nan(self):
        assert math.isnan(spearman(np.ones(5), np.arange(5.0))[0])
        assert math.isnan(spearman(np.arange(2.0), np.arange(2.0))[0])


class TestSeedInterval:
    def test_matches_scipy_t_interval(self):
        x = np.array([1.2, 1.5, 0.9, 1.4])
        got = seed_interval(x)
        lo, hi = stats.t.interval(0.95, df=3, loc=x.mean(), scale=stats.sem(x))
        assert (got.mean, got.low, got.high, got.n) == pytest.approx((x.mean(), lo, hi, 4))

    def test_two_seeds_closed_form(self):
        got = seed_interval([1.0, 3.0])
        # t_{0.975, 1} = 12.7062..., s = sqrt(2), s / sqrt(2) = 1.
        assert got.half_width == pytest.approx(12.706204736, rel=1e-8)
        assert got.mean == 2.0

    def test_one_seed(self):
        got = seed_interval([4.2])
        assert got.mean == 4.2 and math.isnan(got.low) and math.isnan(got.high) and got.n == 1

    def test_errors(self):
        with pytest.raises(ValueError, match="at least one"):
            seed_interval([])
        with pytest.raises(ValueError, match="confidence"):
            seed_interval([1.0, 2.0], confidence=95)


class TestMeanRotation:
    def test_symmetric_spread_gives_centre(self):
        from benchmark.evaluation.constant import mean_rotation

        centre = Rotation.from_euler("ZXY", [40.0, 60.0, 5.0], degrees=True)
        offsets = Rotation.from_rotvec(
            np.array([[0.3, 0, 0], [-0.3, 0, 0], [0, 0.2, 0], [0, -0.2, 0]])
        )
        R = torch.from_numpy((centre * offsets).as_matrix())
        np.testing.assert_allclose(mean_rotation(R).numpy(), centre.as_matrix(), atol=1e-12)

    def test_is_chordal_minimiser(self):
        from benchmark.evaluation.constant import mean_rotation

        R = torch.from_numpy(Rotation.random(20, random_state=3).as_matrix())
        M = mean_rotation(R)
        cost = lambda X: float(((R - X) ** 2).sum())  # noqa: E731
        perturbed = Rotation.from_rotvec(np.random.default_rng(0).normal(0, 0.05, (50, 3)))
        for P in perturbed.as_matrix():
            assert cost(M) <= cost(torch.from_numpy(P) @ M) + 1e-12
        assert torch.det(M) == pytest.approx(1.0)


class TestConstantPredictor:
    def test_against_closed_form(self):
        from benchmark.evaluation.constant import constant_predictor

        class Labels(torch.utils.data.Dataset):
            def __init__(self, R, T):
                self.R, self.T = R, T

            def __len__(self):
                return len(self.R)

            def __getitem__(self, i):
                return {"R": self.R[i], "T": self.T[i], "index": torch.tensor(i)}

        # Training labels: UAV yaw +-10 deg around 0 -> mean attitude yaw 0 (pitch -20, roll 0).
        train_R = relative(uav_rotations(np.array([[10.0, -20.0, 0.0], [-10.0, -20.0, 0.0]])))
        train_T = torch.tensor([[0.0, 0.0, 100.0], [10.0, 0.0, 100.0]], dtype=torch.float64)
        test_R = relative(uav_rotations(np.array([[30.0, -20.0, 0.0], [-90.0, -20.0, 0.0]])))
        test_T = torch.tensor([[5.0, 1.0, 90.0], [0.0, 0.0, 100.0]], dtype=torch.float64)
        summary, frame = constant_predictor(Labels(train_R, train_T), Labels(test_R, test_T))
        np.testing.assert_allclose(frame["dpsi_deg"], [30.0, 90.0], atol=1e-9)
        np.testing.assert_allclose(frame["dtheta_deg"], [0.0, 0.0], atol=1e-9)
        assert summary["dE_m"] == pytest.approx(2.5) and summary["dU_m"] == pytest.approx(5.0)
        assert summary["dN_m"] == pytest.approx(0.5)
