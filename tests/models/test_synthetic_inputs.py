"""``synthetic_inputs``: synthetic labels and context in the dataset's ranges, consistent with each
other; ``model-info`` feeds them to a pair encoder (gravity-aided needs them) and refuses bf16 as
training does on a CPU without native bf16."""

from __future__ import annotations

import math

import pytest
import torch

from benchmark.cli import main
from benchmark.data.dataset import CONTEXT_KEYS
from benchmark.data.dataset import PRIOR_SIGMA as DATASET_PRIOR_SIGMA
from benchmark.geometry import SAT_R_N, rotmat_to_euler
from benchmark.models.precision_support import ALLOW_SLOW_BF16_ENV
from benchmark.models.synthetic_inputs import PRIOR_SIGMA, synthetic_labels
from tests.cpu_kinds import AVX2_ONLY, fake_cpu

MATCHING = ["model-info", "--encoder", "matching", "--variant", "/", "--size", "32"]
MATCHING += ["--repeats", "1", "--warmup", "0"]


def test_labels_and_context_agree_and_stay_in_the_dataset_ranges():
    assert PRIOR_SIGMA == DATASET_PRIOR_SIGMA
    R, T, ctx = synthetic_labels(4000)
    assert set(ctx) == set(CONTEXT_KEYS) and R.dtype == T.dtype == torch.float32
    assert all(v.dtype == torch.float32 and v.shape[0] == 4000 for v in ctx.values())
    assert torch.allclose(torch.linalg.det(R), torch.ones(4000), atol=1e-5)
    # Euler angles of R_uav^n = R_uav^sat R_sat^n (Eq. 2), read back independently.
    yaw, pitch, roll = rotmat_to_euler(R.double() @ SAT_R_N)
    assert yaw.min() < -3.0 and yaw.max() > 3.0  # the whole circle
    assert -math.radians(50) - 1e-6 <= pitch.min() and pitch.max() <= 1e-6
    assert roll.abs().max() <= math.radians(10) + 1e-6
    height = T[:, 2] + ctx["sat_height_m"]
    assert 80 - 1e-3 <= height.min() and height.max() <= 120 + 1e-3
    assert T[:, :2].abs().max() <= 380 + 1e-3
    # Priors = truth + noise of PRIOR_SIGMA (sample standard deviations within 5 %).
    noise = torch.cat([ctx["prior_attitude"] - torch.stack([pitch, roll], 1).float(),
                       (ctx["prior_altitude_m"] - height)[:, None]], 1)  # fmt: skip
    assert noise.std(0).tolist() == pytest.approx(list(PRIOR_SIGMA), rel=0.05)
    assert torch.equal(ctx["sat_footprint_m"][0], torch.tensor([2000.0, 1000.0]))
    assert float(ctx["fov"][0]) == pytest.approx(math.radians(60.0))
    again = synthetic_labels(4000)
    assert torch.equal(again[0], R) and torch.equal(again[1], T)


def test_model_info_runs_a_gravity_aided_matching_encoder(capsys):
    """The protocol needs the context's priors: model-info gives it the synthetic one."""
    args = [*MATCHING, "--set", "encoder_options.protocol=gravity_aided"]
    assert main(args) == 0
    assert "MFLOPs/pair" in capsys.readouterr().out


def test_model_info_bf16_is_gated_like_training(monkeypatch, capsys):
    fake_cpu(monkeypatch, AVX2_ONLY)
    monkeypatch.delenv(ALLOW_SLOW_BF16_ENV, raising=False)
    assert main([*MATCHING, "--precision", "bf16"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "precision=bf16" in err and "needs avx512_bf16 or amx_bf16" in err
    assert f"{ALLOW_SLOW_BF16_ENV}=1" in err
    monkeypatch.setenv(ALLOW_SLOW_BF16_ENV, "1")
    assert main([*MATCHING, "--precision", "bf16"]) == 0
    assert "bf16 autocast" in capsys.readouterr().out
