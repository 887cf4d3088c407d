"""The sequence table's cells (report/sequence.py) and the fusion claims (claims/fusion.py) on
per-frame errors whose answers are known."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmark.evaluation.paired import pooled_bootstrap
from benchmark.runner.claims.evidence import (
    CONTRADICTED,
    NO_DIFFERENCE,
    SUPPORTED,
    Evidence,
)
from benchmark.runner.claims.frame_errors import FrameErrors
from benchmark.runner.claims.fusion import (
    fused_family_claim,
    fusion_claims,
    fusion_gain_claim,
    uncertainty_gain_claim,
)
from benchmark.runner.claims.sequence_errors import (
    SequenceErrors,
    exact_yaw_geodesic_deg,
    sequence_rows,
)
from benchmark.runner.report.sequence import oracle_distance, sequence_axes, sequence_figure

N_FLIGHTS, PER_FLIGHT = 20, 8
FLIGHT = np.repeat(np.arange(N_FLIGHTS), PER_FLIGHT)
N = len(FLIGHT)


def errors(level: float, seed: int, seeds: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.abs(level + rng.normal(0, 2.0, (seeds, N)))


class TestSequenceRows:
    def test_cells_against_numpy(self):
        frame, fused = errors(30.0, 1), errors(10.0, 2)
        modes = {
            m: {"dpsi_deg": e, "dphi_deg": e + 1.0, "horizontal_m": 5 * e}
            for m, e in (("frame", frame), ("filter", fused), ("smooth", fused * 0.5))
        }
        item = SequenceErrors("A", "long/standard", {"data": modes}, FLIGHT, np.zeros(N))
        rows = sequence_rows([item]).set_index("mode")
        assert rows.loc["frame", "mean_dpsi_deg"] == pytest.approx(frame.mean())
        assert rows.loc["smooth", "acc10"] == pytest.approx(((fused * 0.5 + 1) <= 10).mean())
        assert rows.loc["filter", "median_horizontal_m"] == pytest.approx(
            np.median(5 * fused, axis=1).mean()
        )
        d, lo, hi = pooled_bootstrap(frame + 1, fused + 1, FLIGHT, 2000, 0, paired_seeds=True)
        assert rows.loc["filter", "gain_dphi_deg"] == pytest.approx(d)
        assert (rows.loc["filter", "gain_dphi_deg_lo"], rows.loc["filter", "gain_dphi_deg_hi"]) == (
            pytest.approx(lo), pytest.approx(hi))  # fmt: skip
        assert np.isnan(rows.loc["frame"].get("gain_dphi_deg", np.nan))


class TestExactYawCeiling:
    def test_geodesic_against_the_rotation_module(self):
        import torch

        from benchmark.geometry import euler_to_rotmat, geodesic_distance

        rng = np.random.default_rng(3)
        n = 200
        yaw = rng.uniform(-np.pi, np.pi, n)
        pitch, roll = rng.uniform(-1.2, 0.2, n), rng.uniform(-0.5, 0.5, n)
        pitch_hat, roll_hat = pitch + rng.normal(0, 0.2, n), roll + rng.normal(0, 0.2, n)
        t = lambda x: torch.as_tensor(x, dtype=torch.float64)  # noqa: E731
        reference = np.degrees(geodesic_distance(
            euler_to_rotmat(t(yaw), t(pitch_hat), t(roll_hat)),
            euler_to_rotmat(t(yaw), t(pitch), t(roll)),
        ).numpy())  # fmt: skip
        ours = exact_yaw_geodesic_deg(pitch_hat, roll_hat, pitch, roll)
        np.testing.assert_allclose(ours, reference, atol=1e-9)
        assert np.all(exact_yaw_geodesic_deg(pitch, roll, pitch, roll) < 1e-6)

    def test_cell_is_the_fraction_within_10_deg(self):
        e = errors(20.0, 4)
        modes = {m: {"dpsi_deg": e, "dphi_deg": e, "horizontal_m": e}
                 for m in ("frame", "filter", "smooth")}  # fmt: skip
        exact = np.abs(np.random.default_rng(5).normal(8.0, 4.0, e.shape))
        item = SequenceErrors("A", "long/towns", {"data": modes}, FLIGHT, np.zeros(N),
                              exact_yaw_dphi=exact)  # fmt: skip
        rows = sequence_rows([item]).set_index("mode")
        np.testing.assert_allclose(rows["acc10_exact_yaw"], (exact <= 10).mean())  # every mode
        bare = SequenceErrors("B", "long/towns", {"data": modes}, FLIGHT, np.zeros(N))
        assert np.isnan(sequence_rows([bare])["acc10_exact_yaw"]).all()


class TestOracleDistance:
    def rows(self, learned_best: float, oracle: float):
        import pandas as pd

        return pd.DataFrame(
            [
                {"label": "A", "mode": "smooth", "learned": True, "mean_dpsi_deg": learned_best},
                {"label": "B", "mode": "smooth", "learned": True, "mean_dpsi_deg": 40.0},
                {"label": "Constant (train mean)", "mode": "smooth", "learned": False,
                 "mean_dpsi_deg": 1.0},  # not learned: never the best row
                {"label": "UAV-only control", "mode": "smooth", "learned": True, "control": True,
                 "mean_dpsi_deg": 2.0},  # the control is no candidate either
                {"label": "Geometry oracle (not learned; given true position, pitch, roll)",
                 "mode": "smooth", "learned": False, "mean_dpsi_deg": oracle},
                {"label": "A", "mode": "frame", "learned": True, "mean_dpsi_deg": 0.5},
            ]
        )  # fmt: skip

    def test_above_the_oracle(self):
        text = oracle_distance(self.rows(12.0, 9.5))
        assert "A, 12.0° against the oracle's 9.5°, +2.5° (above it)" in text

    def test_at_or_below(self):
        assert "-1.0° (at or below it)" in oracle_distance(self.rows(8.0, 9.0))

    def test_nothing_without_an_oracle_row(self):
        assert oracle_distance(self.rows(8.0, 9.0).iloc[[0, 1, 2]]) == ""


class FakeStore:
    """The parts of ``FrameStore`` the fusion claims read: per-frame errors by (label, mode)."""

    def __init__(self, fused: dict[tuple[str, str, str], np.ndarray], heads: list[str],
                 uncertainty: dict[str, np.ndarray] | None = None):  # fmt: skip
        self.fused, self.heads, self.unc = fused, heads, uncertainty or {}

    def _fe(self, values: np.ndarray) -> FrameErrors:
        return FrameErrors(values, np.arange(N), FLIGHT, (0, 1), ("enc0", "enc1"))

    def labels(self, table, split=None, control=None):
        return list(self.heads)

    def has(self, table, label, split, x=None):
        return True

    def has_sequence(self, table, label, split):
        return (label, split, "frame") in self.fused

    def sequence_errors(self, table, label, split, metric, mode, odometry="data"):
        return self._fe(self.fused[label, split, mode])

    def errors(self, table, label, split, metric, x=None, satellite="true"):
        if metric == "uncertainty":
            if label not in self.unc:
                raise ValueError("no column 'uncertainty'")
            return self._fe(self.unc[label])
        return self._fe(self.fused[label, split, "frame"])

    def train_split(self, table, label, x=None):
        return "standard/train"

    def constant(self, split, metric, train_split):
        return FrameErrors(np.full((1, N), 90.0), np.arange(N), FLIGHT, (0,))


def store_with(gains: dict[str, float], splits: tuple[str, ...]) -> FakeStore:
    fused = {}
    for k, (label, gain) in enumerate(gains.items()):
        for j, split in enumerate(splits):
            frame = errors(30.0, 10 * k + j)
            fused[label, split, "frame"] = frame
            fused[label, split, "filter"] = np.abs(frame - gain)
            fused[label, split, "smooth"] = np.abs(frame - 1.5 * gain)
    return FakeStore(fused, list(gains))


GAIN = ("standard/test", "towns/test", "generalized/test")
LONG = ("long/standard", "long/towns", "long/london")


class TestFusionGainClaim:
    def test_supported_when_every_head_gains(self):
        claim = fusion_gain_claim(Evidence(store_with({"A": 10.0, "B": 8.0}, GAIN), 400))
        assert claim.verdict == SUPPORTED and len(claim.comparisons) == 6

    def test_a_head_without_a_gain_is_no_practical_difference(self):
        claim = fusion_gain_claim(Evidence(store_with({"A": 10.0, "B": 0.0}, GAIN), 400))
        assert claim.verdict == NO_DIFFERENCE


class TestFusedFamilyClaim:
    def test_distribution_better_fused(self):
        store = store_with({"Pd/Re-Net": 12.0, "Re-Net-R": 2.0}, LONG)
        claim = fused_family_claim(Evidence(store, 400))
        assert claim.verdict == SUPPORTED and len(claim.comparisons) == 3

    def test_regression_better_fused_contradicts(self):
        store = store_with({"Pd/Re-Net": 2.0, "Re-Net-R": 14.0}, LONG)
        assert fused_family_claim(Evidence(store, 400)).verdict == CONTRADICTED


class TestUncertaintyGainClaim:
    def test_uncertainty_that_ranks_the_gain(self):
        store = store_with({"Pd/Re-Net": 10.0, "Re-Net-R": 10.0}, LONG)
        rng = np.random.default_rng(0)
        frame = store.fused["Pd/Re-Net", "long/standard", "frame"]
        gain = rng.uniform(0, 25, (1, N)).repeat(2, axis=0)  # varies from frame to frame
        store.fused["Pd/Re-Net", "long/standard", "smooth"] = np.abs(frame - gain)
        store.unc = {"Pd/Re-Net": gain + rng.normal(0, 3.0, (2, N))}  # ranks it, with noise
        claim = uncertainty_gain_claim(Evidence(store, 400))
        assert claim.verdict == SUPPORTED and len(claim.comparisons) == 1
        assert "Re-Net-R" in claim.evidence  # named: no uncertainty to rank by


class TestFusionClaims:
    def test_none_without_a_sequence_table(self):
        assert fusion_claims(Evidence(FakeStore({}, []), 100)) == []
        claims = fusion_claims(Evidence(store_with({"A": 5.0}, GAIN + LONG), 100))
        assert [c.kind for c in claims] == ["fusion"] * 3


class TestPitchRollOfTheBestHead:
    """A ``pitch_roll: best_on_val`` volume row: the head is chosen on standard/val only, and
    δφ is the volume's fused yaw with that head's pitch and roll, scored against the rotation
    module."""

    SPLIT = "long/towns"
    SEEDS = (0, 1)

    def spec(self):
        from pathlib import Path

        from benchmark.runner.plan.specs import RowSpec, TableSpec

        matching = {"encoder": "matching", "encoder_options": {"grey_gradient": True}}
        rows = (
            RowSpec("A", "", {"attitude": "matrix_fisher"}),
            RowSpec("B", "", {"attitude": "re_net_r"}),
            RowSpec("Control", "", {"attitude": "pd_re_net", "satellite_input": "blank"}),
            RowSpec("Gravity", "", {"attitude": "re_net_svd", "encoder": "matching",
                                    "encoder_options": {"protocol": "gravity_aided"}}),
            RowSpec("V", "", {"attitude": "pd_re_net", **matching}, beliefs="volume",
                    pitch_roll="best_on_val"),
        )  # fmt: skip
        return TableSpec("seq", "t", "sequence", Path("seq.yaml"), rows,
                         eval_splits=(self.SPLIT,))  # fmt: skip

    def build(self, tmp_path, val: dict[str, float], test: dict[str, float], missing=()):
        """Units of every row per seed on encoder ``enc-<seed>``; a head's val (test) CSV has
        pitch and roll errors of ``val[label]`` (``test[label]``) degrees each; the volume unit
        writes its fusion table. ``missing``: (label, seed) without a validation file."""
        import pandas as pd

        from benchmark.models.model_config import ModelConfig
        from benchmark.runner.execute.worker import eval_key, eval_paths, volume_sequence_paths
        from benchmark.runner.plan.units import Unit
        from benchmark.training.config import PretrainedConfig, TrainConfig

        spec, units = self.spec(), []
        rng = np.random.default_rng(7)
        truth = pd.DataFrame({"index": np.arange(N), "yaw_deg": rng.uniform(-180, 180, N),
                              "pitch_deg": rng.uniform(-60, 0, N),
                              "roll_deg": rng.uniform(-10, 10, N)})  # fmt: skip
        for job in spec.jobs():
            for seed in self.SEEDS:
                key = f"{job.label}-{seed}"
                model = {"encoder": "matching", **job.row.model}
                cfg = TrainConfig(
                    seed=seed,
                    model=ModelConfig(**model),
                    pretrained=PretrainedConfig(checkpoint=f"enc-{seed}.pt", key=f"enc-{seed}"),
                )
                units.append(Unit(key, cfg, [job]))
                unit_dir = tmp_path / "units" / key
                for split, err in (("standard/val", val), (self.SPLIT, test)):
                    if job.label not in err or ((job.label, seed) in missing and "val" in split):
                        continue
                    sign = rng.choice([-1.0, 1.0], (N, 2))
                    frame = truth.assign(
                        yaw_hat_deg=truth["yaw_deg"],
                        pitch_hat_deg=truth["pitch_deg"] + sign[:, 0] * err[job.label],
                        roll_hat_deg=truth["roll_deg"] + sign[:, 1] * err[job.label],
                        dtheta_deg=err[job.label],
                        dgamma_deg=err[job.label],
                    )
                    path = eval_paths(unit_dir, eval_key(split, "true"))[0]
                    path.parent.mkdir(parents=True, exist_ok=True)
                    frame.to_csv(path, index=False)
                if job.beliefs == "volume":
                    yaw_hat = truth["yaw_deg"] + rng.normal(0, 5, N)
                    fused = pd.DataFrame({
                        "odometry": "data", "index": np.arange(N), "flight": FLIGHT,
                        "sample": np.arange(N) % PER_FLIGHT, "t_s": 2.0 * (np.arange(N) % 8),
                        "mode": "frame", "yaw_hat_deg": yaw_hat, "E_hat_m": 0.0, "N_hat_m": 0.0,
                        "dpsi_deg": np.abs(yaw_hat - truth["yaw_deg"]), "dphi_deg": -1.0,
                        "horizontal_m": 3.0,
                    })  # fmt: skip
                    path = volume_sequence_paths(unit_dir, self.SPLIT)[0]
                    path.parent.mkdir(parents=True, exist_ok=True)
                    fused.to_csv(path, index=False)
        return spec, units, truth

    def test_chosen_on_validation_never_on_test(self, tmp_path):
        from benchmark.runner.claims.sequence_errors import best_pitch_roll_head

        # B is better on standard/val, A on the test split; the blank control and the
        # gravity-aided head (another protocol) are better still but never candidates
        val = {"A": 3.0, "B": 1.0, "Control": 0.1, "Gravity": 0.1, "V": 8.0}
        test = {"A": 0.5, "B": 4.0, "V": 8.0}
        spec, units, _ = self.build(tmp_path, val, test)
        volume = [u for u in units if u.key.startswith("V-")]
        label, by_seed = best_pitch_roll_head(spec, units, tmp_path, volume)
        assert label == "B"
        assert {v: u.key for v, u in by_seed.items()} == {"V-0": "B-0", "V-1": "B-1"}

    def test_its_own_head_when_no_head_row_reads_its_encoder(self, tmp_path):
        from benchmark.runner.claims.sequence_errors import OWN_HEAD, best_pitch_roll_head
        from benchmark.training.config import PretrainedConfig

        val, test = {"A": 3.0, "B": 1.0, "V": 8.0}, {"A": 3.0, "B": 1.0}
        spec, units, _ = self.build(tmp_path, val, test)
        # every unit trained end to end (no shared encoder): no head reads the volume's encoder
        for u in units:
            u.cfg = dataclasses.replace(u.cfg, pretrained=PretrainedConfig())
        volume = [u for u in units if u.key.startswith("V-")]
        label, by_seed = best_pitch_roll_head(spec, units, tmp_path, volume)
        assert label == OWN_HEAD and {k: u.key for k, u in by_seed.items()} == {
            "V-0": "V-0", "V-1": "V-1"}  # fmt: skip

    def test_a_row_without_every_seed_is_no_candidate(self, tmp_path):
        from benchmark.runner.claims.sequence_errors import best_pitch_roll_head

        val, test = {"A": 3.0, "B": 1.0, "V": 8.0}, {"A": 3.0, "B": 1.0}
        spec, units, _ = self.build(tmp_path, val, test, missing={("B", 1)})
        volume = [u for u in units if u.key.startswith("V-")]
        assert best_pitch_roll_head(spec, units, tmp_path, volume)[0] == "A"

    def test_dphi_is_the_fused_yaw_with_the_chosen_pitch_and_roll(self, tmp_path):
        import torch

        from benchmark.geometry import euler_to_rotmat, geodesic_distance
        from benchmark.runner.claims.sequence_errors import load_sequences

        val, test = {"A": 3.0, "B": 1.0, "V": 8.0}, {"A": 0.5, "B": 4.0, "V": 8.0}
        spec, units, truth = self.build(tmp_path, val, test)
        (item,) = load_sequences(spec, units, tmp_path)
        assert item.label == "V (B)"
        import pandas as pd

        from benchmark.runner.execute.worker import eval_key, eval_paths, volume_sequence_paths

        t = lambda x: torch.as_tensor(np.radians(np.asarray(x, np.float64)))  # noqa: E731
        for row, seed in enumerate(self.SEEDS):
            fused = pd.read_csv(volume_sequence_paths(tmp_path / "units" / f"V-{seed}",
                                                      self.SPLIT)[0])  # fmt: skip
            head = pd.read_csv(eval_paths(tmp_path / "units" / f"B-{seed}",
                                          eval_key(self.SPLIT, "true"))[0])  # fmt: skip
            reference = np.degrees(geodesic_distance(
                euler_to_rotmat(t(fused["yaw_hat_deg"]), t(head["pitch_hat_deg"]),
                                t(head["roll_hat_deg"])),
                euler_to_rotmat(t(truth["yaw_deg"]), t(truth["pitch_deg"]),
                                t(truth["roll_deg"])),
            ).numpy())  # fmt: skip
            got = item.errors["data"]["frame"]
            np.testing.assert_allclose(got["dphi_deg"][row], reference, atol=1e-7)
            np.testing.assert_array_equal(got["dpsi_deg"][row], fused["dpsi_deg"])  # the volume's
            assert item.exact_yaw_dphi is not None  # from B's pitch and roll: 4° off each way
            np.testing.assert_allclose(
                item.exact_yaw_dphi[row],
                exact_yaw_geodesic_deg(*(np.radians(head[c].to_numpy()) for c in (
                    "pitch_hat_deg", "roll_hat_deg", "pitch_deg", "roll_deg"))),
            )  # fmt: skip


class TestSequenceFigure:
    @staticmethod
    def item(label: str, split: str, level: float, stress: bool = True) -> SequenceErrors:
        t_s = np.tile(np.arange(PER_FLIGHT) * 2.0, N_FLIGHTS)
        modes = {"filter": {"dpsi_deg": errors(level, 1) + t_s}}
        runs = {"data": modes, **({"4x": {"filter": {"dpsi_deg": errors(level, 2)}}}
                                  if stress else {})}  # fmt: skip
        return SequenceErrors(label, split, runs, FLIGHT, t_s)

    def test_a_panel_row_per_odometry_and_a_line_per_row(self) -> None:
        import matplotlib.pyplot as plt

        labels = [f"head {n}" for n in range(23)]  # more rows than one palette has colours
        items = [
            self.item(lab, split, 10.0 + n, stress=n != 0)
            for n, lab in enumerate(labels)
            for split in ("long/standard", "long/towns")
        ]
        items.append(self.item("short", "standard/test", 5.0))  # long splits only are drawn
        fig = sequence_axes(items)
        try:
            axes = np.array(fig.axes[:4]).reshape(2, 2)
            titles = [ax.get_title() for ax in axes.flat]
            assert titles == [
                "long/standard, the dataset's odometry",
                "long/towns, the dataset's odometry",
                "long/standard, 4x its noise",
                "long/towns, 4x its noise",
            ]
            assert [len(ax.lines) for ax in axes.flat] == [23, 23, 22, 22]
            # every row its own colour and style, the same in every panel
            looks = {(line.get_label(), tuple(line.get_color()), line.get_linestyle())
                     for ax in axes.flat for line in ax.lines}  # fmt: skip
            assert len({(c, s) for _, c, s in looks}) == 23 == len({lab for lab, _, _ in looks})
            # the curve is the mean over seeds and flights at each second fused
            line = next(x for x in axes[0, 0].lines if x.get_label() == "head 3")
            e = errors(13.0, 1) + np.tile(np.arange(PER_FLIGHT) * 2.0, N_FLIGHTS)
            t = np.tile(np.arange(PER_FLIGHT) * 2.0, N_FLIGHTS)
            want = [e[:, t == x].mean() for x in np.unique(t)]
            np.testing.assert_allclose(line.get_ydata(), want)
            np.testing.assert_allclose(line.get_xdata(), np.unique(t))
            assert len(fig.legends) == 1 and len(fig.legends[0].get_texts()) == 23
        finally:
            plt.close(fig)

    def test_nothing_to_draw_writes_nothing(self, tmp_path) -> None:
        assert sequence_axes([]) is None
        assert sequence_figure([], tmp_path / "s.png") is False
        assert not (tmp_path / "s.png").exists()
