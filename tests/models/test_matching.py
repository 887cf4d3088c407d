"""The matching encoder: correlation, pose volume, its NLL, the pair-encoder contract, shapes and
every registered attitude head on top of it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from benchmark.models import PairEncoder, create_model, list_heads, matching_ops
from benchmark.models.matching import matching
from benchmark.models.matching_ops import (
    bev_templates,
    correlate_conv,
    correlate_dft,
    correlate_fft,
    correlate_xdft,
    fft_size,
)


def _context(b: int, size_m=(2000.0, 1000.0)) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(b)
    return {
        "fov": torch.full((b,), math.radians(60.0)),
        "sat_footprint_m": torch.tensor([size_m]).expand(b, 2).clone(),
        "sat_height_m": torch.full((b,), 1000.0),
        "prior_attitude": torch.rand(b, 2, generator=g) * torch.tensor([-0.8, 0.3]),
        "prior_altitude_m": 70.0 + 20.0 * torch.rand(b, generator=g),
    }


def _labels(b: int) -> tuple[torch.Tensor, torch.Tensor]:
    from benchmark.geometry import SAT_R_N, euler_to_rotmat

    g = torch.Generator().manual_seed(100 + b)
    e = torch.rand(b, 3, generator=g, dtype=torch.float64)
    R_n = euler_to_rotmat((e[:, 0] - 0.5) * 6.2, -0.8 * e[:, 1], 0.3 * (e[:, 2] - 0.5))
    R = (R_n @ SAT_R_N.to(R_n).transpose(0, 1)).float()
    T = torch.cat([(torch.rand(b, 2, generator=g) - 0.5) * 600, -920 + torch.zeros(b, 1)], 1)
    return R, T


class TestCorrelate:
    @pytest.mark.parametrize("b", [1, 3])
    def test_fft_equals_conv_and_brute_force(self, b):
        g = torch.Generator().manual_seed(b)
        sat = torch.randn(b, 4, 13, 13, generator=g, dtype=torch.float64)
        tpl = torch.randn(b, 5, 4, 5, 5, generator=g, dtype=torch.float64)
        fft, conv = correlate_fft(sat, tpl), correlate_conv(sat, tpl)
        assert fft.shape == conv.shape == (b, 5, 9, 9)
        torch.testing.assert_close(fft, conv, rtol=1e-10, atol=1e-10)
        dft = correlate_dft(sat, tpl)  # complex64 transforms: float32 rounding
        torch.testing.assert_close(dft, conv, rtol=1e-4, atol=1e-4)
        i, k, y, x = b - 1, 3, 7, 2
        brute = (tpl[i, k] * sat[i, :, y : y + 5, x : x + 5]).sum()
        assert float(conv[i, k, y, x]) == pytest.approx(float(brute), rel=1e-12)

    @pytest.mark.parametrize("fn", [correlate_fft, correlate_conv])
    def test_gradcheck_float64(self, fn):
        # (correlate_dft runs in complex64 by design: its gradient is checked against conv's.)
        g = torch.Generator().manual_seed(0)
        sat = torch.randn(2, 2, 7, 7, generator=g, dtype=torch.float64, requires_grad=True)
        tpl = torch.randn(2, 3, 2, 3, 3, generator=g, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(fn, (sat, tpl))

    def test_dft_gradient_matches_conv(self):
        g = torch.Generator().manual_seed(2)
        sat = torch.randn(2, 3, 15, 15, generator=g, requires_grad=True)
        tpl = torch.randn(2, 4, 3, 7, 7, generator=g, requires_grad=True)
        w = torch.randn(2, 4, 9, 9, generator=g)
        grads = []
        for fn in (correlate_dft, correlate_conv):
            gs, gt = torch.autograd.grad((fn(sat, tpl) * w).sum(), (sat, tpl))
            grads.append((gs, gt))
        torch.testing.assert_close(grads[0][0], grads[1][0], rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(grads[0][1], grads[1][1], rtol=1e-4, atol=1e-4)


class TestCorrelateXdft:
    """The default correlation (issue 40): a real DFT along the columns, a batched GEMM along the
    rows. Against the direct correlation (``correlate_conv``, a grouped conv2d) and a brute-force
    sum, in float64; against the 2-D DFT it replaced (``correlate_dft``, complex64) in float32
    on the quick step's shapes; gradients by float64 gradcheck and against conv's."""

    # (b, k, c, t, g): the grid side g is a 2-3-5 FFT size (20, 10, 15) or not (13, 23, 63:
    # the columns padded to 15, 24, 64); t == g leaves one position, t = 1 every cell.
    SHAPES = ((1, 5, 4, 5, 13), (3, 2, 3, 9, 23), (2, 4, 2, 7, 20), (1, 3, 2, 10, 10),
              (2, 3, 1, 1, 15), (2, 36, 8, 25, 63))  # fmt: skip

    @pytest.mark.parametrize(("b", "k", "c", "t", "g"), SHAPES)
    def test_equals_conv_and_brute_force_float64(self, b, k, c, t, g):
        gen = torch.Generator().manual_seed(g)
        sat = torch.randn(b, c, g, g, generator=gen, dtype=torch.float64)
        tpl = torch.randn(b, k, c, t, t, generator=gen, dtype=torch.float64)
        got, conv = correlate_xdft(sat, tpl), correlate_conv(sat, tpl)
        m = g - t + 1
        assert got.shape == (b, k, m, m) and got.dtype == torch.float64
        torch.testing.assert_close(got, conv, rtol=1e-10, atol=1e-10)
        i, j, y, x = b - 1, k - 1, m - 1, 0  # the last row: y + t - 1 = g - 1, no wrap-around
        brute = (tpl[i, j] * sat[i, :, y : y + t, x : x + t]).sum()
        assert float(got[i, j, y, x]) == pytest.approx(float(brute), rel=1e-12, abs=1e-12)

    def test_gradcheck_float64(self):
        gen = torch.Generator().manual_seed(0)
        sat = torch.randn(2, 2, 7, 7, generator=gen, dtype=torch.float64, requires_grad=True)
        tpl = torch.randn(2, 3, 2, 3, 3, generator=gen, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(correlate_xdft, (sat, tpl))

    def test_float32_matches_the_dft_it_replaced_forward_and_backward(self):
        """The quick step's shapes (36 yaws, 8 channels, 25 x 25 templates, 63 x 63 grid):
        both float32 paths within 2e-6 of the float64 direct correlation's largest value (the
        stated tolerance: float32 rounding of ~5000-term sums), and their gradients within
        1e-4 relative of conv's float64 ones."""
        gen = torch.Generator().manual_seed(3)
        sat = torch.randn(2, 8, 63, 63, generator=gen, requires_grad=True)
        tpl = torch.randn(2, 36, 8, 25, 25, generator=gen, requires_grad=True)
        w = torch.randn(2, 36, 39, 39, generator=gen)
        sat64, tpl64 = (
            sat.detach().double().requires_grad_(),
            tpl.detach().double().requires_grad_(),
        )
        ref = correlate_conv(sat64, tpl64)
        ref_grads = torch.autograd.grad((ref * w.double()).sum(), (sat64, tpl64))
        scale = float(ref.abs().max())
        for fn in (correlate_xdft, correlate_dft):
            out = fn(sat, tpl)
            assert out.dtype == torch.float32
            assert float((out.double() - ref).abs().max()) <= 2e-6 * scale, fn.__name__
            grads = torch.autograd.grad((out * w).sum(), (sat, tpl))
            for got, want in zip(grads, ref_grads, strict=True):
                err = float((got.double() - want).abs().max()) / float(want.abs().max())
                assert err <= 1e-4, (fn.__name__, err)

    def test_bf16_under_autocast(self):
        """Under CPU autocast bf16 the GEMMs run in bf16 (the error is bf16's, far above
        float32's) and the result and gradients come back in the inputs' float32; on unit
        feature vectors, as the matcher correlates them, within 1 % of the largest value."""
        gen = torch.Generator().manual_seed(4)
        unit = torch.nn.functional.normalize
        sat = unit(torch.randn(2, 8, 63, 63, generator=gen), dim=1).requires_grad_()
        tpl = unit(torch.randn(2, 36, 8, 25, 25, generator=gen), dim=2).requires_grad_()
        ref = correlate_conv(sat.detach().double(), tpl.detach().double())
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = correlate_xdft(sat, tpl)
        assert out.dtype == torch.float32
        err = float((out.double() - ref).abs().max()) / float(ref.abs().max())
        assert 1e-4 < err < 1e-2, err
        out.sum().backward()
        assert sat.grad.dtype == tpl.grad.dtype == torch.float32
        assert torch.isfinite(sat.grad).all() and torch.isfinite(tpl.grad).all()

    def test_padding_is_the_2_3_5_fft_size(self):
        # The columns are transformed at fft_size(g) >= g: nothing the kept outputs read wraps.
        assert [fft_size(g) for g in (13, 23, 63, 64, 71)] == [15, 24, 64, 64, 72]


def _conv_grads(sat, tpl, w):
    """correlate_conv's output and its gradients of ``(out * w).sum()`` (the reference)."""
    sat, tpl = (x.detach().requires_grad_() for x in (sat, tpl))
    out = correlate_conv(sat, tpl)
    return (out.detach(), *torch.autograd.grad((out * w).sum(), (sat, tpl)))


class TestCorrelateXdftBlocks:
    """``correlate_xdft``'s blocks of pairs (issue 40: 2 by default), a partial last block
    included, and its per-thread workspace (buffers reused across blocks, calls and shapes),
    against the direct correlation in float64."""

    @pytest.mark.parametrize("block", [1, 2, 3, 8])
    def test_blocks_equal_conv_forward_and_backward_float64(self, block):
        gen = torch.Generator().manual_seed(block)
        sat = torch.randn(5, 3, 17, 17, generator=gen, dtype=torch.float64, requires_grad=True)
        tpl = torch.randn(5, 4, 3, 6, 6, generator=gen, dtype=torch.float64, requires_grad=True)
        w = torch.randn(5, 4, 12, 12, generator=gen, dtype=torch.float64)
        out = correlate_xdft(sat, tpl, block=block)
        grads = torch.autograd.grad((out * w).sum(), (sat, tpl))
        for got, want in zip((out, *grads), _conv_grads(sat, tpl, w), strict=True):
            torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-10)

    def test_gradcheck_float64_partial_block(self):
        gen = torch.Generator().manual_seed(1)
        sat = torch.randn(3, 2, 7, 7, generator=gen, dtype=torch.float64, requires_grad=True)
        tpl = torch.randn(3, 3, 2, 3, 3, generator=gen, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda s, t: correlate_xdft(s, t, block=2), (sat, tpl))

    @pytest.mark.parametrize("which", ["sat", "templates"])
    def test_one_input_requiring_grad(self, which):
        gen = torch.Generator().manual_seed(2)
        sat = torch.randn(3, 2, 11, 11, generator=gen, dtype=torch.float64)
        tpl = torch.randn(3, 2, 2, 5, 5, generator=gen, dtype=torch.float64)
        w = torch.randn(3, 2, 7, 7, generator=gen, dtype=torch.float64)
        x = (sat if which == "sat" else tpl).requires_grad_()
        (got,) = torch.autograd.grad((correlate_xdft(sat, tpl) * w).sum(), (x,))
        want = _conv_grads(sat, tpl, w)[1 if which == "sat" else 2]
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-10)

    def test_workspace_reused_across_shapes_and_interleaved_calls(self):
        """Two forwards before their backwards (the matcher's altitude banks), then other
        shapes, then the first again: every result and gradient still conv's (no buffer of one
        call leaks into another)."""
        gen = torch.Generator().manual_seed(3)
        f64 = torch.float64
        cases = [
            (torch.randn(4, 2, 13, 13, generator=gen, dtype=f64),
             torch.randn(4, 3, 2, 5, 5, generator=gen, dtype=f64)),
            (torch.randn(4, 2, 13, 13, generator=gen, dtype=f64),
             torch.randn(4, 3, 2, 5, 5, generator=gen, dtype=f64)),
            (torch.randn(2, 3, 10, 10, generator=gen, dtype=f64),
             torch.randn(2, 2, 3, 4, 4, generator=gen, dtype=f64)),
        ]  # fmt: skip
        for _ in range(2):
            leaves = [(s.clone().requires_grad_(), t.clone().requires_grad_()) for s, t in cases]
            outs = [correlate_xdft(s, t) for s, t in leaves]  # every forward first
            for (s, t), out in zip(leaves, outs, strict=True):
                w = torch.linspace(-1, 1, out.numel(), dtype=f64).view_as(out)
                grads = torch.autograd.grad((out * w).sum(), (s, t))
                for got, want in zip((out, *grads), _conv_grads(s, t, w), strict=True):
                    torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-10)

    def test_workspaces_per_thread_bounded(self):
        cache = matching_ops._WORKSPACES.cache  # this thread's, filled by the calls above
        assert 1 <= len(cache) <= matching_ops._WORKSPACE_SHAPES


class TestTransposePairs:
    @pytest.mark.parametrize("dtype", [torch.float64, torch.float32, torch.bfloat16])
    def test_equals_the_batched_transpose(self, dtype):
        src = torch.randn(3, 66, 200, generator=torch.Generator().manual_seed(0)).to(dtype)
        out = torch.empty(3, 200, 66, dtype=dtype)
        matching_ops._transpose_pairs(src, out)
        assert torch.equal(out, src.transpose(1, 2))


class TestBevTemplates:
    def test_gradcheck_float64(self):
        # The warp is differentiable in the features and in the geometry (pitch, roll, height).
        g = torch.Generator().manual_seed(1)
        feats = torch.randn(2, 2, 12, 12, generator=g, dtype=torch.float64, requires_grad=True)
        pitch = torch.tensor([-0.6, -0.4], dtype=torch.float64, requires_grad=True)
        roll = torch.tensor([0.05, -0.1], dtype=torch.float64, requires_grad=True)
        alt = torch.tensor([80.0, 90.0], dtype=torch.float64, requires_grad=True)
        fov = torch.full((2,), 1.0, dtype=torch.float64)
        yaws = torch.tensor([0.3, 2.0], dtype=torch.float64)

        def warp(f, p, r, a):
            return bev_templates(f, (2, 2), 24, yaws, 2, 23.0, p, r, a, fov)[0]

        assert torch.autograd.gradcheck(warp, (feats, pitch, roll, alt), atol=1e-6)


class TestBevTemplatesMasking:
    def test_masked_cells_are_exact_zeros_as_a_multiply_by_the_mask(self):
        """Masked cells sample outside the map (``OUTSIDE_GRID``): the templates equal, bit for
        bit, the unmasked sampling times the mask, and so do the features' gradients."""
        from benchmark.models.matching_geometry import ground_to_uav_pixel, pixel_to_grid
        from benchmark.models.matching_ops import _template_cells

        g = torch.Generator().manual_seed(5)
        feats = torch.randn(3, 4, 24, 24, generator=g, requires_grad=True)
        pitch, roll = torch.tensor([-0.7, -0.3, -1.2]), torch.tensor([0.05, -0.1, 0.0])
        alt, fov = torch.tensor([80.0, 60.0, 120.0]), torch.full((3,), 1.0)
        yaws = torch.linspace(0.0, 6.0, 7)
        got, mask = bev_templates(feats, (2, 2), 48, yaws, 6, 20.0, pitch, roll, alt, fov)
        assert 0 < int(mask.sum()) < mask.numel()  # some cells masked, some not
        level, _ = _template_cells(feats, yaws, 6, 20.0)
        uv, _ = ground_to_uav_pixel(level, pitch, roll, alt, fov, 48)
        coords = pixel_to_grid(uv, 48, (2, 2)).reshape(3, 7 * 13, 13, 2)
        plain = torch.nn.functional.grid_sample(feats, coords, align_corners=True)
        want = plain.view(3, 4, 7, 13, 13).permute(0, 2, 1, 3, 4) * mask.unsqueeze(2)
        assert torch.equal(got, want)
        w = torch.randn(got.shape, generator=g)
        (g_got,) = torch.autograd.grad((got * w).sum(), feats)
        (g_want,) = torch.autograd.grad((want * w).sum(), feats)
        torch.testing.assert_close(g_got, g_want, rtol=1e-6, atol=1e-6)


class TestUnitChannels:
    def test_equals_torch_normalize_and_its_gradient_float64(self):
        from benchmark.models.matching_ops import unit_channels

        g = torch.Generator().manual_seed(6)
        x = torch.randn(3, 5, 7, 9, generator=g, dtype=torch.float64)
        x[0, :, 0, 0] = 0.0  # a zero cell stays zero (the norm floored, as normalize does)
        want = torch.nn.functional.normalize(x, dim=1)
        torch.testing.assert_close(unit_channels(x), want, rtol=1e-14, atol=1e-14)
        assert torch.autograd.gradcheck(
            unit_channels, (x[1:, :, 1:4, 1:4].clone().requires_grad_(),)
        )


@pytest.fixture(scope="module")
def flat_scene():
    """A flat 512 m city (textures kept) and its nadir satellite image, 480 x 480 m at 96 px."""
    from benchmark.sim.render import render_satellite
    from benchmark.sim.world import build_city

    city = build_city("oxford", 11, cache_dir=False, size_m=(512.0, 512.0), n_lights=1)
    flat = city.with_rasters(
        height=np.zeros_like(city.height), mat=np.zeros_like(city.mat),
        ground=np.zeros_like(city.ground),
    )  # fmt: skip
    sat = render_satellite(flat, np.array([0.0, 0.0]), height_m=1000.0,
                           footprint_m=(480.0, 480.0), size=96)  # fmt: skip
    return flat, sat


def _raw(img: np.ndarray) -> torch.Tensor:
    """Raw image channels as features: RGB in [0, 1] minus the image mean, (1, 3, H, W)."""
    x = torch.from_numpy(img.astype(np.float64)).permute(2, 0, 1)[None] / 255.0
    return x - x.mean(dim=(2, 3), keepdim=True)


# (yaw deg, dE m, dN m, pitch deg): poses whose view sees enough ground for raw grey levels.
POSES = [(100.0, 30.0, -20.0, -40.0), (10.0, 0.0, 60.0, -50.0), (280.0, -40.0, 10.0, -45.0)]


class TestVolumeOnRenderedPair:
    @pytest.mark.parametrize("pose", POSES)
    def test_peaks_at_the_true_yaw_and_position(self, flat_scene, pose):
        from benchmark.sim.camera import Camera
        from benchmark.sim.render import render_uav

        city, sat = flat_scene
        yaw_deg, de, dn, pitch_deg = pose
        yaw, pitch, roll, alt = math.radians(yaw_deg), math.radians(pitch_deg), 0.05, 80.0
        img = render_uav(city, np.array([de, dn, alt]), yaw, pitch, roll, Camera.square(96, 60.0))
        enc = matching(
            input_size=96, n_yaw=36, cell_m=10.0, search_m=80.0, template_m=120.0
        ).double()
        t64 = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
        with torch.no_grad():
            fov, fp = t64(math.radians(60.0)), t64([480.0, 480.0])
            lv = enc.match(_raw(img), _raw(sat), t64(pitch), t64(roll), t64(alt), fov, fp,
                           (1, 1), (1, 1))  # fmt: skip
        assert lv.shape == (1, 36, 17, 17)
        assert float(lv.exp().sum()) == pytest.approx(1.0, abs=1e-9)
        y, e, n = enc.decode_volume(lv)
        err = abs((math.degrees(float(y)) - yaw_deg + 180.0) % 360.0 - 180.0)
        assert err <= 5.0 + 1e-6  # the true yaw's bin
        assert (float(e), float(n)) == (de, dn)
        # The NLL term: lower at the true pose than at a wrong yaw or a wrong position.
        true = float(enc.volume_nll(lv, t64(yaw), t64(de), t64(dn)))
        assert true < float(enc.volume_nll(lv, t64(yaw + math.pi / 2), t64(de), t64(dn))) - 3
        assert true < float(enc.volume_nll(lv, t64(yaw), t64(de + 60.0), t64(dn - 40.0))) - 3

    def test_the_default_correlation_gives_todays_volume(self, flat_scene):
        """The rendered pair's pose volume with the default correlation (``xdft``): equal to
        the direct correlation's in float64 and to the 2-D DFT's (the default before issue
        40) in float32, within 1e-4 in log-probability, where the volume holds its mass."""
        from benchmark.sim.camera import Camera
        from benchmark.sim.render import render_uav

        city, sat = flat_scene
        yaw_deg, de, dn, pitch_deg = POSES[0]
        img = render_uav(city, np.array([de, dn, 80.0]), math.radians(yaw_deg),
                         math.radians(pitch_deg), 0.05, Camera.square(96, 60.0))  # fmt: skip
        volumes = {}
        for dtype in (torch.float64, torch.float32):
            for method in ("xdft", "conv", "dft"):
                enc = matching(input_size=96, n_yaw=36, cell_m=10.0, search_m=80.0,
                               template_m=120.0, correlation=method).to(dtype)  # fmt: skip
                t = lambda *v, d=dtype: torch.tensor(v, dtype=d)  # noqa: E731
                with torch.no_grad():
                    volumes[method, dtype] = enc.match(
                        _raw(img).to(dtype), _raw(sat).to(dtype), t(math.radians(pitch_deg)),
                        t(0.05), t(80.0), t(math.radians(60.0)), t([480.0, 480.0]), (1, 1), (1, 1),
                    )  # fmt: skip
        f64, f32 = torch.float64, torch.float32
        torch.testing.assert_close(volumes["xdft", f64], volumes["conv", f64], rtol=0, atol=1e-9)
        held = volumes["dft", f32] > -20.0  # where the mass is (e^-20 of the peak is nothing)
        diff = (volumes["xdft", f32] - volumes["dft", f32]).abs()
        assert float(diff[held].max()) <= 1e-4
        assert (
            float((volumes["xdft", f32].double() - volumes["conv", f64]).abs()[held].max()) <= 1e-4
        )


class TestVolumeNll:
    def test_delta_volume_and_smoothing(self):
        enc = matching(input_size=32, n_yaw=8, cell_m=10.0, search_m=20.0, template_m=20.0)
        lv = torch.full((1, 8, 5, 5), -30.0)
        lv[0, 2, 1, 3] = 0.0  # nearly all mass at yaw 90 deg, N = +10 m, E = +10 m
        lv = torch.log_softmax(lv.flatten(1), 1).view_as(lv)
        at = enc.volume_nll(lv, torch.tensor([math.pi / 2]), torch.tensor([10.0]),
                            torch.tensor([10.0]))  # fmt: skip
        off = enc.volume_nll(lv, torch.tensor([math.pi / 2]), torch.tensor([10.0]),
                             torch.tensor([-10.0]))  # fmt: skip
        # smoothing 0.5 cell / bin: the target puts w = 1 / (1 + 2 exp(-2))^3 on the true cell
        # and the rest on its 6 neighbours at -30 (and beyond), so NLL ~ 30 (1 - w).
        w = 1 / (1 + 2 * math.exp(-2)) ** 3
        assert float(at) == pytest.approx(30 * (1 - w), rel=0.02)
        assert float(off) > 29.0


class TestMatchingEncoderContract:
    @pytest.mark.parametrize("b", [1, 8])
    @pytest.mark.parametrize("protocol", ["vision_only", "gravity_aided"])
    @pytest.mark.parametrize("planes", [0, 4])
    def test_shapes_and_loss_keys(self, b, protocol, planes):
        torch.manual_seed(0)
        model = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options={"protocol": protocol,
                                              "height_planes": planes})  # fmt: skip
        assert isinstance(model.encoder, PairEncoder)
        f = model.encoder.feature_dim
        assert model.attitude_head.in_features == f == len(model.encoder.feature_names)
        uav, sat = torch.rand(b, 3, 32, 32), torch.rand(b, 3, 32, 32)
        R, T = _labels(b)
        for train in (True, False):
            model.train(train)
            out = model(uav, sat, torch.arange(b), context=_context(b))
            lv = out.encoder["log_volume"]
            assert lv.shape[:2] == (b, 36) and out.encoder["gravity"].shape == (b, 3)
            terms = model.loss(out, R, T)
            assert {"total", "att", "tran", "enc", "enc_volume", "enc_gravity"} <= set(terms)
            assert all(torch.isfinite(v) for v in terms.values())
            R_hat, T_hat = model.decode(out)
            assert R_hat.shape == (b, 3, 3) and T_hat.shape == (b, 3)
        model.train()
        model.loss(model(uav, sat, None, context=_context(b)), R, T)["total"].backward()
        grads = [p.grad for p in model.encoder.parameters()]
        assert all(g is not None and torch.isfinite(g).all() for g in grads)

    def test_shared_satellite_is_exact(self):
        torch.manual_seed(0)
        model = create_model(encoder="matching", variant="/", input_size=32).eval()
        uav, one = torch.rand(4, 3, 32, 32), torch.rand(1, 3, 32, 32)
        sat = one.expand(4, 3, 32, 32).clone()
        ctx = _context(4)
        a = model(uav, sat, torch.zeros(4, dtype=torch.int64), context=ctx)
        b = model(uav, sat, None, context=ctx)
        torch.testing.assert_close(a.encoder["log_volume"], b.encoder["log_volume"])

    def test_weight_zero_is_heads_only(self):
        torch.manual_seed(0)
        model = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options={"volume_nll_weight": 0.0,
                                              "gravity_weight": 0.0})  # fmt: skip
        R, T = _labels(2)
        out = model(torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32), context=_context(2))
        terms = model.loss(out, R, T)
        assert float(terms["enc"]) == 0.0 and float(terms["enc_volume"]) > 0
        torch.testing.assert_close(terms["total"], terms["att"] + terms["tran"])

    def test_bad_options_and_context(self):
        with pytest.raises(ValueError, match="variant"):
            create_model(encoder="matching", input_size=32)  # the default variant is a-f
        with pytest.raises(ValueError, match="protocol"):
            create_model(encoder="matching", variant="/", input_size=32,
                         encoder_options={"protocol": "imu"})  # fmt: skip
        model = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options={"protocol": "gravity_aided"})  # fmt: skip
        with pytest.raises(ValueError, match="prior_attitude"):
            ctx = _context(2)
            del ctx["prior_attitude"]
            model(torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32), context=ctx)
        with pytest.raises(ValueError, match="sat_footprint_m"):
            ctx = _context(2)
            ctx["sat_footprint_m"] = torch.ones(2)
            model(torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32), context=ctx)

    def test_height_planes_start_from_the_flat_view_and_keep_the_default(self):
        # Without the option the encoder has the parameters (names, order, seeded values) it
        # had before the option existed; with it the only new ones are the plane logits, and
        # the untrained logits give every pixel the same plane distribution (ground ~0.77).
        torch.manual_seed(0)
        flat = create_model(encoder="matching", variant="/", input_size=32)
        torch.manual_seed(0)
        planes = create_model(encoder="matching", variant="/", input_size=32,
                              encoder_options={"height_planes": 6})  # fmt: skip
        a, b = dict(flat.encoder.named_parameters()), dict(planes.encoder.named_parameters())
        assert set(b) - set(a) == {"plane_logits.weight", "plane_logits.bias"}
        for name, value in a.items():
            torch.testing.assert_close(b[name], value, rtol=0, atol=0)
        q = torch.softmax(planes.encoder.plane_logits.bias, 0)
        assert float(q[0]) == pytest.approx(math.exp(3) / (math.exp(3) + 6))
        with pytest.raises(ValueError, match="height_planes"):
            create_model(encoder="matching", variant="/", input_size=32,
                         encoder_options={"height_planes": 1})  # fmt: skip

    def test_protocol_is_part_of_the_config(self):
        from benchmark.models import ModelConfig

        a = ModelConfig(encoder="matching", variant="/")
        b = ModelConfig(encoder="matching", variant="/",
                        encoder_options={"protocol": "gravity_aided"})  # fmt: skip
        assert a.encoder_options == {} and hash(a) != hash(b)


@pytest.mark.parametrize("head", list_heads("attitude"))
class TestEveryAttitudeHead:
    def test_builds_and_runs_on_the_matching_encoder(self, head):
        torch.manual_seed(0)
        model = create_model(encoder="matching", variant="/", input_size=32, attitude=head)
        R, T = _labels(3)
        model.translation_head.fit_statistics(T.double())
        out = model(torch.rand(3, 3, 32, 32), torch.rand(3, 3, 32, 32), context=_context(3))
        terms = model.loss(out, R, T)
        terms["total"].backward()
        assert torch.isfinite(terms["total"])
        model.eval()
        with torch.no_grad():
            R_hat, _ = model.decode(model(torch.rand(3, 3, 32, 32), torch.rand(3, 3, 32, 32),
                                          context=_context(3)))  # fmt: skip
        eye = torch.eye(3).expand(3, 3, 3)
        torch.testing.assert_close(R_hat @ R_hat.transpose(1, 2), eye, atol=1e-4, rtol=0)


class TestContextFields:
    def test_items_carry_the_geometry_and_seeded_priors(self, smoke_dataset):
        from benchmark.data.dataset import PRIOR_SIGMA, PairDataset

        ds = PairDataset(smoke_dataset, "standard/train", verify="size")
        sat = ds.sat_table.set_index("sat_index")
        noise = []
        for i in range(len(ds)):
            item, row = ds[i], ds.poses.iloc[i]
            ctx = item["context"]
            assert float(ctx["fov"]) == pytest.approx(
                math.radians(ds.manifest["profile"]["fov_deg"])
            )
            s = sat.loc[int(item["sat_id"])]
            assert ctx["sat_footprint_m"].tolist() == [s.footprint_E_m, s.footprint_N_m]
            assert float(ctx["sat_height_m"]) == s.height_m
            truth = [row.pitch, row.roll, row.dU + row.sat_height_m]
            got = [*ctx["prior_attitude"].tolist(), float(ctx["prior_altitude_m"])]
            noise.append(np.subtract(got, truth) / np.asarray(PRIOR_SIGMA))
        z = np.asarray(noise)
        assert np.all(np.abs(z) < 5) and np.abs(z).mean() > 0.3  # noisy, at the stated scale
        again = PairDataset(smoke_dataset, "standard/train", verify="size")[3]["context"]
        torch.testing.assert_close(again, ds[3]["context"])  # the same priors for every model
        other = PairDataset(smoke_dataset, "frames/train", verify="size")
        a = other[3]["context"]["prior_attitude"] - other[3]["uav_euler"][1:]
        b = ds[3]["context"]["prior_attitude"] - ds[3]["uav_euler"][1:]
        assert not torch.equal(a, b)  # another split, other noise

    def test_swap_serves_the_swapped_images_geometry_and_keeps_the_priors(self, smoke_dataset):
        from benchmark.data.dataset import PairDataset

        true = PairDataset(smoke_dataset, "towns/train", verify="size")
        swap = PairDataset(smoke_dataset, "towns/train", verify="size", satellite="swap")
        sat = swap.sat_table.set_index("sat_index")
        for i in range(len(swap)):
            item = swap[i]
            s = sat.loc[int(item["sat_id"])]
            assert item["context"]["sat_footprint_m"].tolist() == [s.footprint_E_m, s.footprint_N_m]
            torch.testing.assert_close(item["context"]["prior_attitude"],
                                       true[i]["context"]["prior_attitude"])  # fmt: skip


class TestTrainEndToEnd:
    def test_train_and_evaluate_pass_the_context(self, smoke_dataset, tmp_path):
        from benchmark.training.config import load_train_config
        from benchmark.training.pipeline import train_and_evaluate

        cfg = load_train_config(
            None,
            [
                f"data.root={smoke_dataset}", "data.limit_train=8", "data.limit_val=4",
                "data.verify=size", "model.encoder=matching", "model.variant=/",
                "model.encoder_options.protocol=gravity_aided", "model.attitude=re_net_r",
                "model.attitude_options.hidden=32", "optim.name=adam", "optim.batch_size=4",
                "optim.epochs=1", "threads=1",
            ],
        )  # fmt: skip
        done = train_and_evaluate(cfg, tmp_path / "run", ["standard/test"])
        history = done.trained.history[0]
        assert {"train_loss_enc_volume", "train_loss_enc_gravity", "val_loss_enc"} <= set(history)
        assert math.isfinite(done.metrics["standard/test"]["median_dpsi_deg"])


class TestMatchAltitudes:
    """``altitude_offsets_m``: the volume's scale dimension (``match_altitudes``)."""

    @pytest.mark.parametrize("pose", POSES[:2])
    def test_peaks_at_the_true_altitude_yaw_and_position(self, flat_scene, pose):
        # On flat ground a wrong height scales the bird's-eye view about the point below the
        # UAV (by h' / h), so the raw-pixel match scores best at the height it was rendered at.
        from benchmark.sim.camera import Camera
        from benchmark.sim.render import render_uav

        city, sat = flat_scene
        yaw_deg, de, dn, pitch_deg = pose
        yaw, pitch, roll, alt = math.radians(yaw_deg), math.radians(pitch_deg), 0.05, 80.0
        img = render_uav(city, np.array([de, dn, alt]), yaw, pitch, roll, Camera.square(96, 60.0))
        enc = matching(input_size=96, n_yaw=36, cell_m=10.0, search_m=80.0, template_m=120.0,
                       altitude_offsets_m=(-24.0, 0.0, 24.0)).double()  # fmt: skip
        t64 = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
        altitudes = t64([56.0, 80.0, 104.0])  # (1, 3)
        with torch.no_grad():
            fov, fp = t64(math.radians(60.0)), t64([480.0, 480.0])
            joint = enc.match_altitudes(_raw(img), _raw(sat), t64(pitch), t64(roll), altitudes,
                                        fov, fp, (1, 1), (1, 1))  # fmt: skip
        assert joint.shape == (1, 3, 36, 17, 17)
        assert float(joint.exp().sum()) == pytest.approx(1.0, abs=1e-9)
        posterior = joint.exp().sum(dim=(2, 3, 4))[0]  # (S,)
        assert int(posterior.argmax()) == 1 and float(posterior[1]) > 0.9
        y, e, n = enc.decode_volume(torch.logsumexp(joint, 1))
        assert abs((math.degrees(float(y)) - yaw_deg + 180.0) % 360.0 - 180.0) <= 5.0 + 1e-6
        assert (float(e), float(n)) == (de, dn)
        # The joint NLL prefers the true height to a wrong one by a clear margin.
        args = (t64(yaw), t64(de), t64(dn))
        at = float(enc.volume_nll_altitudes(joint, altitudes, *args, t64(80.0)))
        assert at < float(enc.volume_nll_altitudes(joint, altitudes, *args, t64(56.0))) - 1

    def test_one_altitude_twice_is_match(self):
        # Two identical hypotheses split each cell's mass in half: the joint is match() - log 2
        # and its marginal is match() itself (an independent path: no altitude code in match).
        g = torch.Generator().manual_seed(3)
        enc = matching(input_size=32, n_yaw=8, cell_m=20.0, search_m=60.0, template_m=60.0,
                       altitude_offsets_m=(-5.0, 5.0)).double()  # fmt: skip
        uav = torch.randn(2, 4, 16, 16, generator=g, dtype=torch.float64)
        sat = torch.randn(2, 4, 16, 32, generator=g, dtype=torch.float64)
        pitch = torch.tensor([-0.6, -0.5], dtype=torch.float64)
        roll = torch.tensor([0.02, -0.04], dtype=torch.float64)
        alt = torch.tensor([85.0, 95.0], dtype=torch.float64)
        fov = torch.full((2,), 1.0, dtype=torch.float64)
        fp = torch.tensor([[2000.0, 1000.0]], dtype=torch.float64).expand(2, 2)
        single = enc.match(uav, sat, pitch, roll, alt, fov, fp)
        joint = enc.match_altitudes(uav, sat, pitch, roll, torch.stack([alt, alt], 1), fov, fp)
        torch.testing.assert_close(joint[:, 0], single - math.log(2.0))
        torch.testing.assert_close(torch.logsumexp(joint, 1), single)

    def test_gradcheck_float64(self):
        g = torch.Generator().manual_seed(4)
        enc = matching(input_size=24, n_yaw=4, cell_m=30.0, search_m=30.0, template_m=30.0,
                       correlation="fft", altitude_offsets_m=(-8.0, 8.0))  # fmt: skip
        enc = enc.double()
        uav = torch.randn(1, 2, 12, 12, generator=g, dtype=torch.float64, requires_grad=True)
        sat = torch.randn(1, 2, 12, 24, generator=g, dtype=torch.float64, requires_grad=True)
        alts = torch.tensor([[82.0, 98.0]], dtype=torch.float64, requires_grad=True)
        t64 = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731

        def joint(u, s, a):
            return enc.match_altitudes(u, s, t64(-0.6), t64(0.03), a, t64(1.0),
                                       t64([2000.0, 1000.0]))  # fmt: skip

        assert torch.autograd.gradcheck(joint, (uav, sat, alts), atol=1e-6)


class TestVolumeNllAltitudes:
    def test_against_a_direct_sum(self):
        # The target written out cell by cell (numpy, float64): exp(-dyaw^2 / 2 sy^2 - dN^2 /
        # 2 sp^2 - dE^2 / 2 sp^2 - (h_s - h)^2 / 2 sa^2), normalised over every cell.
        enc = matching(input_size=32, n_yaw=8, cell_m=10.0, search_m=20.0, template_m=20.0,
                       altitude_offsets_m=(-10.0, 0.0, 10.0)).double()  # fmt: skip
        g = torch.Generator().manual_seed(5)
        joint = torch.log_softmax(torch.randn(1, 3 * 8 * 25, generator=g, dtype=torch.float64), 1)
        joint = joint.view(1, 3, 8, 5, 5)
        alts = torch.tensor([[86.0, 96.0, 106.0]], dtype=torch.float64)
        yaw, east, north, h = 1.0, 7.0, -12.0, 99.0
        args = [torch.tensor([v], dtype=torch.float64) for v in (yaw, east, north, h)]
        got = float(enc.volume_nll_altitudes(joint, alts, *args))
        lj = joint[0].numpy()
        w = np.zeros_like(lj)
        sy, sp, sa = 0.5 * 2 * math.pi / 8, 0.5 * 10.0, 0.5 * 10.0
        for s in range(3):
            for k in range(8):
                d = (k * 2 * math.pi / 8 - yaw + math.pi) % (2 * math.pi) - math.pi
                for r in range(5):
                    for c in range(5):
                        n_m, e_m = (2 - r) * 10.0, (c - 2) * 10.0  # row 0 is north
                        w[s, k, r, c] = math.exp(
                            -0.5 * (d / sy) ** 2 - 0.5 * ((n_m - north) / sp) ** 2
                            - 0.5 * ((e_m - east) / sp) ** 2
                            - 0.5 * ((float(alts[0, s]) - h) / sa) ** 2
                        )  # fmt: skip
        # (the yaw and cell buffers are built in float32: agreement to ~1e-9, not 1e-15)
        assert got == pytest.approx(float(-(w / w.sum() * lj).sum()), rel=1e-7)

    def test_one_hypothesis_is_the_pose_nll(self):
        enc = matching(input_size=32, n_yaw=8, cell_m=10.0, search_m=20.0, template_m=20.0)
        g = torch.Generator().manual_seed(6)
        lv = torch.log_softmax(torch.randn(2, 200, generator=g), 1).view(2, 8, 5, 5)
        args = (torch.tensor([0.4, 3.0]), torch.tensor([5.0, -9.0]), torch.tensor([0.0, 14.0]))
        one = enc.volume_nll_altitudes(lv[:, None], torch.tensor([[90.0], [70.0]]), *args,
                                       torch.tensor([100.0, 60.0]))  # fmt: skip
        torch.testing.assert_close(one, enc.volume_nll(lv, *args))


class TestAltitudeSearchInTheEncoder:
    OFFSETS = (-12.0, 0.0, 12.0)

    @pytest.mark.parametrize("b", [1, 8])
    def test_where_it_searches_shapes_and_loss(self, b):
        torch.manual_seed(0)
        opts = {"protocol": "gravity_aided", "altitude_offsets_m": list(self.OFFSETS)}
        model = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options=opts)  # fmt: skip
        uav, sat, ctx = torch.rand(b, 3, 32, 32), torch.rand(b, 3, 32, 32), _context(b)
        R, T = _labels(b)
        model.train()
        out = model(uav, sat, torch.arange(b), context=ctx)
        joint, alts = out.encoder["log_volume_joint"], out.encoder["altitudes"]
        assert joint.shape[:3] == (b, 3, 36) and alts.shape == (b, 3)
        torch.testing.assert_close(out.encoder["log_volume"], torch.logsumexp(joint, 1))
        # training: around the prior, the centre jittered by at most half a spacing
        centre = alts[:, 1] - ctx["prior_altitude_m"]
        assert bool((centre.abs() <= 6.0 + 1e-4).all())
        torch.testing.assert_close(alts - alts[:, 1:2], torch.tensor([self.OFFSETS]).expand(b, 3))
        terms = model.loss(out, R, T)
        assert all(torch.isfinite(v) for v in terms.values())
        terms["total"].backward()
        assert all(p.grad is not None for p in model.encoder.parameters())
        # gravity-aided evaluation trusts the altimeter: one altitude, the plain match
        model.eval()
        with torch.no_grad():
            out = model(uav, sat, torch.arange(b), context=ctx)
        assert "log_volume_joint" not in out.encoder
        torch.manual_seed(0)
        plain = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options={"protocol": "gravity_aided"}).eval()  # fmt: skip
        plain.load_state_dict(model.state_dict())
        with torch.no_grad():
            ref = plain(uav, sat, torch.arange(b), context=ctx)
        torch.testing.assert_close(out.encoder["log_volume"], ref.encoder["log_volume"])
        # vision-only evaluation searches around the gravity branch's height
        model.encoder.protocol = "vision_only"
        with torch.no_grad():
            out = model(uav, sat, torch.arange(b), context=ctx)
        grav = out.encoder["gravity"][:, 2].clamp(min=5.0)
        torch.testing.assert_close(out.encoder["altitudes"][:, 1], grav)

    def test_options_refused_and_no_new_parameters(self):
        torch.manual_seed(0)
        flat = create_model(encoder="matching", variant="/", input_size=32)
        torch.manual_seed(0)
        search = create_model(encoder="matching", variant="/", input_size=32,
                              encoder_options={"altitude_offsets_m": [-12, 0, 12]})  # fmt: skip
        assert list(flat.state_dict()) == list(search.state_dict())
        for name, value in flat.state_dict().items():
            torch.testing.assert_close(search.state_dict()[name], value, rtol=0, atol=0)
        for bad in ([0.0], [0.0, 0.0], [5.0, -5.0], [0.0, float("nan")]):
            with pytest.raises(ValueError, match="altitude_offsets_m"):
                matching(input_size=32, altitude_offsets_m=tuple(bad))
        with pytest.raises(ValueError, match="height_planes"):
            matching(input_size=32, altitude_offsets_m=(-10.0, 10.0), height_planes=4)


class TestTrainViewNoise:
    """``train_view_noise_deg`` / ``_m``: extra Gaussian noise on the training view's pitch,
    roll and height (the vision-only test view comes from the gravity branch, noisier than the
    sensor priors); evaluation builds the view from the priors untouched."""

    def _used(self, model, b, train):
        enc = model.encoder
        cols = [enc.feature_names.index(n) for n in ("pitch_used", "roll_used", "alt_used")]
        uav, sat, ctx = torch.rand(b, 3, 32, 32), torch.rand(b, 3, 32, 32), _context(b)
        model.train(train)
        with torch.no_grad():
            feats = model.encode_pairs(uav, sat, torch.arange(b), ctx).features
        used = feats[:, cols] / torch.tensor([1.0, 1.0, 0.01])  # the summary's scaling undone
        prior = torch.cat([ctx["prior_attitude"], ctx["prior_altitude_m"][:, None]], 1)
        return used - prior

    def test_training_view_gets_the_stated_noise_and_evaluation_none(self):
        torch.manual_seed(0)
        opts = {"protocol": "gravity_aided", "train_view_noise_deg": 3.0,
                "train_view_noise_m": 10.0}  # fmt: skip
        model = create_model(encoder="matching", variant="/", input_size=32, encoder_options=opts)
        diff = self._used(model, 400, train=True)
        # sample standard deviations of 400 draws: within 15 % of the stated sigmas
        sigma = torch.tensor([math.radians(3.0), math.radians(3.0), 10.0])
        torch.testing.assert_close(diff.std(0), sigma, rtol=0.15, atol=0)
        assert float(diff.mean(0)[2].abs()) < 3 * 10.0 / 20  # 3 standard errors
        torch.testing.assert_close(self._used(model, 8, train=False), torch.zeros(8, 3),
                                   rtol=0, atol=1e-4)  # fmt: skip

    def test_off_by_default_and_negative_refused(self):
        torch.manual_seed(0)
        model = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options={"protocol": "gravity_aided"})  # fmt: skip
        torch.testing.assert_close(self._used(model, 8, train=True), torch.zeros(8, 3),
                                   rtol=0, atol=1e-4)  # fmt: skip
        for name in ("train_view_noise_deg", "train_view_noise_m"):
            with pytest.raises(ValueError, match=name):
                matching(input_size=32, **{name: -1.0})
