"""``benchmark.models.matching_pixels``: the fixed grey/gradient channels against OpenCV's Sobel,
and the photometric jitter's promises (exact labels need untouched geometry)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from benchmark.models import create_model
from benchmark.models.matching_pixels import (
    denormalize,
    grey_gradient,
    normalize,
    photometric_jitter,
)


def reference_grey_gradient(img: np.ndarray, pool: tuple[int, int]) -> np.ndarray:
    """OpenCV: grey level, Sobel (3 x 3, replicated border) / 8, magnitude, block means,
    standardised with the sample standard deviation."""
    grey = img.mean(0)
    gx = cv2.Sobel(grey, cv2.CV_64F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_64F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    out = []
    for f in (grey, np.sqrt(gx**2 + gy**2 + 1e-12)):
        h, w = f.shape[0] // pool[1], f.shape[1] // pool[0]
        f = f[: h * pool[1], : w * pool[0]].reshape(h, pool[1], w, pool[0]).mean((1, 3))
        out.append((f - f.mean()) / max(f.std(ddof=1), 1e-3))
    return np.stack(out)


class TestGreyGradient:
    @pytest.mark.parametrize("pool", [(2, 2), (1, 2)])
    def test_against_opencv(self, pool):
        rng = np.random.default_rng(0)
        imgs = rng.random((2, 3, 24, 32))
        got = grey_gradient(torch.from_numpy(imgs), pool).numpy()
        for b in range(2):
            np.testing.assert_allclose(got[b], reference_grey_gradient(imgs[b], pool), atol=1e-10)

    @pytest.mark.parametrize("batch", [1, 8])
    def test_shapes(self, batch):
        assert grey_gradient(torch.rand(batch, 3, 16, 16), (1, 2)).shape == (batch, 2, 8, 16)

    def test_invariant_to_brightness_and_contrast(self):
        """Standardised per image: a * x + b (same for every channel) changes nothing, so a
        city style's overall brightness does not reach the correlation."""
        x = torch.rand(2, 3, 16, 16, dtype=torch.float64)
        torch.testing.assert_close(grey_gradient(0.3 * x + 0.2, (2, 2)), grey_gradient(x, (2, 2)))

    def test_flat_image_gives_zeros(self):
        assert torch.equal(
            grey_gradient(torch.full((1, 3, 8, 8), 0.5), (2, 2)), torch.zeros(1, 2, 4, 4)
        )

    def test_gradcheck_float64(self):
        x = torch.rand(1, 3, 8, 8, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda t: grey_gradient(t, (2, 2)), (x,))


class TestPhotometricJitter:
    def test_strength_zero_is_identity(self):
        x = torch.rand(2, 3, 8, 8)
        assert photometric_jitter(x, 0.0) is x

    def test_range_shape_and_seeded(self):
        x = torch.rand(4, 3, 16, 16)
        a = photometric_jitter(x, 1.0, torch.Generator().manual_seed(1))
        b = photometric_jitter(x, 1.0, torch.Generator().manual_seed(1))
        assert a.shape == x.shape and torch.equal(a, b)
        assert a.min() >= 0 and a.max() <= 1
        assert not torch.allclose(a, x)

    def test_geometry_untouched(self):
        """Colours change, places do not: an edge stays where it was (labels stay exact)."""
        x = torch.zeros(8, 3, 16, 16)
        x[:, :, :, 9:] = 0.8  # a vertical edge between columns 8 and 9
        y = photometric_jitter(x, 2.0, torch.Generator().manual_seed(0))
        step = (y[:, :, :, 1:] - y[:, :, :, :-1]).abs().amax((1, 2))  # (8, 15) per column pair
        assert torch.equal(step.argmax(1), torch.full((8,), 8))
        assert (step[:, :8].amax(1) == 0).all() and (step[:, 9:].amax(1) == 0).all()

    def test_images_drawn_independently(self):
        x = torch.full((2, 3, 4, 4), 0.4)
        y = photometric_jitter(x, 1.0, torch.Generator().manual_seed(3))
        assert not torch.allclose(y[0], y[1])

    def test_normalize_round_trip(self):
        x = torch.rand(2, 3, 4, 4)
        torch.testing.assert_close(denormalize(normalize(x)), x)


class TestMatchingEncoderOptions:
    def build(self, **options):
        torch.manual_seed(0)
        return create_model(encoder="matching", variant="/", input_size=32, encoder_options=options)

    def test_defaults_add_no_parameter(self):
        """Models trained before the options existed load and give the same numbers."""
        plain, with_options = self.build(), self.build(grey_gradient=True)
        extra = set(with_options.state_dict()) - set(plain.state_dict())
        assert extra == {"encoder.grey_gradient_log_gain"}
        for key, value in plain.state_dict().items():
            assert torch.equal(value, with_options.state_dict()[key]), key

    def test_jitter_only_in_training(self):
        plain, jittered = self.build(), self.build(photometric=1.0)
        uav, sat = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
        plain.eval(), jittered.eval()
        with torch.no_grad():
            a, b = plain(uav, sat), jittered(uav, sat)
        torch.testing.assert_close(a.attitude, b.attitude, rtol=0, atol=0)
        jittered.train()
        with torch.no_grad():
            c = jittered(uav, sat)
        assert not torch.allclose(a.attitude, c.attitude)

    def test_negative_photometric_named(self):
        with pytest.raises(ValueError, match="photometric"):
            self.build(photometric=-1.0)
