"""Profiles and the simulate / preview / bench command lines."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmark.cli import main
from benchmark.data.profiles import DATA_PROFILES, DataProfile, get_data_profile


class TestProfiles:
    def test_issue_sizes(self):
        assert (
            DATA_PROFILES["smoke"].image_size <= 48
            and 10 <= DATA_PROFILES["smoke"].n_standard < 100
        )
        assert (
            DATA_PROFILES["quick"].image_size == 96
            and 1000 <= DATA_PROFILES["quick"].n_standard <= 9999
        )
        assert (
            DATA_PROFILES["paper"].image_size == 224 and DATA_PROFILES["paper"].n_standard >= 10000
        )
        for p in DATA_PROFILES.values():  # paper Sec. 3.1 / 3.5 constants
            assert p.sat_height_m == 1000.0 and p.sat_footprint_m == (2000.0, 1000.0)
            assert p.flight_pitches_deg == (0.0, -10.0, -50.0)
            assert p.flight_altitude_m == (70.0, 90.0)

    def test_frozen(self):
        with pytest.raises(dataclasses.FrozenInstanceError):
            DATA_PROFILES["quick"].image_size = 1

    def test_size_override_scales_every_set(self):
        q = DATA_PROFILES["quick"]
        p = get_data_profile("quick", q.n_standard // 10)
        assert p.n_standard == q.n_standard // 10 and p.image_size == q.image_size
        assert p.n_generalized_test == q.n_generalized_test // 10
        assert p.n_height_train == q.n_height_train // 10

    def test_bad_input(self):
        with pytest.raises(ValueError, match="unknown profile 'huge'"):
            get_data_profile("huge")
        for bad in (0, -3, 2):
            with pytest.raises(ValueError, match=">= 3 pairs"):
                get_data_profile("quick", bad)
        with pytest.raises(ValueError, match="standard_fractions"):
            dataclasses.replace(DATA_PROFILES["smoke"], standard_fractions=(0.5, 0.5, 0.5))
        for bad in (0, -1, 2.5):
            with pytest.raises(ValueError, match="eval_samples_per_flight must be None or an"):
                dataclasses.replace(DATA_PROFILES["smoke"], eval_samples_per_flight=bad)

    def test_odometry_noise_and_long_flights(self):
        """Issue 39: the stated odometry figures (at least the issue's yardstick) and the long
        test flights per profile: quick's and paper's last >= 60 s."""
        for p in DATA_PROFILES.values():
            assert (p.odometry_gyro_bias_dps, p.odometry_yaw_walk_deg) == (0.2, 0.2)
            assert (p.odometry_scale_sigma, p.odometry_step_sigma_m) == (0.03, 0.5)
        counts = {k: (p.n_long_flights, p.long_samples_per_flight, p.long_frame_stride)
                  for k, p in DATA_PROFILES.items()}  # fmt: skip
        assert counts == {"smoke": (2, 6, 60), "quick": (24, 32, 60), "paper": (40, 32, 60)}
        for name in ("quick", "paper"):
            p = DATA_PROFILES[name]
            assert (p.long_samples_per_flight - 1) * p.long_frame_stride / 30.0 >= 60.0
            assert p.standard_only().n_long_flights == 0

    def test_size_override_scales_long_flights_not_their_length(self):
        q = DATA_PROFILES["quick"]
        small = q.with_size(q.n_standard // 10)
        assert small.n_long_flights == 3  # ceil(24 / 10): fewer flights, each as long
        assert small.long_samples_per_flight == q.long_samples_per_flight
        assert small.long_frame_stride == q.long_frame_stride
        assert q.with_size(3).n_long_flights == 1
        assert q.standard_only().with_size(300).n_long_flights == 0

    @pytest.mark.parametrize(
        "field", ["odometry_gyro_bias_dps", "odometry_yaw_walk_deg", "odometry_scale_sigma",
                  "odometry_step_sigma_m"],
    )  # fmt: skip
    @pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), "0.2", True])
    def test_bad_odometry_figure_named(self, field, bad):
        with pytest.raises(ValueError, match=f"DataProfile.{field} must be"):
            dataclasses.replace(DATA_PROFILES["smoke"], **{field: bad})

    @pytest.mark.parametrize(
        ("field", "bad"),
        [("n_long_flights", -1), ("n_long_flights", 1.5), ("long_samples_per_flight", 1),
         ("long_frame_stride", 0), ("n_long_flights", float("nan")), ("n_long_flights", True)],
    )  # fmt: skip
    def test_bad_long_flights_named(self, field, bad):
        with pytest.raises(ValueError, match=f"DataProfile.{field} must be an integer"):
            dataclasses.replace(DATA_PROFILES["smoke"], **{field: bad})

    def test_dict_round_trip(self):
        for p in DATA_PROFILES.values():
            assert DataProfile.from_dict(p.to_dict()) == p
        with pytest.raises(ValueError, match="unknown fields"):
            DataProfile.from_dict({**DATA_PROFILES["smoke"].to_dict(), "colour": 1})


class TestSimulateCommand:
    def test_unknown_profile_exits_2(self, tmp_path, capsys):
        with pytest.raises(SystemExit) as err:
            main(["simulate", "--profile", "huge", "--out", str(tmp_path / "x")])
        assert err.value.code == 2 and not (tmp_path / "x").exists()
        assert "huge" in capsys.readouterr().err

    @pytest.mark.parametrize("flag", [["--size", "0"], ["--size", "-5"], ["--workers", "0"]])
    def test_bad_numbers_exit_2(self, tmp_path, capsys, flag):
        assert main(["simulate", "--profile", "smoke", "--out", str(tmp_path / "x"), *flag]) == 2
        assert not (tmp_path / "x").exists()
        assert flag[0] in capsys.readouterr().err

    def test_writes_and_resumes_dataset(self, smoke_root, city_cache, tmp_path, capsys):
        out = tmp_path / "ds"
        args = ["simulate", "--profile", "smoke", "--out", str(out), "--workers", "1",
                "--city-cache", str(city_cache), "--quiet"]  # fmt: skip
        assert main(args) == 0
        assert "written" in capsys.readouterr().out
        assert (out / "manifest.json").read_bytes() == (smoke_root / "manifest.json").read_bytes()
        assert main(args) == 0 and "already complete" in capsys.readouterr().out

    def test_other_config_refused(self, smoke_root, city_cache, capsys):
        before = (smoke_root / "manifest.json").read_bytes()
        code = main(["simulate", "--profile", "smoke", "--size", "30", "--out", str(smoke_root),
                     "--city-cache", str(city_cache), "--quiet"])  # fmt: skip
        assert code == 2
        assert "different config" in capsys.readouterr().err
        assert (smoke_root / "manifest.json").read_bytes() == before

    def test_complete_dataset_reported(self, smoke_root, city_cache, capsys):
        code = main(["simulate", "--profile", "smoke", "--out", str(smoke_root),
                     "--city-cache", str(city_cache), "--quiet"])  # fmt: skip
        assert code == 0 and "already complete" in capsys.readouterr().out


class TestPreviewCommand:
    def test_writes_png(self, smoke_root, tmp_path):
        import matplotlib.image

        out = tmp_path / "sheet.png"
        assert main(["preview", str(smoke_root), "--split", "flight/pitch-10", "--n", "4",
                     "--out", str(out)]) == 0  # fmt: skip
        img = matplotlib.image.imread(out)
        assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 300
        assert np.std(img[..., :3]) > 0.05

    def test_library_returns_where_it_wrote(self, smoke_root, tmp_path, capsys):
        # Issue 41: the library returns the result; the command prints its line.
        from benchmark.data.preview import PreviewConfig, PreviewResult, preview

        out = tmp_path / "sheet.png"
        result = preview(PreviewConfig(smoke_root, "flight/pitch-10", 2, out))
        assert result == PreviewResult(out, 2, "flight/pitch-10") and out.stat().st_size > 0
        assert capsys.readouterr().out == ""
        assert main(["preview", str(smoke_root), "--split", "flight/pitch-10", "--n", "2",
                     "--out", str(out)]) == 0  # fmt: skip
        assert capsys.readouterr().out == f"wrote {out} (2 pairs of flight/pitch-10)\n"

    def test_unknown_split_and_missing_dataset(self, smoke_root, tmp_path, capsys):
        assert main(["preview", str(smoke_root), "--split", "nope"]) == 2
        assert "unknown split" in capsys.readouterr().err
        assert main(["preview", str(tmp_path / "none")]) == 2
        assert "does not exist" in capsys.readouterr().err


class TestBenchCommand:
    def test_unknown_target(self, capsys):
        assert main(["bench", "nope"]) == 2
        assert "simulate" in capsys.readouterr().err

    def test_targets_resolve(self):
        import importlib

        from benchmark.commands.bench import TARGET_HELP, TARGETS

        assert set(TARGETS) == set(TARGET_HELP)
        for path in TARGETS.values():
            module = importlib.import_module(path)
            assert isinstance(module.HELP, str)
            assert callable(module.add_arguments) and callable(module.run)
