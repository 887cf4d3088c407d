"""The continuity study (paper Fig. 2, Eq. 6) against the paper's own statements."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from benchmark.analysis.continuity import (
    eq6_threshold_deg,
    find_jumps,
    paper_rotvec,
    refine_jump,
    sweep,
)
from benchmark.cli import main


def jumps_of(table: pd.DataFrame, rep_prefix: str) -> list[float]:
    return sorted(
        {
            round(j.heading_deg, 2)
            for j in find_jumps(table)
            if j.representation.startswith(rep_prefix)
        }
    )


class TestEq6Threshold:
    def test_paper_value(self):
        # Paper: "From Eq. (6), the intermittent point occurs when psi = -63.03 deg" for
        # theta = -20 deg, gamma = -10 deg. The closed form evaluates to 63.04 deg.
        assert eq6_threshold_deg(math.radians(-20), math.radians(-10)) == pytest.approx(
            63.03, abs=0.02
        )

    @pytest.mark.parametrize(("pitch", "roll"), [(-20, -10), (-40, 5), (-5, -8), (-50, 10)])
    def test_matches_case_boundary_of_eq3(self, pitch, roll):
        # Eq. 6 is where R33 >= R11 + R22 stops holding: check it against the sampled matrix
        # (independent of the quaternion code).
        step = 0.01
        table = sweep(math.radians(pitch), math.radians(roll), step, "uav")
        holds = (table.R33 >= table.R11 + table.R22).to_numpy()
        edges = table.heading_deg.to_numpy()[np.nonzero(holds != np.roll(holds, -1))[0]] + step / 2
        threshold = eq6_threshold_deg(math.radians(pitch), math.radians(roll))
        assert np.min(np.abs(np.abs(edges) - threshold)) < 2 * step


class TestSweep:
    def test_paper_fig2_single_quaternion_jump(self):
        table = sweep(math.radians(-20), math.radians(-10), 0.01, "uav")
        assert jumps_of(table, "quaternion") == pytest.approx([-63.04], abs=0.02)
        # Eq. 7 inherits the quaternion's jump
        assert jumps_of(table, "rotation vector") == pytest.approx([-63.04], abs=0.02)

    def test_rotation_matrix_is_continuous(self):
        for attitude in ("uav", "relative"):
            table = sweep(math.radians(-20), math.radians(-10), 0.05, attitude)
            assert jumps_of(table, "rotation matrix") == []

    def test_euler_jumps_at_plus_minus_180(self):
        table = sweep(math.radians(-30), math.radians(5), 0.05, "uav")
        assert jumps_of(table, "Euler") == [180.0]

    def test_convention_heading_is_yaw_in_degrees(self):
        table = sweep(math.radians(-20), math.radians(-10), 1.0, "uav")
        np.testing.assert_allclose(table.yaw_deg, table.heading_deg, atol=1e-9)
        np.testing.assert_allclose(table.pitch_deg, -20.0, atol=1e-9)

    def test_rejects_bad_step(self):
        with pytest.raises(ValueError, match="step"):
            sweep(0.0, 0.0, 0.0, "uav")


class TestRefineJump:
    def test_bisection_lands_on_eq6(self):
        # The bisected quaternion jump equals the closed form to far better than the sampling step.
        pitch, roll = math.radians(-20), math.radians(-10)
        at = refine_jump(pitch, roll, "uav", "q0", -63.5, -62.5)
        assert at == pytest.approx(-eq6_threshold_deg(pitch, roll), abs=1e-4)


class TestPaperRotvec:
    def test_matches_axis_angle_for_positive_q0(self):
        angle, axis = 0.7, np.array([0.6, 0.0, 0.8])
        q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
        import torch

        rv = paper_rotvec(torch.tensor(q))
        np.testing.assert_allclose(rv.numpy(), angle * axis, atol=1e-12)


class TestContinuityCommand:
    def test_writes_csv_png_and_summary(self, tmp_path, capsys):
        assert main(["continuity", "--step", "0.5", "--out", str(tmp_path)]) == 0
        for name in (
            "continuity_uav.csv",
            "continuity_uav.png",
            "continuity_uav.md",
            "continuity_uav_jumps.csv",
        ):
            assert (tmp_path / name).stat().st_size > 0
        table = pd.read_csv(tmp_path / "continuity_uav.csv")
        assert len(table) == 720
        assert "63.041 deg" in capsys.readouterr().out

    def test_library_returns_the_report_and_prints_nothing(self, tmp_path, capsys):
        # Issue 41: the library returns the summary and the files; the command prints them.
        from benchmark.analysis.continuity import ContinuityConfig, continuity_report
        from benchmark.errors import InputError

        report = continuity_report(ContinuityConfig(step=0.5, out=tmp_path))
        assert capsys.readouterr().out == ""
        assert [f.name for f in report.files] == [
            "continuity_uav.csv",
            "continuity_uav.png",
            "continuity_uav.md",
            "continuity_uav_jumps.csv",
        ]
        assert all(f.stat().st_size > 0 for f in report.files)
        assert report.summary == (tmp_path / "continuity_uav.md").read_text()
        assert "63.041 deg" in report.summary
        assert report.lines()[-2:] == [
            "",
            f"wrote {tmp_path / 'continuity_uav'}.{{csv,png,md}} and continuity_uav_jumps.csv",
        ]
        with pytest.raises(InputError, match="step must be in"):
            continuity_report(ContinuityConfig(step=0.0, out=tmp_path / "bad"))
        assert not (tmp_path / "bad").exists()

    def test_bad_angle_exits_2(self, tmp_path, capsys):
        assert main(["continuity", "--pitch", "120", "--out", str(tmp_path)]) == 2
        assert "--pitch must be" in capsys.readouterr().err
        assert not any(tmp_path.iterdir())
