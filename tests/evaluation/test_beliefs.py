"""Per-frame beliefs for every head (issue 39, item 2), against independent references: scipy's
Euler angles for the slice, a per-rotation loop of ``log_prob`` for the densities (fast vs naive),
scipy quadrature, Monte Carlo over Haar-random rotations and the matrix Fisher head's own
tanh-sinh normaliser for ``c(kappa)``, scipy's von Mises for the regression heads' width, and
draws from known mixtures for the fits. Float64 where it matters."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import torch
from scipy import integrate, special, stats
from scipy.spatial.transform import Rotation

from benchmark.evaluation.beliefs import (
    AttitudeCalibration,
    PositionCalibration,
    calibrate_from_predictions,
    calibrated_yaw_beliefs,
    check_validation_split,
    gives_density,
    isotropic_fisher_log_normaliser,
    position_beliefs,
    raw_batch_size,
    take_raw,
    yaw_beliefs,
    yaw_slice,
)
from benchmark.evaluation.fusion_grid import (
    CircularGrid,
    PlanarGrid,
    normalize_log_density,
    von_mises_belief,
)
from benchmark.evaluation.metrics import predictions_frame
from benchmark.geometry import SAT_R_N, euler_to_rotmat, geodesic_distance, rotmat_to_euler
from benchmark.models import AttitudeHead, create_head, get_head_class, list_heads

F64 = torch.float64
DEG = math.pi / 180
ATTITUDE = list_heads("attitude")
DENSITY = [n for n in ATTITUDE if gives_density(get_head_class(n))]
REGRESSION = [n for n in ATTITUDE if not gives_density(get_head_class(n))]
SAT = SAT_R_N.numpy()
FEATURES = 24


def make_head(name: str, dtype: torch.dtype = torch.float32) -> AttitudeHead:
    torch.manual_seed(0)
    return create_head(name, in_features=FEATURES).to(dtype).eval()


def head_output(head: AttitudeHead, batch: int, dtype: torch.dtype, seed: int = 1):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, FEATURES, generator=g, dtype=F64).to(dtype)
    with torch.no_grad():
        raw = head(x)
        return raw, head.decode(raw)


def scipy_slice(R_hat: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """``(B, n, 3, 3)``: scipy's intrinsic ZXY Euler angles (R = Rz Rx Ry) of ``R_hat SAT_R_N``,
    the yaw replaced by each ``psi``, back to ``R_uav^sat``."""
    out = np.empty((len(R_hat), len(psi), 3, 3))
    for b, R in enumerate(R_hat):
        _, pitch, roll = Rotation.from_matrix(R @ SAT).as_euler("ZXY")
        for j, p in enumerate(psi):
            out[b, j] = Rotation.from_euler("ZXY", [p, pitch, roll]).as_matrix() @ SAT.T
    return out


def wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def uav_yaw(R_uav_sat: torch.Tensor) -> torch.Tensor:
    return rotmat_to_euler(R_uav_sat @ SAT_R_N.to(R_uav_sat.dtype))[0]


class ToyYawHead(AttitudeHead):
    """A density on SO(3) of the UAV yaw only, von Mises ``(mu, kappa)`` per frame, with a dict
    raw. Normalised w.r.t. Haar: under Haar the yaw is uniform, so ``exp(k cos(psi - mu)) /
    I0(k)`` integrates to 1. Not registered: the registry-free contract is all it needs."""

    gives_log_prob = True

    def forward(self, features: torch.Tensor) -> dict[str, torch.Tensor]:
        return {"mu": features[:, 0], "kappa": 20 + features[:, 1].abs()}

    def decode(self, raw: dict[str, torch.Tensor]) -> torch.Tensor:
        zero = torch.zeros_like(raw["mu"])
        return euler_to_rotmat(raw["mu"], zero, zero) @ SAT_R_N.to(raw["mu"].dtype).T

    def log_prob(self, raw: dict[str, torch.Tensor], R: torch.Tensor) -> torch.Tensor:
        k = raw["kappa"]
        return k * torch.cos(uav_yaw(R.to(k.dtype)) - raw["mu"]) - torch.log(torch.special.i0(k))


def toy_raw(batch: int, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "mu": (torch.rand(batch, generator=g, dtype=F64) * 2 - 1) * math.pi,
        "kappa": 20 + 30 * torch.rand(batch, generator=g, dtype=F64),
    }


def fisher_angles(kappa: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Geodesic angles of isotropic matrix Fisher draws around any mode: density proportional to
    ``exp(2 kappa cos t) (1 - cos t)`` on [0, pi] (Haar angle density times the trace term),
    drawn by inverse CDF on a fine grid."""
    t = np.linspace(0, np.pi, 400001)
    f = np.exp(-4 * kappa * np.sin(t / 2) ** 2) * (1 - np.cos(t))
    cdf = np.concatenate([[0], np.cumsum((f[1:] + f[:-1]) / 2 * np.diff(t))])
    return np.interp(rng.random(n), cdf / cdf[-1], t)


def mixture_angles(kappa: float, weight: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    angles = fisher_angles(kappa, n, rng)
    outliers = rng.random(n) < weight
    angles[outliers] = Rotation.random(int(outliers.sum()), random_state=seed).magnitude()
    return angles


# -- the contract test ---------------------------------------------------------------------------
class TestGivesDensity:
    @pytest.mark.parametrize("name", ATTITUDE)
    def test_registry_flags(self, name):
        cls = get_head_class(name)
        assert gives_density(cls) == (cls.is_probabilistic or cls.gives_log_prob)
        assert gives_density(make_head(name)) == gives_density(cls)

    def test_both_kinds_are_registered(self):
        # the parametrised tests below would silently test nothing otherwise
        assert DENSITY and REGRESSION

    def test_toy(self):
        assert gives_density(ToyYawHead) and not gives_density(AttitudeHead)


class TestCheckValidationSplit:
    @pytest.mark.parametrize("split", ["standard/val", "towns/val"])
    def test_accepts(self, split):
        assert check_validation_split(split) == split

    @pytest.mark.parametrize(
        "split", ["standard/test", "standard/train", "towns/london", "val", "standard/val2", ""]
    )
    def test_refuses(self, split):
        with pytest.raises(ValueError, match="validation split only"):
            check_validation_split(split)


# -- raw batches ---------------------------------------------------------------------------------
class TestTakeRaw:
    def test_tensor(self):
        raw = torch.arange(12.0).view(4, 3)
        out = take_raw(raw, torch.tensor([2, 2, 0]))
        torch.testing.assert_close(out, raw[[2, 2, 0]])

    def test_nested_dict(self):
        raw = {"a": torch.arange(4.0), "b": {"c": torch.arange(8).view(4, 2)}}
        out = take_raw(raw, torch.tensor([3, 1]))
        assert set(out) == {"a", "b"} and set(out["b"]) == {"c"}
        torch.testing.assert_close(out["a"], torch.tensor([3.0, 1.0]))
        torch.testing.assert_close(out["b"]["c"], torch.tensor([[6, 7], [2, 3]]))

    def test_refuses_other_types(self):
        with pytest.raises(TypeError, match="Tensor or a dict"):
            take_raw([torch.zeros(2)], torch.tensor([0]))


class TestRawBatchSize:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_sizes(self, batch):
        assert raw_batch_size(torch.zeros(batch, 5)) == batch
        assert raw_batch_size({"x": torch.zeros(batch), "y": torch.zeros(batch, 2, 2)}) == batch

    def test_mismatch(self):
        with pytest.raises(ValueError, match="batch"):
            raw_batch_size({"x": torch.zeros(2), "y": torch.zeros(3)})


# -- the slice -----------------------------------------------------------------------------------
class TestYawSlice:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_scipy(self, batch):
        R_hat = Rotation.random(batch, random_state=batch).as_matrix()
        psi = np.linspace(-np.pi, np.pi, 13, endpoint=False)
        out = yaw_slice(torch.tensor(R_hat), torch.tensor(psi))
        assert out.shape == (batch, 13, 3, 3) and out.dtype == F64
        np.testing.assert_allclose(out.numpy(), scipy_slice(R_hat, psi), atol=1e-13, rtol=0)

    def test_convention_passes_through_the_estimate(self):
        # Head-independent: R_hat from known UAV yaw, pitch, roll; the slice at the true yaw is
        # R_hat, and every slice rotation keeps that pitch and roll (UAV attitude, Eq. 1, 2).
        yaw = torch.tensor([0.3, -2.9, 1.7], dtype=F64)
        pitch = torch.tensor([-0.4, 0.1, 0.7], dtype=F64)
        roll = torch.tensor([0.2, -0.05, -1.1], dtype=F64)
        R_hat = euler_to_rotmat(yaw, pitch, roll) @ SAT_R_N.T  # R_uav^sat = R_uav^n (R_sat^n)^T
        out = yaw_slice(R_hat, yaw)  # (3, 3, 3, 3): slice b at yaw_k
        for b in range(3):
            torch.testing.assert_close(out[b, b], R_hat[b], atol=1e-15, rtol=0)
        psi = CircularGrid(36).centres()
        y, p, r = rotmat_to_euler(yaw_slice(R_hat, psi) @ SAT_R_N)
        torch.testing.assert_close(y, psi.expand(3, 36), atol=1e-13, rtol=0)
        torch.testing.assert_close(p, pitch[:, None].expand(3, 36), atol=1e-13, rtol=0)
        torch.testing.assert_close(r, roll[:, None].expand(3, 36), atol=1e-13, rtol=0)

    def test_gimbal_lock_still_passes_through_the_estimate(self):
        R_hat = euler_to_rotmat(*(torch.tensor([v], dtype=F64) for v in (0.4, math.pi / 2, 0.3)))
        R_hat = R_hat @ SAT_R_N.T
        yaw = rotmat_to_euler(R_hat @ SAT_R_N)[0]  # the in-plane angle, roll folded in
        torch.testing.assert_close(yaw_slice(R_hat, yaw)[0, 0], R_hat[0], atol=1e-12, rtol=0)


# -- calibration ---------------------------------------------------------------------------------
class TestIsotropicFisherLogNormaliser:
    @pytest.mark.parametrize("kappa", [0.0, 1e-3, 0.5, 2.0, 10.0, 100.0, 1e3, 1e4])
    def test_against_quadrature(self, kappa):
        # c(kappa) e^{-3 kappa} = int exp(-2 kappa (1 - cos t)) (1 - cos t) / pi dt, no overflow
        width = min(1.0, 1 / math.sqrt(max(kappa, 1e-12)))
        q = integrate.quad(
            lambda t: math.exp(-2 * kappa * (1 - math.cos(t))) * (1 - math.cos(t)) / math.pi,
            0, math.pi, epsabs=0, epsrel=1e-13, limit=500, points=[width],
        )[0]  # fmt: skip
        got = isotropic_fisher_log_normaliser(kappa)
        assert got == pytest.approx(3 * kappa + math.log(q), abs=1e-12 * max(1.0, kappa))

    @pytest.mark.parametrize("kappa", [0.5, 2.0])
    def test_against_monte_carlo(self, kappa):
        # c(kappa) = E_Haar[exp(kappa tr R)], over Haar-random rotations; within 4 standard errors
        R = Rotation.random(400_000, random_state=7).as_matrix()
        values = np.exp(kappa * np.trace(R, axis1=1, axis2=2))
        se = values.std() / math.sqrt(values.size)
        assert abs(values.mean() - math.exp(isotropic_fisher_log_normaliser(kappa))) < 4 * se

    @pytest.mark.parametrize("kappa", [1e-4, 0.7, 30.0, 3e3])
    def test_against_the_matrix_fisher_head(self, kappa):
        # the closed form e^k (I0(2k) - I1(2k)) against Mohlin et al.'s 1-D integral at F = k I
        # (baselines/matrix_fisher.py, tanh-sinh quadrature): two independent routes
        from baselines.matrix_fisher import log_normaliser

        s = torch.full((3,), kappa, dtype=F64)
        assert isotropic_fisher_log_normaliser(kappa) == pytest.approx(
            float(log_normaliser(s)), abs=1e-11 * max(1.0, kappa)
        )

    def test_uniform_is_one(self):
        assert isotropic_fisher_log_normaliser(0.0) == 0.0

    @pytest.mark.parametrize("kappa", [-1.0, math.inf, math.nan])
    def test_refuses(self, kappa):
        with pytest.raises(ValueError, match="kappa"):
            isotropic_fisher_log_normaliser(kappa)


class TestAttitudeCalibration:
    @pytest.mark.parametrize(("kappa", "weight"), [(5.0, 0.5), (50.0, 0.3), (800.0, 0.05)])
    def test_fit_recovers_known_parameters(self, kappa, weight):
        angles = mixture_angles(kappa, weight, 20_000, seed=int(kappa))
        fit = AttitudeCalibration.fit(angles, "standard/val")
        assert fit.kappa == pytest.approx(kappa, rel=0.05)
        assert fit.outlier_weight == pytest.approx(weight, abs=0.015)
        assert fit.split == "standard/val"

    def test_fit_accepts_a_tensor(self):
        angles = mixture_angles(50.0, 0.3, 2000, seed=3)
        assert AttitudeCalibration.fit(torch.tensor(angles), "towns/val") == (
            AttitudeCalibration.fit(angles, "towns/val")
        )

    @pytest.mark.parametrize("split", ["standard/test", "standard/train", "generalized/test"])
    def test_refuses_a_split_other_than_validation(self, split):
        with pytest.raises(ValueError, match=f"refusing split '{split}'"):
            AttitudeCalibration.fit(mixture_angles(50.0, 0.3, 100, seed=0), split)

    @pytest.mark.parametrize("kappa", [0.3, 20.0, 2000.0])
    def test_density_is_normalised_over_haar(self, kappa):
        cal = AttitudeCalibration(kappa, 0.2, "standard/val")
        t = np.linspace(0, np.pi, 200_001)
        f = np.exp(cal.log_density(t).numpy()) * (1 - np.cos(t)) / np.pi  # Haar angle density
        assert integrate.trapezoid(f, t) == pytest.approx(1.0, abs=1e-6)

    def test_log_density_keeps_type_and_shape(self):
        cal = AttitudeCalibration(10.0, 0.1, "standard/val")
        out = cal.log_density(torch.zeros(2, 5))
        assert out.shape == (2, 5) and out.dtype == F64
        # at the mode: log((1 - w) e^{3 kappa} / c + w)
        expected = math.log(0.9 * math.exp(30 - isotropic_fisher_log_normaliser(10.0)) + 0.1)
        assert float(out[0, 0]) == pytest.approx(expected, rel=1e-14)

    @pytest.mark.parametrize(
        ("kappa", "weight", "match"),
        [(0.0, 0.1, "kappa"), (math.inf, 0.1, "kappa"), (1.0, 0.0, "outlier_weight"),
         (1.0, 1.0, "outlier_weight")],
    )  # fmt: skip
    def test_bad_parameters(self, kappa, weight, match):
        with pytest.raises(ValueError, match=match):
            AttitudeCalibration(kappa, weight, "standard/val")

    @pytest.mark.parametrize("errors", [[0.1, -0.2], [0.1, 4.0], [0.1, math.nan], [0.1]])
    def test_bad_errors(self, errors):
        with pytest.raises(ValueError, match="errors_rad"):
            AttitudeCalibration.fit(np.array(errors), "standard/val")


class TestPositionCalibration:
    AREA = 1000.0 * 800.0

    def draws(self, sigma: float, weight: float, n: int, seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        d = rng.normal(0.0, sigma, (n, 2))
        out = rng.random(n) < weight
        d[out] = rng.uniform([-500, -400], [500, 400], (int(out.sum()), 2))  # the footprint
        return d

    @pytest.mark.parametrize(("sigma", "weight"), [(20.0, 0.3), (5.0, 0.05), (60.0, 0.5)])
    def test_fit_recovers_known_parameters(self, sigma, weight):
        fit = PositionCalibration.fit(self.draws(sigma, weight, 20_000, 1), self.AREA, "x/val")
        assert fit.sigma_m == pytest.approx(sigma, rel=0.03)
        assert fit.outlier_weight == pytest.approx(weight, abs=0.015)
        assert (fit.split, fit.area_m2) == ("x/val", self.AREA)

    def test_refuses_a_split_other_than_validation(self):
        with pytest.raises(ValueError, match="refusing split 'standard/test'"):
            PositionCalibration.fit(self.draws(20.0, 0.3, 100, 0), self.AREA, "standard/test")

    def test_density(self):
        cal = PositionCalibration(7.0, 0.25, "standard/val", self.AREA)
        d = torch.tensor([[0.0, 0.0], [3.0, -4.0]], dtype=F64)
        gauss = stats.multivariate_normal(np.zeros(2), 49 * np.eye(2)).pdf(d.numpy())
        np.testing.assert_allclose(
            np.exp(cal.log_density(d).numpy()), 0.75 * gauss + 0.25 / self.AREA, rtol=1e-13
        )
        other = np.exp(cal.log_density(d, area_m2=4 * self.AREA).numpy())
        np.testing.assert_allclose(other, 0.75 * gauss + 0.25 / (4 * self.AREA), rtol=1e-13)

    @pytest.mark.parametrize("area", [0.0, -1.0, math.inf])
    def test_bad_area(self, area):
        with pytest.raises(ValueError, match="area_m2"):
            PositionCalibration.fit(self.draws(20.0, 0.3, 100, 0), area, "standard/val")

    def test_bad_errors(self):
        with pytest.raises(ValueError, match="d_en"):
            PositionCalibration.fit(np.zeros((10, 3)), self.AREA, "standard/val")


class TestCalibrateFromPredictions:
    def frame(self, n: int = 3000, seed: int = 0) -> pd.DataFrame:
        """A predictions table (metrics.predictions_frame) with known error statistics."""
        rng = np.random.default_rng(seed)
        R_gt = Rotation.random(n, random_state=seed)
        angles = mixture_angles(80.0, 0.2, n, seed)
        axes = rng.normal(size=(n, 3))
        turn = Rotation.from_rotvec(
            axes / np.linalg.norm(axes, axis=1, keepdims=True) * angles[:, None]
        )
        T_gt = rng.normal(0, 100, (n, 3))
        T_hat = T_gt + np.concatenate([rng.normal(0, 12.0, (n, 2)), np.zeros((n, 1))], axis=1)
        t = lambda x: torch.tensor(x, dtype=F64)  # noqa: E731
        return predictions_frame(
            t((turn * R_gt).as_matrix()), t(R_gt.as_matrix()), t(T_hat), t(T_gt)
        )

    def test_fits_both_from_the_table(self):
        frame = self.frame()
        attitude, position = calibrate_from_predictions(frame, "standard/val", 8e5)
        assert attitude == AttitudeCalibration.fit(np.radians(frame["dphi_deg"]), "standard/val")
        assert attitude.kappa == pytest.approx(80.0, rel=0.1)
        assert attitude.outlier_weight == pytest.approx(0.2, abs=0.03)
        assert position.sigma_m == pytest.approx(12.0, rel=0.05)
        assert position.area_m2 == 8e5 and position.split == attitude.split == "standard/val"

    @pytest.mark.parametrize(
        "split", ["standard/test", "standard/train", "generalized/test", "towns/london"]
    )
    def test_calibration_uses_the_validation_split_only(self, split):
        # issue 39: a regression head's calibration uses the validation split only
        with pytest.raises(ValueError, match=f"validation split only.*'{split}'"):
            calibrate_from_predictions(self.frame(100), split, 8e5)

    def test_missing_columns(self):
        with pytest.raises(ValueError, match="dphi_deg"):
            calibrate_from_predictions(self.frame(100).drop(columns="dphi_deg"), "x/val", 8e5)


# -- yaw beliefs ---------------------------------------------------------------------------------
MANY = [n for n in DENSITY if hasattr(get_head_class(n), "log_prob_many")]


class TestLogProbMany:
    """The optional contract hook: K rotations per sample, the normaliser shared."""

    def test_nearest_lattice_points_tree_equals_dense_argmax(self):
        from benchmark.geometry import fibonacci_sphere
        from benchmark.models.spherical import KD_TREE_QUERIES, nearest_lattice_points

        grid = fibonacci_sphere(4096, dtype=F64)
        x = torch.tensor(Rotation.random(KD_TREE_QUERIES + 100, random_state=7).as_matrix()[:, 0])
        tree = nearest_lattice_points(x, grid)  # above the threshold: the k-d tree
        dense = (x @ grid.T).argmax(-1)
        assert torch.equal(tree, dense)
        assert torch.equal(nearest_lattice_points(x[:10], grid), dense[:10])  # dense path
        # tree=True: the tree for any number of queries (a frame's belief bits then do not
        # depend on how many frames share a call); tree=False: dense for any number.
        assert torch.equal(nearest_lattice_points(x[:10], grid, tree=True), dense[:10])
        assert torch.equal(nearest_lattice_points(x, grid, tree=False), dense)

    def test_the_heads_with_a_normaliser_define_it(self):
        # a per-sample normaliser (quadrature, softmax over a lattice) shared by K rotations
        assert {"pd_re_net", "ipdf", "re_net_bingham", "pd_net_q", "pd_net_q_sym",
                "pd_net_rv", "matrix_fisher"} <= set(MANY)  # fmt: skip

    @pytest.mark.parametrize("name", MANY)
    def test_equals_log_prob_row_by_row(self, name):
        head = make_head(name, F64)
        raw, _ = head_output(head, 3, F64)
        R = torch.tensor(Rotation.random(3 * 5, random_state=4).as_matrix()).reshape(3, 5, 3, 3)
        with torch.no_grad():
            many = head.log_prob_many(raw, R)
            rows = torch.stack([head.log_prob(take_raw(raw, torch.full((5,), b)), R[b])
                                for b in range(3)])  # fmt: skip
        assert many.shape == (3, 5)
        torch.testing.assert_close(many, rows, atol=1e-9, rtol=1e-9)


class TestCalibratedYawBeliefs:
    def test_against_scipy_geodesic_angles(self):
        # R(psi) = Rz(psi) Rx(pitch) Ry(roll) (paper Eq. 1) against the estimate at yaw_hat with
        # the same pitch and roll: the density at scipy's angle between the two rotations
        grid, cal = CircularGrid(36), AttitudeCalibration(40.0, 0.2, "standard/val")
        yaw_hat, pitch, roll = np.array([-3.0, -0.4, 0.0, 1.2, 3.1]), -0.7, 0.2
        psi = grid.centres().numpy()

        def rot(yaw):
            return Rotation.from_euler("ZXY", [yaw, pitch, roll])

        angle = np.array([[(rot(y).inv() * rot(p)).magnitude() for p in psi] for y in yaw_hat])
        ours = calibrated_yaw_beliefs(torch.tensor(yaw_hat), grid, cal)
        assert ours.shape == (5, 36) and ours.dtype == F64
        torch.testing.assert_close(ours, cal.log_density(torch.tensor(angle)), rtol=0, atol=1e-9)


class TestYawBeliefs:
    GRID = CircularGrid(24)

    @pytest.mark.parametrize("name", DENSITY)
    def test_density_heads_against_a_per_rotation_loop(self, name):
        # fast (chunked, batched) vs naive (one log_prob call per rotation on scipy's slice); the
        # argmax of the belief is the rotation of the slice where the head's density is highest
        head = make_head(name, F64)
        raw, R_hat = head_output(head, 2, F64)
        fast = yaw_beliefs(head, raw, R_hat, self.GRID)
        psi = self.GRID.centres().numpy()
        R = torch.tensor(scipy_slice(R_hat.numpy(), psi))
        with torch.no_grad():
            naive = torch.tensor(
                [[float(head.log_prob(take_raw(raw, torch.tensor([b])), R[b, j][None]))
                  for j in range(len(psi))] for b in range(2)], dtype=F64,
            )  # fmt: skip
        assert fast.shape == (2, 24) and fast.dtype == F64
        torch.testing.assert_close(fast, naive, atol=1e-9, rtol=1e-9)
        best = fast.argmax(-1)
        torch.testing.assert_close(naive.gather(-1, best[:, None])[:, 0], naive.amax(-1))

    @pytest.mark.parametrize("name", DENSITY)
    def test_chunking_is_bit_identical(self, name):
        head = make_head(name)
        raw, R_hat = head_output(head, 2, torch.float32)
        whole = yaw_beliefs(head, raw, R_hat, self.GRID)
        # not 1 or 2: IPDF's score (an MLP) rounds a 1-2 row batch differently (1 float32 ulp)
        for chunk in (3, 7, 47, 10_000):
            assert torch.equal(yaw_beliefs(head, raw, R_hat, self.GRID, chunk=chunk), whole)

    @pytest.mark.parametrize("name", DENSITY)
    def test_density_heads_ignore_a_calibration(self, name):
        head = make_head(name)
        raw, R_hat = head_output(head, 1, torch.float32)
        cal = AttitudeCalibration(10.0, 0.1, "standard/val")
        assert torch.equal(
            yaw_beliefs(head, raw, R_hat, self.GRID, cal), yaw_beliefs(head, raw, R_hat, self.GRID)
        )

    @pytest.mark.parametrize("name", REGRESSION)
    def test_regression_heads_peak_at_the_estimate_with_the_closed_form_width(self, name):
        # On the slice tr(R_hat^T R(psi)) = 1 + 2 cos(psi - yaw_hat): the matrix Fisher part is a
        # von Mises of concentration 2 kappa in yaw, exactly (scipy.stats.vonmises); its mean
        # resultant length is I1(2 kappa) / I0(2 kappa).
        head = make_head(name)
        raw, R_hat = head_output(head, 3, torch.float32)
        grid, kappa = CircularGrid(720), 150.0
        cal = AttitudeCalibration(kappa, 1e-6, "standard/val")
        belief = normalize_log_density(yaw_beliefs(head, raw, R_hat, grid, cal), grid)
        yaw_hat = uav_yaw(R_hat.double())
        psi = grid.centres()
        nearest = wrap(psi.numpy()[None] - yaw_hat.numpy()[:, None])
        assert torch.equal(belief.argmax(-1), torch.tensor(np.abs(nearest).argmin(-1)))
        reference = stats.vonmises(2 * kappa, loc=yaw_hat.numpy()[:, None]).logpdf(psi.numpy())
        # the 1e-6 uniform share lifts the far tail (~e^{-4 kappa}) to log(1e-6 / (2 pi))
        tail = np.exp(reference) < 1e-3
        np.testing.assert_allclose(belief.numpy()[~tail], reference[~tail], atol=1e-5, rtol=0)
        resultant = (belief.exp() * torch.exp(1j * (psi - yaw_hat[:, None]))).sum(-1) * grid.cell
        np.testing.assert_allclose(
            resultant.abs().numpy(), special.i1e(2 * kappa) / special.i0e(2 * kappa), atol=1e-5
        )

    def test_regression_mixture_matches_the_formula(self):
        head = make_head(REGRESSION[0])
        raw, R_hat = head_output(head, 2, torch.float32)
        kappa, w = 40.0, 0.2
        out = yaw_beliefs(head, raw, R_hat, self.GRID, AttitudeCalibration(kappa, w, "a/val"))
        delta = wrap(self.GRID.centres().numpy()[None] - uav_yaw(R_hat.double()).numpy()[:, None])
        log_g = math.log(special.i0e(2 * kappa) - special.i1e(2 * kappa))
        expected = np.log((1 - w) * np.exp(2 * kappa * (np.cos(delta) - 1) - log_g) + w)
        np.testing.assert_allclose(out.numpy(), expected, atol=1e-9, rtol=0)

    def test_regression_angle_is_the_geodesic_distance_to_the_slice(self):
        # the identity the regression branch uses, against the matrices (exact rotations)
        head = make_head(REGRESSION[0])
        R_hat = torch.tensor(Rotation.random(5, random_state=2).as_matrix())
        cal = AttitudeCalibration(40.0, 0.2, "standard/val")
        out = yaw_beliefs(head, None, R_hat, self.GRID, cal)
        slice_ = yaw_slice(R_hat, self.GRID.centres())
        expected = cal.log_density(geodesic_distance(R_hat[:, None], slice_))
        torch.testing.assert_close(out, expected, atol=1e-10, rtol=0)

    @pytest.mark.parametrize("name", REGRESSION)
    def test_regression_head_needs_a_calibration(self, name):
        head = make_head(name)
        raw, R_hat = head_output(head, 1, torch.float32)
        with pytest.raises(ValueError, match=f"{type(head).__name__} \\({name}\\).*Calibration"):
            yaw_beliefs(head, raw, R_hat, self.GRID)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_dict_raw_and_uav_yaw(self, batch):
        # A head whose density is a von Mises in the UAV's yaw (navigation frame): its belief is
        # that von Mises on the grid, so the grid is the UAV yaw, counter-clockwise, as Eq. 1.
        head, raw = ToyYawHead(FEATURES), toy_raw(batch)
        grid = CircularGrid(360)
        out = yaw_beliefs(head, raw, head.decode(raw), grid, chunk=100)
        expected = von_mises_belief(grid, raw["mu"], raw["kappa"])
        torch.testing.assert_close(normalize_log_density(out, grid), expected, atol=1e-10, rtol=0)

    def test_bad_arguments(self):
        head, raw = ToyYawHead(FEATURES), toy_raw(3)
        R_hat = head.decode(raw)
        with pytest.raises(ValueError, match="R_hat"):
            yaw_beliefs(head, raw, R_hat[:, :2], self.GRID)
        with pytest.raises(ValueError, match="batch size"):
            yaw_beliefs(head, raw, R_hat[:2], self.GRID)
        for chunk in (0, 2.5, True):
            with pytest.raises(ValueError, match="chunk"):
                yaw_beliefs(head, raw, R_hat, self.GRID, chunk=chunk)


# -- position beliefs ----------------------------------------------------------------------------
class TestPositionBeliefs:
    GRID = PlanarGrid(-100.0, -60.0, 5.0, 41, 25)
    CAL = PositionCalibration(12.0, 0.2, "standard/val", 8e5)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_closed_form_at_the_cell_centres(self, batch):
        rng = np.random.default_rng(batch)
        hat = torch.tensor(rng.uniform([-90, -50], [90, 50], (batch, 2)), dtype=F64)
        out = position_beliefs(hat, self.GRID, self.CAL)
        assert out.shape == (batch, 41, 25) and out.dtype == F64
        east = -100.0 + 5.0 * np.arange(41)
        north = -60.0 + 5.0 * np.arange(25)
        for b in range(batch):
            x = np.stack(np.meshgrid(east, north, indexing="ij"), -1)
            gauss = stats.multivariate_normal(hat[b].numpy(), 144 * np.eye(2)).pdf(x)
            np.testing.assert_allclose(np.exp(out[b].numpy()), 0.8 * gauss + 0.2 / 8e5, rtol=1e-12)

    def test_convention_east_first(self):
        out = position_beliefs(torch.tensor([[50.0, 0.0]], dtype=F64), self.GRID, self.CAL)
        i, j = np.unravel_index(int(out[0].argmax()), out[0].shape)
        assert (i, j) == (30, 12)  # east0 + 30 h = 50 m, north0 + 12 h = 0 m

    def test_bad_shape(self):
        with pytest.raises(ValueError, match="T_hat_en"):
            position_beliefs(torch.zeros(2, 3), self.GRID, self.CAL)
