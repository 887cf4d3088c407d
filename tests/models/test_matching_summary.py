"""``MatchingEncoder._summary``: every feature against a naive numpy computation (loops, no
torch) on random log-volumes, by name (``feature_names``), with arg-maxes placed inside, on the
border and in the corner of the searched square and on the first and last yaw bins (wrap)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from benchmark.models.matching import MatchingEncoder, matching


def _encoder() -> MatchingEncoder:
    # 12 yaw bins, P = 2 * 3 + 1 = 7 positions per axis (search 300 m of 100 m cells).
    return matching(input_size=32, n_yaw=12, cell_m=100.0, search_m=300.0, template_m=200.0)


def _log_volume(b: int, k: int, p: int, peaks: list[tuple[int, int, int]], seed: int):
    """``(B, K, P, P)`` float64 log-probabilities: random scores, plus a peak at ``peaks[i]``
    (yaw bin, row, column) in pair ``i`` (sharp enough to be the joint and marginal arg-max)."""
    rng = np.random.default_rng(seed)
    scores = rng.normal(0.0, 1.0, (b, k, p, p))
    for i, (yk, r, c) in enumerate(peaks):
        scores[i, yk, r, c] += 6.0
        scores[i, (yk + 1) % k, r, c] += 3.0  # an uneven neighbour: the refinement moves
    scores -= scores.reshape(b, -1).max(1)[:, None, None, None]
    log_z = np.log(np.exp(scores).reshape(b, -1).sum(1))
    return scores - log_z[:, None, None, None]


def _naive(enc: MatchingEncoder, lv: np.ndarray, predicted, used, sat_height) -> list[dict]:
    """The features of each pair, computed with explicit loops from their definitions."""
    k, p = lv.shape[1], lv.shape[2]
    n = enc.search_cells
    cell = enc.cell_m
    yaws = [2 * math.pi * j / k for j in range(k)]
    east = [(c - n) * cell for c in range(p)]  # column c -> dE
    north = [(n - r) * cell for r in range(p)]  # row r (north first) -> dN
    scale = n * cell
    out = []
    for b in range(lv.shape[0]):
        prob = np.exp(lv[b])
        yaw_m = [sum(prob[j, r, c] for r in range(p) for c in range(p)) for j in range(k)]
        pos = [[sum(prob[j, r, c] for j in range(k)) for c in range(p)] for r in range(p)]
        pe = [sum(pos[r][c] for r in range(p)) for c in range(p)]
        pn = [sum(pos[r][c] for c in range(p)) for r in range(p)]
        e_mean = sum(w * x for w, x in zip(pe, east, strict=True))
        n_mean = sum(w * x for w, x in zip(pn, north, strict=True))
        e_var = sum(w * (x - e_mean) ** 2 for w, x in zip(pe, east, strict=True))
        n_var = sum(w * (x - n_mean) ** 2 for w, x in zip(pn, north, strict=True))
        # Arg-max of the position marginal; of the joint volume for the yaw refinement.
        r_arg, c_arg = max(
            ((r, c) for r in range(p) for c in range(p)), key=lambda t: pos[t[0]][t[1]]
        )
        j_arg = max(
            ((j, r, c) for j in range(k) for r in range(p) for c in range(p)),
            key=lambda t: lv[b][t],
        )[0]
        nb = {d: yaw_m[(j_arg + d) % k] for d in (-1, 0, 1)}
        nb_mass = sum(nb.values())
        yaw_ref = yaws[j_arg] + (2 * math.pi / k) * sum(d * w for d, w in nb.items()) / nb_mass
        block = [
            pos[r][c]
            for r in range(r_arg - 1, r_arg + 2)
            for c in range(c_arg - 1, c_arg + 2)
            if 0 <= r < p and 0 <= c < p  # cells beyond the border hold no mass
        ]
        pos_mass = sum(block)
        entropy = -sum(prob[idx] * lv[b][idx] for idx in np.ndindex(*prob.shape))
        e_arg, n_arg = east[c_arg] / scale, north[r_arg] / scale
        pr, us = predicted[b], used[b]
        out.append({
            "yaw_cos": sum(w * math.cos(y) for w, y in zip(yaw_m, yaws, strict=True)),
            "yaw_sin": sum(w * math.sin(y) for w, y in zip(yaw_m, yaws, strict=True)),
            "E_mean": e_mean / scale,
            "N_mean": n_mean / scale,
            "E_std": math.sqrt(e_var + 1e-6) / scale,
            "N_std": math.sqrt(n_var + 1e-6) / scale,
            "E_argmax": e_arg,
            "N_argmax": n_arg,
            "peak_logp": lv[b].max() / 10.0,
            "entropy": entropy / math.log(k * p * p),
            "pitch_pred": pr[0], "roll_pred": pr[1], "alt_pred": pr[2] / 100.0,
            "pitch_used": us[0], "roll_used": us[1], "alt_used": us[2] / 100.0,
            "dU_est_km": (us[2] - sat_height[b]) / 1000.0,
            "sat_height_km": sat_height[b] / 1000.0,
            "yaw_argmax_cos": math.cos(yaw_ref),
            "yaw_argmax_sin": math.sin(yaw_ref),
            "yaw_peak_mass": nb_mass,
            "pos_peak_mass": pos_mass,
            "yaw_argmax_cos_w": math.cos(yaw_ref) * nb_mass,
            "yaw_argmax_sin_w": math.sin(yaw_ref) * nb_mass,
            "E_argmax_w": e_arg * pos_mass,
            "N_argmax_w": n_arg * pos_mass,
        })  # fmt: skip
    return out


# (yaw bin, row, column) of the planted peak of each pair: inside; first row (north edge) at the
# last yaw bin (its +1 neighbour wraps to bin 0); the south-east corner at bin 0 (its -1
# neighbour wraps to the last bin); the west edge.
PEAKS = [(5, 3, 2), (11, 0, 4), (0, 6, 6), (7, 4, 0)]


@pytest.mark.parametrize("seed", [0, 1])
def test_summary_features_match_a_naive_computation(seed):
    enc = _encoder().double()
    k, p = enc.n_yaw, 2 * enc.search_cells + 1
    lv = _log_volume(len(PEAKS), k, p, PEAKS, seed)
    rng = np.random.default_rng(100 + seed)
    b = len(PEAKS)
    predicted = np.column_stack([rng.uniform(-0.8, 0, b), rng.uniform(-0.2, 0.2, b),
                                 rng.uniform(70, 120, b)])  # fmt: skip
    used = predicted + rng.normal(0, [0.02, 0.02, 2.0], (b, 3))
    sat_height = rng.uniform(600, 1400, b)
    got = enc._summary(*(torch.from_numpy(x) for x in (lv, predicted, used, sat_height)))
    assert got.shape == (b, enc.feature_dim) and enc.feature_dim == len(enc.feature_names)
    want = _naive(enc, lv, predicted, used, sat_height)
    assert set(want[0]) == set(enc.feature_names), "a feature without a reference"
    # Tolerance: the encoder's yaw buffer holds float32 angles (rounded at ~1e-7 rad); the rest
    # is float64 arithmetic in both.
    n = enc.search_cells
    for i in range(b):
        _, r, c = PEAKS[i]  # the planted peak is the arg-max (the border cases are exercised)
        assert (want[i]["E_argmax"], want[i]["N_argmax"]) == ((c - n) / n, (n - r) / n)
        for j, name in enumerate(enc.feature_names):
            assert float(got[i, j]) == pytest.approx(want[i][name], rel=1e-6, abs=1e-7), (
                f"pair {i} (peak {PEAKS[i]}), feature {name}"
            )


def test_border_block_has_fewer_cells_and_refinement_wraps():
    """The 3 x 3 mass at a corner sums 4 cells (no wrap-around to the opposite side), and the
    refined yaw at bin 0 moves towards the last bin when that neighbour is heavier."""
    enc = _encoder().double()
    k, p = enc.n_yaw, 2 * enc.search_cells + 1
    lv = np.full((1, k, p, p), -50.0)
    lv[0, 0, 0, 0] = 0.0  # the corner, yaw bin 0
    lv[0, k - 1, 0, 0] = math.log(0.5)  # the last bin (wraps to -1 from bin 0)
    lv[0, 0, p - 1, p - 1] = math.log(0.25)  # the opposite corner: outside the 3 x 3 block
    lv = lv - np.log(np.exp(lv).sum())
    feats = enc._summary(torch.from_numpy(lv), *(torch.zeros(1, 3, dtype=torch.float64),) * 2,
                         torch.full((1,), 1000.0, dtype=torch.float64))  # fmt: skip
    f = dict(zip(enc.feature_names, feats[0].tolist(), strict=True))
    total = 1.0 + 0.5 + 0.25 + (k * p * p - 3) * math.exp(-50.0)
    assert f["pos_peak_mass"] == pytest.approx((1.5 + k * 3 * math.exp(-50.0)) / total, rel=1e-9)
    yaw = math.atan2(f["yaw_argmax_sin"], f["yaw_argmax_cos"])
    # Yaw marginal: bin 0 holds 1 + 0.25 (both corners), the last bin 0.5: -0.5 / 1.75 bins.
    assert yaw == pytest.approx(-(2 * math.pi / k) * 0.5 / 1.75, rel=1e-6)
