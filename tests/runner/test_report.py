"""Report cells: mean over seeds and the flight x seed bootstrap interval, validation beside test.

Inputs are real-format predictions CSVs written in ``tmp_path`` (the columns and paths the runner
writes), summarised by the report code and compared with naive computations.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark.evaluation.paired import paired_bootstrap
from benchmark.runner.claims.report_numbers import (
    EXTRA_METRICS,
    REPORT_METRICS,
    results_frame,
    with_horizontal_errors,
)
from benchmark.runner.claims.spread import (
    FLIGHT_BOOT,
    cell_interval,
    read_frames,
    seed_flight_bootstrap,
)
from benchmark.runner.claims.table_intervals import summarize
from benchmark.runner.execute.reference_rows import ReferenceResults
from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan.repro_profiles import get_repro_profile
from benchmark.runner.plan.specs import default_spec_dir, load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.runner.report.sweeps import (
    series_label,
    sweep_figure,
    sweep_label,
    sweep_table,
    sweep_tick,
)
from benchmark.runner.report.tables import (
    extra_metrics_table,
    interval_note,
    load_paper,
    markdown_table,
    paper_value,
    pick,
)

SPLITS = ["standard/train", "standard/val", "standard/test", "generalized/test"]
SPLITS += [f"height{h}/{p}" for h in (600, 800, 1000, 1200, 1400) for p in ("train", "test")]
FRAME_COLS = ["dE_m", "dN_m", "dU_m", "dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg"]


def naive_bootstrap(errors: np.ndarray, groups: np.ndarray, n_boot: int, seed: int) -> np.ndarray:
    """Replicates by explicit concatenation, with the random draws of the paired module's pooled
    bootstrap against a zero-error model (flights first, then that model's one seed, then the
    seeds), each replicate built frame by frame."""
    rng = np.random.default_rng(seed)
    flights = np.unique(groups)
    draws_f = rng.integers(0, len(flights), size=(n_boot, len(flights)))
    rng.integers(0, 1, size=(n_boot, 1))  # the zero model's single seed
    draws_s = rng.integers(0, errors.shape[0], size=(n_boot, errors.shape[0]))
    out = []
    for fb, sb in zip(draws_f, draws_s, strict=True):
        means = []
        for s in sb:
            frames = np.concatenate([errors[s][groups == flights[f]] for f in fb])
            means.append(frames.mean())
        out.append(np.mean(means))
    return np.asarray(out)


class TestSeedFlightBootstrap:
    @pytest.mark.parametrize("n_seeds", [1, 3, 8])
    def test_matches_naive_replicates(self, n_seeds):
        rng = np.random.default_rng(1)
        groups = np.repeat([3, 7, 8, 11], [5, 2, 9, 4])
        errors = rng.gamma(2.0, 10.0, size=(n_seeds, groups.size))
        mean, lo, hi = seed_flight_bootstrap(errors, groups, n_boot=300, seed=5)
        reps = naive_bootstrap(errors, groups, 300, 5)
        assert mean == pytest.approx(errors.mean(), rel=1e-12)
        assert (lo, hi) == pytest.approx(tuple(np.quantile(reps, [0.025, 0.975])), rel=1e-12)

    def test_one_seed_is_the_flight_bootstrap_of_the_paired_module(self):
        rng = np.random.default_rng(2)
        groups = np.repeat(np.arange(6), 7)
        errors = rng.uniform(0, 90, size=groups.size)
        ours = seed_flight_bootstrap(errors, groups, n_boot=500, seed=3)
        ref = paired_bootstrap(np.zeros_like(errors), errors, groups, n_boot=500, seed=3)
        assert ours == pytest.approx(ref, rel=1e-12)

    def test_one_flight_resamples_seeds_only(self):
        errors = np.array([[1.0, 3.0], [5.0, 7.0], [9.0, 11.0]])  # seed means 2, 6, 10
        mean, lo, hi = seed_flight_bootstrap(errors, np.zeros(2), n_boot=4000, seed=0)
        assert mean == pytest.approx(6.0)
        # replicate means are means of 3 draws from {2, 6, 10}: within [2, 10], never beyond
        assert 2.0 <= lo < 6.0 < hi <= 10.0

    def test_nothing_to_resample(self):
        mean, lo, hi = seed_flight_bootstrap(np.array([[4.0, 6.0]]), np.array([1, 1]))
        assert mean == 5.0 and math.isnan(lo) and math.isnan(hi)

    def test_deterministic(self):
        groups = np.repeat(np.arange(4), 3)
        errors = np.arange(24.0).reshape(2, 12)
        assert seed_flight_bootstrap(errors, groups) == seed_flight_bootstrap(errors, groups)

    @pytest.mark.parametrize(
        "errors, groups, match",
        [
            (np.ones((2, 3)), np.zeros(4), "N = len"),
            (np.array([[1.0, np.nan]]), np.zeros(2), "finite"),
            (np.ones((2, 0)), np.zeros(0), "S, N >= 1"),
        ],
    )
    def test_bad_input(self, errors, groups, match):
        with pytest.raises(ValueError, match=match):
            seed_flight_bootstrap(errors, groups)


def write_predictions(path: Path, errors: dict[str, np.ndarray], flights: np.ndarray) -> None:
    """A predictions CSV with the runner's columns that the report reads (others are ignored)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    n = flights.size
    frame = pd.DataFrame({"index": np.arange(n), **errors, "flight": flights, "city": "oxford"})
    frame.iloc[::-1].to_csv(path, index=False, float_format="%.10g")  # row order must not matter


PAPER = load_paper(default_spec_dir().parent / "paper_tables.csv")


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """Units of table1 and fig5 on 3 seeds with metrics and predictions CSVs as the runner writes
    them (``<workdir>/units/<key>/eval/<split>.csv``), standard/val evaluated too."""
    tmp_path = tmp_path_factory.mktemp("synthetic")
    specs = load_specs(None, ["table1", "fig5"])
    profile = get_repro_profile("smoke")
    units = plan_units(specs, profile, [0, 1, 2], tmp_path / "data", SPLITS, "d" * 64)
    rng = np.random.default_rng(0)
    flights = {"standard/test": np.repeat([4, 5, 9], 6), "standard/val": np.repeat([1, 2], 5)}
    results, errors = {}, {}
    for unit in units:
        metrics = {}
        for split in unit.eval_splits + ([unit.cfg.data.val_split] * bool(unit.cfg.data.val_split)):
            for suffix in ("", "/swap"):
                key = split + suffix
                g = flights.get(split, np.repeat([0, 1], 3))
                e = {c: rng.gamma(2.0, 5.0 + unit.cfg.seed, size=g.size) for c in FRAME_COLS}
                name = key.replace("/", "__") + ".csv"
                write_predictions(tmp_path / "runs" / "units" / unit.key / "eval" / name, e, g)
                metrics[key] = {c: float(v.mean()) for c, v in e.items()}
                errors[unit.key, key] = (e, g)
        results[unit.key] = UnitResult(unit.key, True, metrics=metrics, seconds=1.0)
    return specs, units, results, errors, tmp_path / "runs"


class TestResultsFrame:
    def test_val_rows_marked(self, synthetic):
        _, units, results, _, _ = synthetic
        frame = results_frame(units, results)
        val = frame[frame.role == "val"]
        assert set(val.split) == {"standard/val"}
        assert set(frame[frame.role == "test"].split) >= {"standard/test", "height600/test"}
        # height units have no validation split: no val rows for them
        assert not val.train_split.str.startswith("height").any()
        # one val row per (job, seed, satellite mode) of the standard-trained jobs
        jobs = [j for u in units for j in u.jobs if j.train_split == "standard/train"]
        assert len(val) == 2 * len(jobs)


class TestWithHorizontalErrors:
    """Rows without the horizontal metrics (units trained before they existed) get them from
    their per-frame errors, computed here naively from the errors the fixture wrote."""

    def test_from_predictions_references_and_absent(self, synthetic):
        _, units, results, errors, workdir = synthetic
        frame = results_frame(units, results)
        assert "median_horizontal_m" not in frame
        ref = pd.DataFrame({"dE_m": [3.0, 6.0, 0.0], "dN_m": [4.0, 8.0, 1.0]})
        extra = pd.DataFrame(
            [
                {
                    "split": "standard/test",
                    "satellite": "true",
                    "reference": "oracle",
                    "train_split": "standard/train",
                },
                {"split": "standard/test", "satellite": "true", "unit": "never-trained"},
            ]
        )
        frame = pd.concat([frame, extra], ignore_index=True)
        refs = ReferenceResults(frames={("oracle", "standard/test", "true"): ref})
        filled = with_horizontal_errors(frame, workdir, refs)
        for r in filled.itertuples():
            if r.unit == "never-trained":  # no predictions: stays empty
                assert math.isnan(r.median_horizontal_m)
                continue
            if r.reference == "oracle":
                assert r.median_horizontal_m == pytest.approx(5.0)
                assert r.horizontal_m == pytest.approx((5.0 + 10.0 + 1.0) / 3)
                continue
            key = r.split + ("/swap" if r.satellite == "swap" else "")
            e, _ = errors[r.unit, key]
            horizontal = [
                math.sqrt(a * a + b * b) for a, b in zip(e["dE_m"], e["dN_m"], strict=True)
            ]
            assert r.median_horizontal_m == pytest.approx(float(np.median(horizontal)))
            assert r.horizontal_m == pytest.approx(sum(horizontal) / len(horizontal))

    def test_shown_in_the_further_metrics(self, synthetic):
        # A further metric is shown only if the report summarises it: every one must be in
        # REPORT_METRICS (the horizontal error once was not, so its column never appeared).
        assert set(EXTRA_METRICS) <= set(REPORT_METRICS)
        specs, units, results, errors, workdir = synthetic
        frame = with_horizontal_errors(results_frame(units, results), workdir, None)
        table1 = frame[frame.table == "table1"]
        summary = summarize(table1, [m for m in REPORT_METRICS if m in frame.columns])
        text = extra_metrics_table(specs[0], summary, EXTRA_METRICS)
        header = next(x for x in text.splitlines() if x.startswith("| split | model |"))
        cols = [c.strip() for c in header.strip("|").split("|")]
        i = cols.index("median horizontal error (m)")
        line = next(x for x in text.splitlines() if x.startswith("| `standard/test` | Re-Net-Q |"))
        cell = [c.strip() for c in line.strip("|").split("|")][i]
        per_seed = []
        for key in table1[(table1.label == "Re-Net-Q") & (table1.split == "standard/test")].unit:
            e, _ = errors[key, "standard/test"]
            per_seed.append(float(np.median(np.hypot(e["dE_m"], e["dN_m"]))))
        assert cell.startswith(f"{np.mean(per_seed):.3f} ±")


class TestCells:
    def test_bootstrap_cell_against_naive(self, synthetic):
        specs, units, results, errors, workdir = synthetic
        frame = results_frame(units, results)
        part = frame[
            (frame.table == "table1") & (frame.label == "Pd/Re-Net")
            & (frame.split == "standard/test") & (frame.satellite == "true")
        ]  # fmt: skip
        assert len(part) == 3  # three seeds
        got = cell_interval(part, ["dphi_deg", "acc10", "median_horizontal_m", "loglik"], workdir)
        assert got["interval"] == FLIGHT_BOOT and got["n_flights"] == 3
        assert "loglik_lo" not in got  # no log_likelihood column: keeps the seed interval
        e = np.stack([errors[u, "standard/test"][0]["dphi_deg"] for u in part.unit])
        g = errors[part.unit.iloc[0], "standard/test"][1]
        reps = naive_bootstrap(e, g, 2000, 0)
        lo, hi = np.quantile(reps, [0.025, 0.975])
        assert (got["dphi_deg_lo"], got["dphi_deg_hi"]) == pytest.approx((lo, hi), rel=1e-8)
        # acc@10°: the mean of the indicator δφ <= 10, resampled as the errors are
        acc = np.quantile(naive_bootstrap((e <= 10.0).astype(float), g, 2000, 0), [0.025, 0.975])
        assert (got["acc10_lo"], got["acc10_hi"]) == pytest.approx(acc, rel=1e-8)
        # the median horizontal error: np.median of each drawn seed's drawn flights' frames
        per_unit = [errors[u, "standard/test"][0] for u in part.unit]
        h = np.stack([np.hypot(e_u["dE_m"], e_u["dN_m"]) for e_u in per_unit])
        rng = np.random.default_rng(0)
        flights = np.unique(g)
        draws_f = rng.integers(0, len(flights), size=(2000, len(flights)))
        draws_s = rng.integers(0, 3, size=(2000, 3))
        medians = [
            np.mean([np.median(np.concatenate([h[s][g == flights[f]] for f in fb])) for s in sb])
            for fb, sb in zip(draws_f, draws_s, strict=True)
        ]
        expected = np.quantile(medians, [0.025, 0.975])
        assert (got["median_horizontal_m_lo"], got["median_horizontal_m_hi"]) == pytest.approx(
            expected, rel=1e-10
        )

        # the rendered Markdown cell: mean over seeds ± half-width of that interval
        metrics = [m for m in REPORT_METRICS if m in frame.columns]
        table1 = frame[frame.table == "table1"]
        summary = summarize(table1, metrics, lambda p: cell_interval(p, metrics, workdir))
        text = markdown_table(specs[0], summary, PAPER)
        line = next(x for x in text.splitlines() if x.startswith("| Pd/Re-Net |"))
        expected = f"{e.mean():.2f} ± {(hi - lo) / 2:.2f}"
        assert expected in line.split(" | ")
        assert "2000 bootstrap replicates that resample the test flights" in text
        assert "Student-t" not in interval_note(summary)  # every row has its per-frame files

    def test_without_per_frame_files_the_seed_t_interval(self, synthetic):
        from scipy import stats

        _specs, units, results, _errors, _ = synthetic
        frame = results_frame(units, results)
        table1 = frame[frame.table == "table1"]
        summary = summarize(table1, ["dphi_deg"], lambda p: cell_interval(p, ["dphi_deg"], None))
        row = pick(summary, "Pd-Net-E", "standard/test")
        values = table1[(table1.label == "Pd-Net-E") & (table1.split == "standard/test")
                        & (table1.satellite == "true")]["dphi_deg"].to_numpy()  # fmt: skip
        half = stats.t.ppf(0.975, 2) * values.std(ddof=1) / math.sqrt(3)
        assert row["interval"] == "seed t"
        assert row["dphi_deg_hi"] - row["dphi_deg"] == pytest.approx(half, rel=1e-10)
        assert "Student-t interval over the 3 seeds" in interval_note(summary)

    def test_read_frames_refuses_other_frames(self, tmp_path):
        e = {c: np.ones(4) for c in FRAME_COLS}
        write_predictions(tmp_path / "a.csv", e, np.array([0, 0, 1, 1]))
        write_predictions(tmp_path / "b.csv", e, np.array([0, 1, 1, 1]))
        with pytest.raises(ValueError, match="other frames"):
            read_frames([tmp_path / "a.csv", tmp_path / "b.csv"])


class TestValidationBesideTest:
    def test_table_val_columns(self, synthetic):
        specs, units, results, errors, _workdir = synthetic
        frame = results_frame(units, results)
        summary = summarize(frame[frame.table == "table1"], ["dpsi_deg", "dphi_deg"])
        text = markdown_table(specs[0], summary, PAPER)
        header = next(x for x in text.splitlines() if x.startswith("| model |"))
        cols = [c.strip() for c in header.strip("|").split("|")]
        i = cols.index("δφ geodesic (°) val")
        assert cols[i - 1] == "δφ geodesic (°) ours (mean)"  # beside the test number
        line = next(x for x in text.splitlines() if x.startswith("| Re-Net-Q |"))
        cell = [c.strip() for c in line.strip("|").split("|")][i]
        unit_keys = frame[(frame.table == "table1") & (frame.label == "Re-Net-Q")].unit.unique()
        vals = [errors[u, "standard/val"][0]["dphi_deg"].mean() for u in unit_keys]
        assert re.match(rf"{np.mean(vals):.2f} ± \d", cell)
        assert "`standard/val` for `standard/train`" in text

    def test_sweep_without_val_split_shows_dash(self, synthetic, tmp_path):
        specs, units, results, _, _workdir = synthetic
        frame = results_frame(units, results)
        fig5 = frame[frame.table == "fig5"]
        # the reproduction measured validation splits (table1's models): the height rows show "-"
        summary = summarize(fig5, ["dphi_deg", "dE_m"])
        assert " val |" not in sweep_table(specs[1], summary)
        text = sweep_table(specs[1], summary, show_val=True)
        header = next(x for x in text.splitlines() if x.startswith("| split |"))
        cols = [c.strip() for c in header.strip("|").split("|")]
        i = cols.index("δφ geodesic (°) val")
        rows = [x for x in text.splitlines() if x.startswith("| `height")]
        assert len(rows) == 10  # two models x five heights
        for r in rows:
            cells = [c.strip() for c in r.strip("|").split("|")]
            assert cells[i] == "–" and re.match(r"\d+\.\d\d ± ", cells[i - 1])
        assert "not run" not in text

    def test_no_val_rows_no_val_columns(self, synthetic):
        specs, units, results, _, _ = synthetic
        frame = results_frame(units, results)
        test_only = frame[(frame.table == "table1") & (frame.role == "test")]
        assert " val |" not in markdown_table(specs[0], summarize(test_only, ["dphi_deg"]), PAPER)


class TestSweepFigure:
    def test_draws_every_seed(self, synthetic, tmp_path, monkeypatch):
        import matplotlib.axes

        specs, units, results, _, workdir = synthetic
        frame = results_frame(units, results)
        fig5 = frame[frame.table == "fig5"]
        metrics = ["dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg", "dE_m", "dN_m", "dU_m"]
        summary = summarize(fig5, metrics, lambda p: cell_interval(p, metrics, workdir))
        dots, bands = [], []
        original_scatter = matplotlib.axes.Axes.scatter
        original_fill = matplotlib.axes.Axes.fill_between

        def scatter(self, x, y, *args, **kwargs):
            dots.append(np.asarray(y, dtype=float))
            return original_scatter(self, x, y, *args, **kwargs)

        def fill_between(self, x, lo, hi, *args, **kwargs):
            bands.append((np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)))
            return original_fill(self, x, lo, hi, *args, **kwargs)

        monkeypatch.setattr(matplotlib.axes.Axes, "scatter", scatter)
        monkeypatch.setattr(matplotlib.axes.Axes, "fill_between", fill_between)
        png = tmp_path / "fig5.png"
        sweep_figure(specs[1], summary, png, per_seed=fig5)
        assert png.stat().st_size > 0
        # per metric and line (two models): 5 sweep values x 3 seeds dots, and a band
        lines = 2 * len(metrics)
        assert len(dots) == lines and all(d.size == 15 for d in dots)
        assert len(bands) == lines and all(np.isfinite(lo).all() for lo, _ in bands)
        true = fig5[(fig5.satellite == "true")]
        assert np.sort(np.concatenate(dots)).tolist() == pytest.approx(
            np.sort(np.concatenate([true[m].to_numpy() for m in metrics])).tolist()
        )


class TestSweepLabels:
    @pytest.mark.parametrize(
        ("sweep", "expected"),
        [
            ("sat_height_m", "satellite image height above ground (m)"),
            ("pitch_bin_deg", "UAV pitch bin (°; satellite camera at -90°)"),
            ("kappa", "vMF concentration κ"),
            ("tilt_angle_deg", "tilt angle (°)"),  # the rule for a sweep without a label
            ("range_m", "range (m)"),
            ("batch_size", "batch size"),
            (None, "sweep value"),
        ],
    )
    def test_axis_label(self, sweep, expected):
        assert sweep_label(sweep) == expected

    @pytest.mark.parametrize(
        ("sweep", "value", "expected"),
        [
            ("pitch_bin_deg", "0to-10", "0 to -10°"),
            ("pitch_bin_deg", "-40to-50", "-40 to -50°"),
            ("range_m", "1.5to2", "1.5 to 2 m"),
            ("sat_height_m", "600", "600"),
            ("sat_height_m", 600, "600"),
            ("kappa", "10", "10"),
            ("variant", "/", "/ (plain)"),
            ("variant", "a-f", "a-f (AGTFM)"),
        ],
    )
    def test_tick(self, sweep, value, expected):
        assert sweep_tick(sweep, value) == expected

    def test_every_spec_sweep_has_a_readable_label(self):
        for spec in load_specs(None, None):
            if spec.kind == "sweep":
                assert "_" not in sweep_label(spec.sweep), spec.name
                for x in spec.sweep_values:
                    assert "to-" not in sweep_tick(spec.sweep, x), (spec.name, x)

    def test_figure_legend_axis_and_ticks(self, synthetic, tmp_path, monkeypatch):
        import matplotlib.figure

        specs, units, results, _, _ = synthetic
        frame = results_frame(units, results)
        fig5 = frame[frame.table == "fig5"]
        summary = summarize(fig5, ["dphi_deg", "dE_m"])
        saved = []
        original = matplotlib.figure.Figure.savefig

        def savefig(self, *args, **kwargs):
            saved.append(self)
            return original(self, *args, **kwargs)

        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
        sweep_figure(specs[1], summary, tmp_path / "fig5.png")
        ax = saved[0].axes[0]
        # Fig. 5's split follows the height: one line per model, named by the model only
        assert [t.get_text() for t in ax.get_legend().get_texts()] == ["Pd/Re-Net", "Re-Net-R"]
        assert ax.get_xlabel() == "satellite image height above ground (m)"
        assert [t.get_text() for t in ax.get_xticklabels()] == ["600", "800", "1000", "1200",
                                                                 "1400"]  # fmt: skip
        # a split that does not follow the sweep value is named in the legend
        assert series_label("Pd/Re-Net", "standard/test", False) == "Pd/Re-Net on standard/test"
        header = next(x for x in sweep_table(specs[1], summary).splitlines() if "| split |" in x)
        assert "| satellite image height above ground (m) |" in header


class TestSwapEffectInterval:
    """The swap probe's Δ interval in a table is the claims' (issue 38): each seed's swapped and
    true errors paired per frame, flights and seeds resampled together; never the mean of the
    seeds' own flight-bootstrap bounds."""

    def test_the_table_prints_the_claims_interval(self, synthetic):
        from benchmark.evaluation.paired import swap_effect
        from benchmark.runner.claims.evidence import N_BOOT, Evidence
        from benchmark.runner.claims.frame_errors import FrameStore
        from benchmark.runner.claims.satellite import swap_rise
        from benchmark.runner.claims.table_intervals import row_interval
        from benchmark.runner.report.tables import swap_probe_table

        specs, units, results, _errors, workdir = synthetic
        frame = results_frame(units, results)
        frame = frame[(frame.table == "table1") & (frame.role == "test")].copy()
        eval_dir = workdir / "units"
        for i in frame.index[frame.satellite == "swap"]:  # each seed's own effect, as trained
            unit, split = frame.at[i, "unit"], frame.at[i, "split"].replace("/", "__")
            true = pd.read_csv(eval_dir / unit / "eval" / f"{split}.csv")
            swap = pd.read_csv(eval_dir / unit / "eval" / f"{split}__swap.csv")
            for key, value in swap_effect(true, swap).items():
                frame.loc[i, key] = value
        metrics = [m for m in REPORT_METRICS if m in frame.columns]
        bare = summarize(frame, metrics)
        row = pick(bare, "Pd/Re-Net", "standard/test", "swap")
        assert math.isnan(row["swap_dpsi_boot_lo_deg"])  # no averaged bounds: no interval
        assert "no interval (no per-frame errors)" in swap_probe_table(specs[0], bare)

        def resolve(part):
            return row_interval(part, metrics, workdir, {}, ReferenceResults())

        summary = summarize(frame, metrics, resolve)
        text = swap_probe_table(specs[0], summary)
        store = FrameStore(workdir, workdir / "no-data", units)
        for label in ("Pd/Re-Net", "Re-Net-Q"):
            line = next(
                x for x in text.splitlines() if x.startswith(f"| `standard/test` | {label} |")
            )
            for metric, short in (("dpsi_deg", "dpsi"), ("dphi_deg", "dphi")):
                claim = swap_rise(Evidence(store), ("table1", label, None), "standard/test", metric)
                row = pick(summary, label, "standard/test", "swap")
                got = (row[f"swap_{short}_boot_lo_deg"], row[f"swap_{short}_boot_hi_deg"])
                assert got == pytest.approx((claim.lo, claim.hi), rel=1e-12)
                assert row[f"swap_{short}_diff_deg"] == pytest.approx(claim.diff, rel=1e-9)
                assert f"{claim.diff:+.2f} [{claim.lo:+.2f}, {claim.hi:+.2f}]" in line
                seeds = frame[(frame.label == label) & (frame.split == "standard/test")
                              & (frame.satellite == "swap")]  # fmt: skip
                averaged = seeds[f"swap_{short}_boot_lo_deg"].mean()
                assert averaged != pytest.approx(claim.lo, rel=1e-6)  # the old cell differs
        assert f"{N_BOOT} replicates that resample whole flights and the seeds together" in text


def _table_rows(spec, values: dict[tuple[str, str], float]) -> pd.DataFrame:
    """One seed's results rows of every row of ``spec`` and of the constant predictor, true and
    swapped image, each metric of the spec at ``values[label, split]`` (default 50)."""
    from benchmark.runner.report.tables import CONSTANT_LABEL

    rows = []
    entries = [(j.label, j.paper_model, j.train_split, j.eval_splits) for j in spec.jobs()]
    entries.append((CONSTANT_LABEL, "", spec.train_split, spec.eval_splits))
    for label, paper_model, train, splits in entries:
        for split in splits:
            value = values.get((label, split), 50.0)
            for satellite in ("true", "swap"):
                rows.append({"table": spec.name, "label": label, "paper_model": paper_model,
                             "x": None, "split": split, "satellite": satellite,
                             "satellite_input": "none" if label == CONSTANT_LABEL else "image",
                             "train_split": train, "role": "test", "seed": 0,
                             **dict.fromkeys(spec.metrics, value)})  # fmt: skip
    return pd.DataFrame(rows)


class TestWhatWasTrainedAndThePaper:
    """Issue 38: a row is shown under what it trained (Table 5's "with AGTFM" row runs quick's
    matching encoder plain), the paper's number beside it still names the paper's model, the
    headers say mean, and the constant predictor's error stands beside the paper's numbers."""

    @staticmethod
    def _plan(profile: str):
        from test_plan import SPLITS as ALL_SPLITS

        specs = load_specs(None, ["table5"])
        units = plan_units(specs, get_repro_profile(profile), [0], Path("/d"), ALL_SPLITS, "h")
        return specs[0], units

    def test_the_label_follows_the_trained_model(self):
        from benchmark.runner.report.training import relabel_note, shown_labels

        _, units = self._plan("quick")
        shown = shown_labels("table5", units)
        assert shown == {"Pd/Re-Net with AGTFM": "Pd/Re-Net · matching encoder, plain"}
        assert "asks for the encoder variant `a-f` (AGTFM)" in relabel_note("table5", units)
        _, smoke = self._plan("smoke")  # GoogLeNet: the row trains AGTFM, its label stays
        assert shown_labels("table5", smoke) == {} and relabel_note("table5", smoke) == ""
        unit = next(u for u in units if any(j.label == "Re-Net" for j in u.jobs))
        unit.cfg = dataclasses.replace(
            unit.cfg, model=dataclasses.replace(unit.cfg.model, variant="a")
        )  # another trained model: another label
        assert shown_labels("table5", units)["Re-Net"] == "Re-Net-R · matching encoder, attention"

    def test_table5_shows_means_the_papers_row_and_the_constant(self):
        from benchmark.runner.report.tables import CONSTANT_LABEL
        from benchmark.runner.report.training import shown_labels

        spec, units = self._plan("quick")
        constant = {"flight/pitch0": 92.83, "flight/pitch-10": 98.83, "flight/pitch-50": 76.37}
        values = {(CONSTANT_LABEL, split): v for split, v in constant.items()}
        summary = summarize(_table_rows(spec, values), list(spec.metrics))
        text = markdown_table(spec, summary, PAPER, [CONSTANT_LABEL], False, frozenset(), [],
                              shown_labels("table5", units))  # fmt: skip
        header = next(x for x in text.splitlines() if x.startswith("| split |"))
        cols = [c.strip() for c in header.strip("|").split("|")]
        assert cols[:3] == ["split", "model", "paper's row"]
        i = cols.index("δψ yaw (°) paper (mean)")
        assert cols[i + 1 : i + 3] == ["δψ yaw (°) constant (mean)", "δψ yaw (°) ours (mean)"]
        table = text.split("Satellite-swap probe")[0]
        models = [x.split(" | ")[1] for x in table.splitlines() if x.startswith("| `flight/")]
        assert "Pd/Re-Net with AGTFM" not in models  # the model column says what trained
        line = next(
            x
            for x in table.splitlines()
            if x.startswith("| `flight/pitch0` | Pd/Re-Net · matching encoder, plain |")
        )
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[2] == "Pd/Re-Net with AGTFM" and cells[i] == "87.49"  # the paper's row
        assert cells[i + 1] == "92.83" and cells[i + 2] == "50.00"
        # the sentence under it, from the same numbers
        paper_psi = [
            (paper_value(PAPER, 5, name, model, "dpsi_deg"), constant[split])
            for split, name in zip(spec.eval_splits, spec.paper_splits, strict=True)
            for model in ("Pd/Re-Net with AGTFM", "Re-Net")
        ]
        reached = sum(p >= c for p, c in paper_psi)
        low, high = min(p for p, _ in paper_psi), max(p for p, _ in paper_psi)
        assert (f"δψ yaw (°): constant 76.37–98.83, paper {low:.2f}–{high:.2f} ({reached} of 6 "
                "paper numbers at or above the constant's on their split)") in text  # fmt: skip
        assert "every median is named so" in text


class TestReportNumbers:
    """Every number of the report is computed before it is written, the intervals as work items
    in a spawn pool: the same numbers with one process or two."""

    def test_the_same_with_any_number_of_workers(self, synthetic):
        from benchmark.runner.claims.report_numbers import ReportInputs, report_numbers
        from benchmark.runner.plan.partial import MergePlan

        specs, units, results, _, workdir = synthetic
        inputs = ReportInputs([], {}, ReferenceResults(), [], {}, {}, {})
        merge = MergePlan(run=list(specs))
        one, two = (
            report_numbers(specs, units, results, workdir.parent / "data", workdir, merge=merge,
                           inputs=inputs, workers=w, quiet=True)
            for w in (1, 2)
        )  # fmt: skip
        assert set(one.summaries) == {s.name for s in specs if s.kind != "sequence"}
        for name, summary in one.summaries.items():
            pd.testing.assert_frame_equal(summary, two.summaries[name])
        pd.testing.assert_frame_equal(one.everything, two.everything)
        assert one.claims_md == two.claims_md and one.findings_md == two.findings_md
        # the flight x seed bootstrap replaced the Student-t interval over seeds
        table1 = one.summaries["table1"]
        assert (table1.loc[table1["role"] == "test", "interval"] != "seed t").all()
