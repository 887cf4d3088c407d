"""The shared head bases (``benchmark/models/head_bases.py``): minimal subclasses declared here get
their distribution, target, decoding, loss, uncertainty and log density right against numpy, scipy
and closed forms, and a missing hook or a bad option fails clearly."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.special import logsumexp, softmax

from benchmark.geometry import fibonacci_sphere, rotmat_to_quat, special_orthogonalize
from benchmark.geometry import super_fibonacci as s3_lattice
from benchmark.models import (
    AttitudeHead,
    GridDistribution,
    LatticeDirections,
    LatticeHead,
    RegressionAttitudeHead,
    RegressionTranslationHead,
)
from benchmark.models.heads import mlp

F, N, B = 6, 256, 5


class Columns(LatticeHead):
    """Three columns of R on S^2 (the Pd/Re-Net representation), declared from scratch."""

    channels = 3
    lattice = staticmethod(fibonacci_sphere)

    def encode(self, R):
        return R.transpose(-1, -2)

    def to_label(self, columns):
        return special_orthogonalize(columns.transpose(-1, -2))


class Quaternion(LatticeHead):
    """One quaternion on S^3: to_label and log_density come from the base."""

    lattice = staticmethod(s3_lattice)

    def encode(self, R):
        return rotmat_to_quat(R)


class Euler(RegressionAttitudeHead):
    raw_shape = (3,)

    def encode(self, R):
        # ZXY intrinsic (yaw, pitch, roll) as scipy gives it, no torch code involved in the test.
        angles = Rotation.from_matrix(R.detach().numpy()).as_euler("ZXY")
        return torch.as_tensor(angles, dtype=R.dtype)

    def to_label(self, x):
        return torch.as_tensor(Rotation.from_euler("ZXY", x.detach().numpy()).as_matrix())


class UnitQuaternion(RegressionAttitudeHead):
    raw_shape = (4,)

    def normalize(self, raw):
        return raw / raw.norm(dim=-1, keepdim=True)

    def encode(self, R):
        return rotmat_to_quat(R)

    def to_label(self, q):
        xyzw = np.roll(q.detach().numpy(), -1, axis=-1)  # scipy is scalar-last
        return torch.as_tensor(Rotation.from_quat(xyzw).as_matrix())


class Matrix(RegressionAttitudeHead):
    raw_shape = (3, 3)

    def encode(self, R):
        return R

    def to_label(self, x):
        return special_orthogonalize(x)


class Translation(RegressionTranslationHead):
    pass


def build(cls, **kwargs):
    torch.manual_seed(0)
    defaults = {"n_points": N} if issubclass(cls, LatticeHead) else {"hidden": 16}
    return cls(in_features=F, **{**defaults, **kwargs}).double()


def features() -> torch.Tensor:
    return torch.randn(B, F, generator=torch.Generator().manual_seed(1), dtype=torch.float64)


def rotations(n: int = B) -> Rotation:
    return Rotation.random(n, random_state=2)


def as_tensor(rot: Rotation) -> torch.Tensor:
    return torch.tensor(rot.as_matrix(), dtype=torch.float64)


def geodesic_deg(R_hat: torch.Tensor, rot: Rotation) -> np.ndarray:
    return np.degrees((Rotation.from_matrix(R_hat.detach().numpy()) * rot.inv()).magnitude())


def directionnet_scale(n: int, sphere_area: float) -> float:
    # DirectionNet's 64 x 64 pixels of (pi / 64) (2 pi / 64) sr, re-expressed for n equal cells.
    return (math.pi / 64) * (2 * math.pi / 64) * n / (4096 * sphere_area)


class TestLatticeHead:
    def test_raw_and_distribution_shapes_and_softmax(self):
        for cls, shape in ((Columns, (B, 3, N)), (Quaternion, (B, N))):
            h = build(cls)
            raw = h(features())
            assert raw.shape == shape
            p = h.distribution(raw)
            np.testing.assert_allclose(p.detach().numpy(), softmax(raw.detach().numpy(), -1))

    def test_target_is_the_discrete_vmf(self):
        h, rot = build(Columns, kappa=7.0), rotations()
        grid = h.grid.double().numpy()
        mu = rot.as_matrix().transpose(0, 2, 1)  # (B, 3 columns, 3)
        logits = 7.0 * mu @ grid.T
        expected = np.exp(logits - logsumexp(logits, axis=-1, keepdims=True))
        got = h.target_distribution(as_tensor(rot)).numpy()
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-15)

    def test_decode_is_the_projected_normalised_expectation(self):
        h = build(Columns)
        p = h.distribution(h(features())).detach()
        grid = h.grid.double().numpy()
        m = p.numpy() @ grid  # (B, 3, 3): rows are the column expectations
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        u, _, vt = np.linalg.svd(m.transpose(0, 2, 1))
        d = np.sign(np.linalg.det(u @ vt))
        expected = u @ (np.stack([np.ones(B), np.ones(B), d], -1)[:, :, None] * vt)
        np.testing.assert_allclose(h.decode(h(features())).detach().numpy(), expected, atol=1e-10)
        assert torch.equal(h.decode(h(features())), h.decode_distribution(p))

    def test_own_target_decodes_to_the_label(self):
        rot = rotations()
        for cls in (Columns, Quaternion):
            h = build(cls, n_points=4096)
            R_hat = h.decode_distribution(h.target_distribution(as_tensor(rot)))
            assert geodesic_deg(R_hat, rot).max() < 1.0, cls.__name__

    def test_loss_is_eq13_plus_scaled_eq14(self):
        rot = rotations()
        for cls, area in ((Columns, 4 * math.pi), (Quaternion, 2 * math.pi**2)):
            h = build(cls, kappa=5.0, alpha=3e4)
            raw = h(features())
            p = softmax(raw.detach().numpy(), -1).reshape(B, -1, N)
            x = h.encode(as_tensor(rot)).numpy().reshape(B, p.shape[1], -1)
            grid = h.grid.double().numpy()
            logits = 5.0 * x @ grid.T
            target = np.exp(logits - logsumexp(logits, axis=-1, keepdims=True))
            m = p @ grid
            cos = (m * x).sum(-1) / np.linalg.norm(m, axis=-1) / np.linalg.norm(x, axis=-1)
            l2 = ((p - target) ** 2).sum(-1)
            per_sample = (1 - cos + 3e4 * directionnet_scale(N, area) * l2).sum(-1)
            got = h.loss(raw, as_tensor(rot))
            assert got.item() == pytest.approx(per_sample.mean(), rel=1e-10)
            got.backward()
            assert all(q.grad is not None and torch.isfinite(q.grad).all() for q in h.parameters())

    def test_uncertainty_is_the_mean_spherical_variance(self):
        h = build(Columns)
        raw = h(features())
        p = softmax(raw.detach().numpy(), -1)
        expected = 1 - np.linalg.norm(p @ h.grid.double().numpy(), axis=-1).mean(-1)
        np.testing.assert_allclose(h.uncertainty(raw).detach().numpy(), expected, rtol=1e-12)
        assert h.uncertainty(torch.zeros(1, 3, N, dtype=torch.float64)).item() > 0.95

    def test_quaternion_defaults_against_scipy_and_the_haar_density(self):
        h, rot = build(Quaternion), rotations()
        grid = h.grid.double().numpy()
        q = np.roll(rot.as_quat(), 1, axis=-1)  # (w, x, y, z)
        R_hat = h.to_label(torch.tensor(q))
        np.testing.assert_allclose(R_hat.numpy(), rot.as_matrix(), atol=1e-12)
        # Uniform prediction: density 1 w.r.t. the normalised Haar measure.
        uniform = torch.zeros(B, N, dtype=torch.float64)
        np.testing.assert_allclose(h.log_prob(uniform, as_tensor(rot)).numpy(), 0.0, atol=1e-12)
        # log(p(q) + p(-q)) + log(n / 2) with the nearest lattice points, by brute force.
        raw = h(features()).detach()
        log_p = raw.numpy() - logsumexp(raw.numpy(), axis=-1, keepdims=True)
        dots = q @ grid.T
        near = np.take_along_axis(log_p, dots.argmax(-1)[:, None], -1)[:, 0]
        far = np.take_along_axis(log_p, dots.argmin(-1)[:, None], -1)[:, 0]
        expected = np.logaddexp(near, far) + math.log(N / 2)
        np.testing.assert_allclose(h.log_prob(raw, as_tensor(rot)).numpy(), expected, rtol=1e-12)

    def test_state_dict_holds_the_decoder_only_and_options_are_the_base_signature(self):
        h = build(Columns, hidden=12)
        shapes = {k: tuple(v.shape) for k, v in h.state_dict().items()}
        assert shapes == {
            "decoder.net.0.weight": (12, F),
            "decoder.net.0.bias": (12,),
            "decoder.net.2.weight": (3 * N, 12),
            "decoder.net.2.bias": (3 * N,),
        }
        assert (h.kappa, h.alpha) == (10.0, 8e7)

    @pytest.mark.parametrize(
        ("option", "value", "message"),
        [("kappa", 0.0, "kappa must be > 0"), ("alpha", -1.0, "alpha must be >= 0"),
         ("n_points", 3, "n_points must be an int >= 4")],
    )  # fmt: skip
    def test_bad_option_names_the_head_and_option(self, option, value, message):
        with pytest.raises(ValueError, match=f"Columns: {message}"):
            build(Columns, **{option: value})

    def test_missing_hooks_fail_clearly(self):
        class NoLabel(LatticeHead):
            channels = 3
            lattice = staticmethod(fibonacci_sphere)

            def encode(self, R):
                return R.transpose(-1, -2)

        h = build(NoLabel)
        raw = h(features())
        with pytest.raises(NotImplementedError, match="NoLabel must define to_label"):
            h.decode(raw)
        with pytest.raises(NotImplementedError, match="NoLabel must define log_density"):
            h.log_prob(raw, as_tensor(rotations()))
        h.loss(raw, as_tensor(rotations())).backward()  # the loss needs encode only


class AxisAndTwist(LatticeDirections, AttitudeHead):
    """One direction on the lattice beside a layer of its own (as Pd-Net-Rv, Re-Net-T)."""

    def __init__(self, in_features, n_points=N, kappa=10.0, alpha=8e7, hidden=8):
        super().__init__(in_features)
        self.init_lattice(n_points, kappa, alpha)
        self.net = mlp(in_features, hidden, n_points)

    def forward(self, features):
        return self.net(features)

    def decode_distribution(self, p):  # the axis alone, angle 90 deg: enough for the contract
        from benchmark.geometry import rotvec_to_rotmat

        return rotvec_to_rotmat(self.direction_mean(p) * (math.pi / 2))


class TestLatticeDirections:
    """The mixins under Pd-Net-Rv, Re-Net-T (``LatticeDirections``), Pd-Net-E and IPDF
    (``GridDistribution``) and ``LatticeHead`` (issue 22)."""

    def test_grid_is_a_buffer_not_saved_and_the_layers_are_the_heads_own(self):
        h = build(AxisAndTwist)
        assert set(h.state_dict()) == {"net.0.weight", "net.0.bias", "net.2.weight", "net.2.bias"}
        assert torch.equal(h.grid.float(), fibonacci_sphere(N)) and h.n_points == N
        assert h.is_probabilistic and issubclass(LatticeHead, LatticeDirections)

    def test_direction_helpers_are_the_discrete_vmf_and_its_moments(self):
        h = build(AxisAndTwist)
        x = torch.nn.functional.normalize(torch.randn(B, 3, dtype=torch.float64), dim=-1)
        grid = h.grid.double().numpy()
        target = h.direction_target(x)
        np.testing.assert_allclose(target.numpy(), softmax(10.0 * x.numpy() @ grid.T, axis=-1))
        resultant = target.numpy() @ grid
        length = np.linalg.norm(resultant, axis=-1)
        np.testing.assert_allclose(h.direction_mean(target).numpy(), resultant / length[:, None])
        np.testing.assert_allclose(h.direction_spread(target).numpy(), 1 - length, atol=1e-12)
        own = h.direction_loss(target, x)  # the target itself: only the Eq. 13 cosine is left
        cosine = (resultant * x.numpy()).sum(-1) / length
        np.testing.assert_allclose(own.numpy(), 1 - cosine, atol=1e-12)

    def test_decode_is_decode_distribution_of_the_distribution(self):
        h = build(AxisAndTwist)
        raw = h(features())
        assert torch.equal(h.decode(raw), h.decode_distribution(torch.softmax(raw, dim=-1)))
        assert issubclass(AxisAndTwist, GridDistribution)

    def test_bad_option_names_the_head(self):
        with pytest.raises(ValueError, match="AxisAndTwist: kappa must be > 0"):
            build(AxisAndTwist, kappa=0.0)


class TestRegressionBases:
    def test_loss_is_the_squared_distance_to_the_encoded_label(self):
        rot = rotations()
        cases = (
            (Euler, rot.as_euler("ZXY")),
            (UnitQuaternion, np.roll(rot.as_quat(), 1, axis=-1)),
            (Matrix, rot.as_matrix()),
        )
        for cls, label in cases:
            h = build(cls)
            raw = h(features())
            assert raw.shape == (B, *cls.raw_shape)
            x = raw.detach().numpy()
            if cls is UnitQuaternion:
                x = x / np.linalg.norm(x, axis=-1, keepdims=True)
                # Compare against the head's sign convention: rotmat_to_quat picks one of +-q.
                label = label * np.sign((label * h.encode(as_tensor(rot)).numpy()).sum(-1))[:, None]
            expected = ((x - label) ** 2).reshape(B, -1).sum(-1).mean()
            loss = h.loss(raw, as_tensor(rot))
            assert loss.item() == pytest.approx(expected, rel=1e-10), cls.__name__
            loss.backward()
            assert h.net[0].weight.grad is not None

    def test_decode_is_to_label_of_the_normalised_raw(self):
        rot = rotations()
        q = torch.tensor(np.roll(rot.as_quat(), 1, axis=-1)) * 3.0  # not unit: normalised first
        np.testing.assert_allclose(build(UnitQuaternion).decode(q).numpy(), rot.as_matrix())
        euler = torch.tensor(rot.as_euler("ZXY"))
        np.testing.assert_allclose(build(Euler).decode(euler).numpy(), rot.as_matrix())

    def test_mlp_shape_and_state_dict_keys(self):
        h = build(Matrix, hidden=7)
        shapes = {k: tuple(v.shape) for k, v in h.state_dict().items()}
        assert shapes == {
            "net.0.weight": (7, F),
            "net.0.bias": (7,),
            "net.2.weight": (9, 7),
            "net.2.bias": (9,),
        }

    def test_translation_base_regresses_the_standardised_translation(self):
        h = build(Translation)
        T_train = np.random.default_rng(4).normal(size=(40, 3)) * 50 + 100
        h.fit_statistics(torch.tensor(T_train))
        mean, std = T_train.mean(0), T_train.std(0)  # numpy's default: the population std
        raw = h(features())
        T = np.random.default_rng(5).normal(size=(B, 3)) * 50
        expected = (((raw.detach().numpy() - (T - mean) / std) ** 2).sum(-1)).mean()
        assert h.loss(raw, torch.tensor(T)).item() == pytest.approx(expected, rel=1e-10)
        decoded = h.decode(raw).detach().numpy()
        np.testing.assert_allclose(decoded, raw.detach().numpy() * std + mean, rtol=1e-12)

    def test_hidden_must_be_positive(self):
        with pytest.raises(ValueError, match="hidden must be a positive int"):
            build(Matrix, hidden=0)
