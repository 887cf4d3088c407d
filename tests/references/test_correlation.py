"""The references' correlations against independent implementations (scipy, OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import stats

from benchmark.references.oracle import masked_ncc
from benchmark.references.template import _standardise, masked_ncc_map


class TestMaskedNcc:
    def test_equals_pearson_on_the_valid_entries(self):
        rng = np.random.default_rng(1)
        a = rng.uniform(0, 255, 200)
        b = a[None, :] * rng.uniform(0.5, 2.0, (3, 1)) + rng.normal(0, 40, (3, 200))
        valid = rng.random((3, 200)) > 0.3
        got = masked_ncc(a, b, valid, min_count=3)
        for k in range(3):
            want = stats.pearsonr(a[valid[k]], b[k, valid[k]]).statistic
            assert got[k] == pytest.approx(want, abs=1e-9)

    def test_too_few_entries_score_minus_infinity(self):
        a = np.arange(10.0)
        valid = np.zeros((1, 10), bool)
        valid[0, :2] = True
        assert masked_ncc(a, a[None], valid, min_count=3)[0] == -np.inf


class TestMaskedNccMap:
    @pytest.mark.parametrize("k", [1, 3])
    def test_equals_cv2_masked_ccoeff_normed_on_the_mean_padded_image(self, k):
        rng = np.random.default_rng(k)
        image = _standardise(rng.uniform(0, 255, (37, 45)).astype(np.float32))
        th, tw = 11, 9
        templates = rng.uniform(0, 255, (k, th, tw)).astype(np.float32)
        masks = (rng.random((k, th, tw)) > 0.35).astype(np.float32)
        got = masked_ncc_map(image, templates, masks)
        assert got.shape == (k, 37, 45)
        # Centred templates: placement (y, x) puts cell (i, j) on pixel (y + i - 5, x + j - 4);
        # OpenCV's top-left placement on the image padded by (5, 4) with its mean (0).
        padded = cv2.copyMakeBorder(image, th // 2, th // 2, tw // 2, tw // 2,
                                    cv2.BORDER_CONSTANT, value=0.0)  # fmt: skip
        for j in range(k):
            want = cv2.matchTemplate(padded, templates[j], cv2.TM_CCOEFF_NORMED, mask=masks[j])
            assert want.shape == (37, 45)
            assert np.allclose(got[j], want, atol=1e-4)

    def test_peak_at_the_true_placement(self):
        rng = np.random.default_rng(7)
        image = _standardise(rng.uniform(0, 255, (40, 40)).astype(np.float32))
        templ = image[10:21, 20:29].copy()[None]  # centre cell (5, 4) -> pixel (15, 24)
        mask = np.ones_like(templ)
        mask[0, :3, :3] = 0.0
        got = masked_ncc_map(image, templ, mask)
        assert np.unravel_index(np.argmax(got[0]), got[0].shape) == (15, 24)
        assert got[0, 15, 24] == pytest.approx(1.0, abs=1e-5)
