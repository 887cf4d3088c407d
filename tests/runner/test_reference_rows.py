"""The non-learned reference rows of the tables (issue 21, item 5): the spec field, the frame
stride, evaluation with its cache on the smoke dataset, the rendered rows, and that no claim about
the heads sees them."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_frames import Repro

import benchmark.references as references_module
from benchmark.evaluation.paired import swap_effect
from benchmark.references import get_reference_class, list_references
from benchmark.runner.claims.all_claims import evaluate_claims
from benchmark.runner.claims.findings import findings_markdown
from benchmark.runner.claims.report_numbers import REPORT_METRICS
from benchmark.runner.claims.spread import FRAME_METRICS, read_frames
from benchmark.runner.claims.table_intervals import summarize
from benchmark.runner.execute import reference_rows as rr
from benchmark.runner.plan.specs import SpecError, default_spec_dir, load_spec
from benchmark.runner.report.tables import NO_VAL, markdown_table

STD = "standard/test"
TABLES = ("table1", "table2", "towns", "extended")
SPEC_HEAD = """# Beyond the paper: reference rows under test.
name: refs
title: References under test
kind: {kind}
train_split: standard/train
eval_splits: [standard/test]
metrics: [dpsi_deg, dphi_deg]
swap_metrics: [dpsi_deg, dphi_deg]
rows:
  - {{label: Pd/Re-Net, paper_model: Pd/Re-Net, attitude: pd_re_net}}
"""


def write_spec(tmp_path: Path, references: str, kind: str = "table") -> Path:
    text = SPEC_HEAD.format(kind=kind) + f"references: {references}\n"
    if kind == "sweep":
        text += "sweep: h\nsweep_values: ['1']\n"
    path = tmp_path / "refs.yaml"
    path.write_text(text)
    return path


class TestSpecField:
    @pytest.mark.parametrize("table", TABLES)
    def test_the_four_tables_list_the_three_references(self, table):
        spec = load_spec(default_spec_dir() / f"{table}.yaml")
        assert spec.references == ("geometry_oracle", "gravity_template", "feature_pnp")
        labels = rr.reference_labels(spec)
        assert all("not learned" in label and "given" in label for label in labels)
        assert "oracle" in labels[0].lower()

    def test_good_names_in_order(self, tmp_path):
        spec = load_spec(write_spec(tmp_path, "[feature_pnp, geometry_oracle]"))
        assert spec.references == ("feature_pnp", "geometry_oracle")

    def test_absent_is_none(self):
        assert load_spec(default_spec_dir() / "table5.yaml").references == ()

    @pytest.mark.parametrize(
        ("value", "kind", "message"),
        [
            ("[geometry_oracle, sift_magic]", "table", r"references\[1\] 'sift_magic' is not a"),
            ("geometry_oracle", "table", "references must be a list"),
            ("[geometry_oracle, geometry_oracle]", "table", "lists a name twice"),
            (
                "[geometry_oracle]",
                "sweep",
                "references are rows of a table or a sequence; kind 'sweep'",
            ),
        ],
    )
    def test_bad_values_name_the_file_and_field(self, tmp_path, value, kind, message):
        path = write_spec(tmp_path, value, kind)
        with pytest.raises(SpecError, match=message) as err:
            load_spec(path)
        assert str(path) in str(err.value)
        if "not a" in message:
            assert all(name in str(err.value) for name in list_references())


class TestStride:
    def test_every_kth_frame_of_each_flight(self):
        flights = ["a", "a", "a", "b", "b", "a", "c"]
        assert rr.strided_rows(flights, 2) == [0, 2, 3, 6]  # a: 1st, 3rd; b: 1st; c: 1st
        assert rr.strided_rows(flights, 1) == list(range(7))
        assert rr.strided_rows(flights, 10) == [0, 3, 6]  # every flight keeps a frame

    def test_stride_below_one(self):
        with pytest.raises(ValueError, match="stride must be >= 1"):
            rr.strided_rows([1, 2], 0)


def oracle_spec(tmp_path: Path):
    return load_spec(write_spec(tmp_path, "[geometry_oracle]"))


@pytest.fixture()
def counted(monkeypatch):
    """Count the evaluations actually run (``run_chunk`` imports it from the package)."""
    calls = []
    real = references_module.evaluate_reference

    def counting(reference, dataset, **kwargs):
        calls.append((reference.name, dataset.satellite))
        return real(reference, dataset, **kwargs)

    monkeypatch.setattr(references_module, "evaluate_reference", counting)
    return calls


class TestSequenceReferences:
    """A sequence spec's references: its splits and its training split's validation split (where
    the fusion density is calibrated), the true image only; then fused beside the heads."""

    def spec(self, tmp_path: Path):
        text = (
            SPEC_HEAD.format(kind="sequence").replace(
                "eval_splits: [standard/test]", "eval_splits: [long/standard]"
            )
            + "references: [geometry_oracle]\n"
        )
        path = tmp_path / "seq" / "refs.yaml"
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
        return load_spec(path)

    def test_splits_and_modes(self, tmp_path):
        wanted = rr._wanted([self.spec(tmp_path)], ["standard/val", "long/standard"])
        assert wanted == [("geometry_oracle", "long/standard", ("true",)),
                          ("geometry_oracle", "standard/val", ("true",))]  # fmt: skip
        # no validation split in the dataset: the test split alone
        assert rr._wanted([self.spec(tmp_path)], ["long/standard"]) == [wanted[0]]

    def test_a_table_on_the_same_split_adds_the_swap(self, tmp_path):
        table = load_spec(write_spec(tmp_path, "[geometry_oracle]"))
        wanted = rr._wanted([self.spec(tmp_path), table], ["standard/val", "standard/test"])
        assert ("geometry_oracle", STD, ("true", "swap")) in wanted

    @pytest.mark.slow
    def test_fused_beside_the_heads(self, tmp_path, smoke_dataset, counted):
        from benchmark.runner.claims.sequence_errors import non_learned_sequences, sequence_rows
        from benchmark.runner.execute.non_learned import fuse_non_learned
        from benchmark.runner.report.tables import CONSTANT_LABEL

        spec = self.spec(tmp_path)
        refs = rr.evaluate_references([spec], smoke_dataset, tmp_path / "w", "smoke", quiet=True)
        assert sorted(counted) == [("geometry_oracle", "true")] * 2  # long/standard, standard/val
        fused = fuse_non_learned([spec], refs, smoke_dataset, quiet=True)
        items = non_learned_sequences(fused[spec.name])
        labels = [i.label for i in items]
        assert labels == [CONSTANT_LABEL, get_reference_class("geometry_oracle").label]
        assert not any(i.learned for i in items)
        assert [i.position_given for i in items] == [False, True]
        rows = sequence_rows(items)
        assert set(rows["mode"]) == {"frame", "filter", "smooth"}
        # per frame, the fused tables score what the reference tables score
        frame = refs.table_frame("geometry_oracle", "long/standard", "true", spec.train_split)
        oracle = rows[(rows["label"] == labels[1]) & (rows["mode"] == "frame")].iloc[0]
        assert oracle["mean_dpsi_deg"] == pytest.approx(frame["dpsi_deg"].mean(), abs=1e-6)


class TestEvaluateAndCache:
    def test_written_then_read_back(self, tmp_path, smoke_dataset, counted):
        spec, work = oracle_spec(tmp_path), tmp_path / "work"
        first = rr.evaluate_references([spec], smoke_dataset, work, "smoke", quiet=True)
        assert sorted(counted) == [("geometry_oracle", "swap"), ("geometry_oracle", "true")]
        csv, js = rr.reference_paths(work, "geometry_oracle", STD, "swap")
        assert csv.name == "standard__test__swap.csv" and js.is_file()
        record = json.loads(js.read_text())
        assert record["given"] == list(get_reference_class("geometry_oracle").given)
        assert record["stride"] == 1 and record["frames"] == len(pd.read_csv(csv))
        # The swap effect as a model's, in a table: swap_effect of the two cached CSVs (the
        # oracle gives up on no frame here, so no frame takes the constant's pose).
        true_csv = rr.reference_paths(work, "geometry_oracle", STD, "true")[0]
        assert not pd.read_csv(true_csv)["reference_failed"].any()
        expected = swap_effect(pd.read_csv(true_csv), pd.read_csv(csv))
        got = first.table_summary("geometry_oracle", STD, "swap", "standard/train")
        for key, value in expected.items():
            assert got[key] == pytest.approx(value)
        # The model's predictions format: the bootstrap's reader takes it as a model's CSV.
        frames = read_frames([true_csv, true_csv])
        assert set(FRAME_METRICS) <= set(frames.columns) and "flight" in frames

        counted.clear()
        second = rr.evaluate_references([spec], smoke_dataset, work, "smoke", quiet=True)
        assert counted == []  # nothing evaluated again
        assert second.summaries == first.summaries
        pd.testing.assert_frame_equal(
            second.frames["geometry_oracle", STD, "true"],
            first.frames["geometry_oracle", STD, "true"],
        )

    def test_incomplete_or_other_stride_is_evaluated_again(
        self, tmp_path, smoke_dataset, counted, monkeypatch
    ):
        spec, work = oracle_spec(tmp_path), tmp_path / "work"
        rr.evaluate_references([spec], smoke_dataset, work, "smoke", quiet=True)
        # No JSON (killed before it was written): the true one again, and the swap one, whose
        # swap effect compares with the new true frames.
        rr.reference_paths(work, "geometry_oracle", STD, "true")[1].unlink()
        counted.clear()
        rr.evaluate_references([spec], smoke_dataset, work, "smoke", quiet=True)
        assert sorted(counted) == [("geometry_oracle", "swap"), ("geometry_oracle", "true")]
        # Another stride for this profile: evaluated again, on 1 frame in 2 of each flight.
        monkeypatch.setitem(rr.PROFILE_STRIDE, "smoke", 2)
        counted.clear()
        out = rr.evaluate_references([spec], smoke_dataset, work, "smoke", quiet=True)
        assert len(counted) == 2
        record = out.record("geometry_oracle", STD, "true")
        assert record["stride"] == 2
        frame = out.frames["geometry_oracle", STD, "true"]
        assert list(frame["index"]) == rr.strided_rows(_flights(smoke_dataset), 2)
        assert "1 in 2 of each flight" in rr.reference_note(spec, out)

    def test_chunks_put_together_are_one_evaluation(self, tmp_path, smoke_dataset, counted):
        spec = oracle_spec(tmp_path)
        whole = rr.evaluate_references([spec], smoke_dataset, None, "smoke", quiet=True)
        counted.clear()
        parts = rr.evaluate_references(
            [spec], smoke_dataset, None, "smoke", quiet=True, chunk_frames=1
        )
        key = ("geometry_oracle", STD, "swap")
        assert len(counted) == 2 * len(whole.frames[key]) > 2  # one call per frame
        pd.testing.assert_frame_equal(parts.frames[key], whole.frames[key])
        timings = set(rr.TIMING_KEYS)
        for k, summary in whole.summaries.items():
            got = {m: v for m, v in parts.summaries[k].items() if m not in timings}
            assert got == pytest.approx({m: v for m, v in summary.items() if m not in timings})

    def test_the_reproductions_workers_bound_the_processes(
        self, tmp_path, smoke_dataset, monkeypatch
    ):
        spec = oracle_spec(tmp_path)
        monkeypatch.setattr(rr, "PARALLEL_MIN_FRAMES", 0)  # any number of frames takes the pool
        monkeypatch.setattr(rr.os, "cpu_count", lambda: 8)
        pools = []
        inline = rr.execute_items

        def inline_pool(items, processes, on_done, quiet, *args):  # runs here, records its size
            pools.append(processes)
            inline(items, 1, on_done, quiet, *args)

        monkeypatch.setattr(rr, "execute_items", inline_pool)
        kwargs = {"quiet": True, "chunk_frames": 1}  # a chunk per frame: more than 3 chunks
        one = rr.evaluate_references([spec], smoke_dataset, None, "smoke", max_processes=1,
                                     **kwargs)  # fmt: skip
        assert pools == [1]  # one process: this one
        three = rr.evaluate_references([spec], smoke_dataset, None, "smoke", max_processes=3,
                                       **kwargs)  # fmt: skip
        assert pools == [1, 3]
        for key, frame in one.frames.items():
            pd.testing.assert_frame_equal(frame, three.frames[key])

    def test_an_error_costs_the_rows_not_the_report(self, tmp_path, smoke_dataset, monkeypatch):
        def broken(reference, dataset, **kwargs):
            raise RuntimeError("cv2 exploded\nsecond line")

        monkeypatch.setattr(references_module, "evaluate_reference", broken)
        spec = oracle_spec(tmp_path)
        out = rr.evaluate_references([spec], smoke_dataset, tmp_path / "w", "smoke", quiet=True)
        assert out.summaries == {} and rr.reference_rows([spec], out) == []
        assert out.errors["geometry_oracle", STD, "true"] == "RuntimeError: cv2 exploded"
        assert "not run (RuntimeError: cv2 exploded)" in rr.reference_note(spec, out)


def _flights(root: Path) -> list:
    from benchmark.data import PairDataset
    from benchmark.evaluation.evaluate import pair_columns

    return list(pair_columns(PairDataset(root, STD, verify="size"))["flight"])


@pytest.fixture(scope="module")
def table1_references(tmp_path_factory, smoke_dataset):
    """table1's three references evaluated on the smoke dataset (cached in a work directory)."""
    spec = load_spec(default_spec_dir() / "table1.yaml")
    work = tmp_path_factory.mktemp("ref-work")
    return spec, rr.evaluate_references([spec], smoke_dataset, work, "smoke", quiet=True)


class TestRenderedRows:
    def test_rows_and_labels_in_the_table(self, table1_references):
        spec, results = table1_references
        rows = pd.DataFrame(rr.reference_rows([spec], results))
        assert len(rows) == 3 * 2  # three references, true and swapped image, one split
        assert set(rows["reference"]) == set(spec.references)
        assert (rows["seed"] == 0).all() and (rows["role"] == "test").all()
        assert not {"frames_per_s", "cpu_ms_per_frame"} & set(rows.columns)
        summary = summarize(rows, [m for m in REPORT_METRICS if m in rows])
        labels = rr.reference_labels(spec)
        text = markdown_table(spec, summary, pd.DataFrame(), [], True, frozenset(), labels)
        main, probe = text.split("Satellite-swap probe")
        for label, name in zip(labels, spec.references, strict=True):
            line = next(x for x in main.splitlines() if x.startswith(f"| {label}"))
            true = results.table_summary(name, STD, "true", "standard/train")
            assert "not run" not in line
            assert line.count(f" {NO_VAL} |") >= 2  # no validation split: not "not run"
            probe_line = next(x for x in probe.splitlines() if f"| {label}" in x)
            swap = results.table_summary(name, STD, "swap", "standard/train")
            if true["failure_rate"] == 1.0:  # no estimate of its own: no number either
                assert f"{true['dpsi_deg']:.2f}" not in line
                cells = [c.strip() for c in line.strip("|").split("|")]
                shown = len(spec.metrics) + len(spec.swap_metrics)
                assert cells.count("fails on 100 % of frames") == shown
                assert probe_line.count("fails on 100 % of frames") == 7  # every cell, verdict
                continue
            assert f"{true['dpsi_deg']:.2f}" in line
            assert f"{swap['swap_dpsi_diff_deg']:+.2f}" in probe_line
        note = rr.reference_note(spec, results)
        assert "part of no claim about the heads" in note
        assert "reads the true position E, N, U, pitch, roll" in note
        assert "reads no true pose value" in note

    def test_columns_do_not_depend_on_where_the_summary_came_from(self, table1_references):
        """A summary computed in this run and the same read back from the cache (JSON, sorted
        keys) give the same columns in the same order: results.csv is the same bytes."""
        spec, results = table1_references
        reordered = {key: dict(reversed(list(summary.items())))
                     for key, summary in results.summaries.items()}  # fmt: skip
        again = dataclasses.replace(results, summaries=reordered)
        first = pd.DataFrame(rr.reference_rows([spec], results))
        second = pd.DataFrame(rr.reference_rows([spec], again))
        assert list(first.columns) == list(second.columns)
        pd.testing.assert_frame_equal(first, second)

    def test_the_note_says_how_failures_read(self):
        spec = load_spec(default_spec_dir() / "table1.yaml")  # trains on standard/train
        record = {"frames": 10, "stride": 1, "train_split": "towns/train",
                  "summary": {"failure_rate": 0.005, "cpu_ms_per_frame": 40.0}}  # fmt: skip
        results = rr.ReferenceResults(records={("feature_pnp", STD, "true"): record})
        note = rr.reference_note(spec, results)
        # one fallback, the table's constant row: an evaluation's own split is never named
        assert "towns/train" not in note and "the pose of this table's constant row" in note
        assert "10 frames, failed <1 %" in note  # a rate above zero never reads 0 %
        assert "reads `fails on 100 % of frames` in its cells" in note
        assert "`standard/test` not run" in note  # the two others: no record

    def test_cells_get_the_flight_bootstrap_of_the_reference_frames(self):
        from benchmark.runner.claims.table_intervals import reference_interval

        rng = np.random.default_rng(0)
        frame = pd.DataFrame({"index": range(60), "flight": np.repeat(np.arange(12), 5),
                              **{m: rng.gamma(2.0, 3.0, 60) for m in FRAME_METRICS}})  # fmt: skip
        label = get_reference_class("geometry_oracle").label
        results = rr.ReferenceResults(frames={("geometry_oracle", STD, "true"): frame})
        part = pd.DataFrame([{"label": label, "split": STD, "satellite": "true",
                              "train_split": "standard/train",
                              "reference": "geometry_oracle"}])  # fmt: skip
        got = reference_interval(part, ["dpsi_deg", "acc10"], results)
        mean = frame["dpsi_deg"].mean()
        assert got["interval"] == "flight×seed bootstrap" and got["n_flights"] == 12
        assert got["dpsi_deg_lo"] < mean < got["dpsi_deg_hi"]
        acc = (frame["dphi_deg"] <= 10.0).mean()  # acc@10°: bootstrapped as the errors are
        assert 0.0 <= got["acc10_lo"] < acc < got["acc10_hi"] <= 1.0
        model_row = part.assign(reference=float("nan"), label="Pd/Re-Net")
        assert reference_interval(model_row, ["dpsi_deg"], results) is None

    def test_the_swap_interval_is_the_models(self, table1_references):
        """A reference's swap effect in a table: the claims' bootstrap of its per-frame rise, as
        a model's with one seed (``N_BOOT`` replicates), not the cached flight bootstrap."""
        from benchmark.runner.claims.evidence import N_BOOT
        from benchmark.runner.claims.spread import seed_flight_bootstrap
        from benchmark.runner.claims.table_intervals import row_interval

        _spec, results = table1_references
        name, train = "gravity_template", "standard/train"
        part = pd.DataFrame([{"label": get_reference_class(name).label, "split": STD,
                              "satellite": "swap", "train_split": train,
                              "reference": name}])  # fmt: skip
        got = row_interval(part, ["dpsi_deg"], None, {}, results)
        true = results.table_frame(name, STD, "true", train).sort_values("index")
        swap = results.table_frame(name, STD, "swap", train).sort_values("index")
        rise = swap["dphi_deg"].to_numpy() - true["dphi_deg"].to_numpy()
        _, lo, hi = seed_flight_bootstrap(rise, true["flight"].to_numpy(), n_boot=N_BOOT)
        assert (got["swap_dphi_boot_lo_deg"], got["swap_dphi_boot_hi_deg"]) == (lo, hi)

    def test_kept_tables_read_the_cache(self, table1_references):
        spec, results = table1_references
        cold = rr.ReferenceResults(workdir=results.workdir)  # a later report, nothing evaluated
        label = rr.reference_labels(spec)[1]
        pd.testing.assert_frame_equal(
            cold.frame_of(label, STD, "swap", "standard/train"),
            results.frames["gravity_template", STD, "swap"],
        )
        assert cold.frame_of("Pd/Re-Net", STD, "true", "standard/train") is None


SPLIT_IN_TWO = """# Beyond the paper: one split in two tables.
name: {name}
title: {name}
kind: table
train_split: {train}
eval_splits: [towns/test]
metrics: [dpsi_deg, dphi_deg]
swap_metrics: [dpsi_deg, dphi_deg]
rows:
  - {{label: Pd/Re-Net, paper_model: Pd/Re-Net, attitude: pd_re_net}}
references: [feature_pnp]
"""


class TestOneFallback:
    """A failed reference frame gets the pose of its table's constant row, whatever the split:
    the constant predictor of that table's training split (issue 38: on towns/test the encoders
    table's PnP row read the towns/train mean beside a constant row of standard/train)."""

    def test_one_split_in_two_tables_gets_each_tables_constant(
        self, tmp_path, smoke_dataset, counted
    ):
        specs = []
        for name, train in (("enc", "standard/train"), ("towns", "towns/train")):
            path = tmp_path / f"{name}.yaml"
            path.write_text(SPLIT_IN_TWO.format(name=name, train=train))
            specs.append(load_spec(path))
        results = rr.evaluate_references(specs, smoke_dataset, tmp_path / "w", "smoke", True)
        assert sorted(counted) == [("feature_pnp", "swap"), ("feature_pnp", "true")]  # once
        rows = pd.DataFrame(rr.reference_rows(specs, results))
        assert (rows["failure_rate"] == 1.0).all()  # PnP gives up on every smoke frame
        means = {}
        for spec in specs:
            train = spec.train_split
            constant, frame = rr.constant_baseline(smoke_dataset, train, "towns/test")
            for satellite in ("true", "swap"):  # the constant reads no image
                row = rows[(rows.table == spec.name) & (rows.satellite == satellite)].iloc[0]
                assert row["train_split"] == train
                for m in ("dtheta_deg", "dpsi_deg", "dphi_deg", "dE_m", "dU_m"):
                    assert row[m] == pytest.approx(constant[m], rel=1e-12), (spec.name, m)
            got = results.table_frame("feature_pnp", "towns/test", "true", train)
            np.testing.assert_allclose(got["dpsi_deg"], frame["dpsi_deg"], rtol=1e-12)
            means[train] = constant["dpsi_deg"]
        assert means["standard/train"] != pytest.approx(means["towns/train"])

    def test_some_failed_frames_take_the_constant_and_say_how_many(self, table1_references):
        spec, results = table1_references
        name, train = "gravity_template", "standard/train"
        mixed = rr.ReferenceResults(frames=dict(results.frames), data_root=results.data_root)
        failed = np.arange(len(results.frames[name, STD, "true"])) % 4 == 1  # a quarter
        for satellite in ("true", "swap"):
            own = results.frames[name, STD, satellite]
            mixed.frames[name, STD, satellite] = own.assign(reference_failed=failed)
        frame = mixed.table_frame(name, STD, "true", train)
        constant = rr.constant_baseline(results.data_root, train, STD)[1].set_index("index")
        own = results.frames[name, STD, "true"]
        for column in ("dpsi_deg", "dE_m", "Rhat01", "yaw_hat_deg"):
            expected = np.where(failed, constant.loc[own["index"], column], own[column])
            np.testing.assert_allclose(frame[column], expected, rtol=1e-12)
        summary = mixed.table_summary(name, STD, "true", train)
        assert summary["failure_rate"] == pytest.approx(failed.mean())
        assert summary["dpsi_deg"] == pytest.approx(frame["dpsi_deg"].mean())
        rows = pd.DataFrame([r for r in rr.reference_rows([spec], mixed) if r["reference"] == name])
        table = summarize(rows, [m for m in REPORT_METRICS if m in rows])
        text = markdown_table(spec, table, pd.DataFrame(), [], True, frozenset(),
                              rr.reference_labels(spec))  # fmt: skip
        label = get_reference_class(name).label
        line = next(x for x in text.splitlines() if x.startswith(f"| {label} ("))
        pct = f"{100 * failed.mean():.0f} %"
        assert line.startswith(f"| {label} (fails on {pct} of frames) |")
        assert f"{summary['dpsi_deg']:.2f}" in line and "fails on 100" not in line


class TestNoClaimSeesThem:
    def test_same_claims_with_and_without_reference_rows(self, tmp_path, table1_references):
        """A synthetic reproduction (heads that win, lose and sit at the constant's level on
        table1 and extended) decided twice: with the reference rows in the summaries and an
        oracle's near-perfect predictions cached in the work directory, and without. Every
        verdict, number and sentence is the same, and no claim names a reference."""
        spec, results = table1_references
        repro = Repro(tmp_path)
        for table in ("table1", "extended"):
            repro.add(table, "Pd/Re-Net", {STD: 5.0})
            repro.add(table, "Re-Net-R", {STD: 12.0})
            repro.add(table, "Pd-Net-E", {STD: "constant"})
        store = repro.store()
        rows = pd.DataFrame(
            [{"table": t, "label": "Pd/Re-Net", "paper_model": "", "x": None, "split": STD,
              "satellite": "true", "satellite_input": "image", "train_split": "standard/train",
              "role": "test", "seed": 0, "dphi_deg": 5.0} for t in ("table1", "extended")]
        )  # fmt: skip
        without = {
            t: summarize(rows[rows.table == t], ["dphi_deg"]) for t in ("table1", "extended")
        }
        refs = pd.DataFrame(rr.reference_rows([spec], results))
        refs = pd.concat([refs, refs.assign(table="extended")], ignore_index=True)
        everything = pd.concat([rows, refs], ignore_index=True)
        with_refs = {
            t: summarize(everything[everything.table == t], ["dphi_deg"])
            for t in ("table1", "extended")
        }
        # An oracle in the work directory, far better than every head, in the models' format.
        src = next((repro.workdir / "units").glob("table1-Pd_Re-Net-None-0/eval/*.csv"))
        for name in spec.references:
            dst = rr.reference_paths(repro.workdir, name, STD, "true")[0]
            dst.parent.mkdir(parents=True, exist_ok=True)
            frame = pd.read_csv(src)
            frame[list(FRAME_METRICS)] = 0.01
            frame.to_csv(dst, index=False)
            dst.with_suffix(".json").write_text(json.dumps({"reference": name, "frames": 60}))

        a = evaluate_claims(without, store)
        b = evaluate_claims(with_refs, repro.store())
        assert [_digest(c) for c in a] == [_digest(c) for c in b]
        assert findings_markdown(a) == findings_markdown(b)
        assert any(c.verdict == "supported" for c in a)  # the claims did decide something
        labels = rr.reference_labels(spec)
        for c in b:
            text = " ".join([c.claim, c.evidence, c.difference, json.dumps(c.facts, default=str)])
            assert not any(label in text for label in labels)
            assert "oracle" not in text.lower()
        assert not set(labels) & (set(store.labels("table1")) | set(store.labels("extended")))


def _digest(claim) -> tuple:
    comps = [(c.where, c.verdict, _num(c.diff), _num(c.lo), _num(c.hi)) for c in claim.comparisons]
    return claim.claim, claim.verdict, claim.evidence, claim.difference, comps, claim.excluded


def _num(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(x, 9)


def test_the_tracker_descriptions_name_what_each_reference_is_given():
    from benchmark.runner.report.descriptions import table_experiment

    text = table_experiment(load_spec(default_spec_dir() / "table1.yaml"), "quick")
    for name in ("geometry_oracle", "gravity_template", "feature_pnp"):
        assert f"`{name}`: reads" in text
    assert "not learned; given true position, pitch, roll" in text
    assert "not learned" not in table_experiment(load_spec(default_spec_dir() / "fig5.yaml"), "q")
