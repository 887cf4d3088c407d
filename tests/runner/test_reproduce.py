"""``uavbench reproduce`` end to end on the smoke profile: every table, idempotence, failures."""

from __future__ import annotations

import dataclasses
import json
import os
import re

import pandas as pd
import pytest
from interrupt_tools import ctrl_c_while_training

from benchmark.cli import main
from benchmark.runner import ReproduceConfig
from benchmark.runner import reproduce as run_reproduction
from benchmark.runner.execute.pool import ExecutorConfig
from benchmark.runner.plan import repro_profiles as profiles_module
from benchmark.runner.plan.specs import load_specs


def reproduce(tmp_path, dataset, *extra: str) -> int:
    out, workdir = str(tmp_path / "reports"), str(tmp_path / "runs")
    return main([
        "reproduce", "--profile", "smoke", "--data", str(dataset), "--out", out,
        "--workdir", workdir, "--tracker", "local", "--quiet", *extra,
    ])  # fmt: skip


def run_statuses(tmp_path) -> list[dict]:
    return [json.loads(p.read_text()) for p in (tmp_path / "tracking-local").rglob("run.json")]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory, smoke_dataset):
    """Every table and figure of the smoke profile, run once for this module."""
    tmp = tmp_path_factory.mktemp("repro")
    previous = os.getcwd()
    os.chdir(tmp)  # the tracking store lives in the working directory
    try:
        # Logged models are checked by tests/tracking/test_reproduce_on_server.py.
        code = reproduce(tmp, smoke_dataset, "--workers", "1", "--no-models")
    finally:
        os.chdir(previous)
    return tmp, code


class TestReproduceSmoke:
    def test_exit_code_and_every_report(self, full_run):
        tmp, code = full_run
        assert code == 0
        reports = tmp / "reports"
        for spec in load_specs():
            text = (reports / f"{spec.name}.md").read_text()
            assert "not run" not in text, spec.name
            if spec.kind in ("sweep", "sequence"):
                assert (reports / f"{spec.name}.png").stat().st_size > 0
        # issue 39: every head fused on every split of the sequence table, three estimates each
        sequence = load_specs(only=["sequence"])[0]
        text = (reports / "sequence.md").read_text()
        for split in sequence.eval_splits:
            assert f"## {split}\n" in text, split
        for row in sequence.rows:
            # a row that takes the pitch and roll of the best head on validation names that head
            chosen = r" \([^|)]+\)" if row.pitch_roll == "best_on_val" else ""
            for estimate in ("per frame", "filtered", "smoothed"):
                line = rf"\| {re.escape(row.label)}{chosen} \| {estimate} \| "
                assert re.search(line, text), (row.label, estimate)
        readme = (reports / "README.md").read_text()
        # fifteen claims of the paper and its controls, and one ranking claim per test split of
        # table extended, the three fusion claims of the sequence table (issue 39), each with a
        # verdict, and the confirmation draw's cell beside it
        rows = [line for line in readme.splitlines() if re.match(r"\| \d+ \| ", line)]
        assert len(rows) == 20
        assert all(re.search(r" \| \*\*[a-z ()]+\*\* \| ", row) for row in rows)
        confirmation = [row.split(" | ")[6] for row in rows]
        assert all(
            c.startswith("**") or c == "– (no confirmation split for its test splits)"
            for c in confirmation
        )
        assert sum(c.startswith("**") for c in confirmation) >= 10  # decided on confirm/* too
        table1 = (reports / "table1.md").read_text()
        assert "| UAV-only control |" in table1 and "swapped sat." in table1
        assert "Satellite-swap probe" in table1
        # the data audit: one row per audited split (val and test of both families) with ratios
        audit = (reports / "heading_cue.md").read_text()
        for split in ("standard/val", "standard/test", "generalized/test", "towns/test"):
            row = next(line for line in audit.splitlines() if f"| {split} |" in line)
            cell = row.rstrip(" |").rsplit("|", 1)[1]  # "0.795 [0.692, 0.921]"
            ratio, lo, hi = (float(v) for v in cell.replace("[", " ").replace(",", " ")
                             .replace("]", " ").split())  # fmt: skip
            assert 0.0 < ratio < 10.0 and lo <= ratio <= hi, row
        assert "Heading-cue audit" in readme and "heading_cue.md" in readme
        # the verdict reads the standard splits pooled over the dataset and 4 more seeds
        assert audit.count("| pooled |") == 2 and "pooled over 5 datasets" in readme

    def test_results_cover_every_job_and_split(self, full_run):
        tmp, _ = full_run
        results = pd.read_csv(tmp / "reports" / "results.csv")
        expected = {
            (s.name, j.label, str(j.x), split)
            for s in load_specs()
            for j in s.jobs()
            for split in j.eval_splits
        }
        for satellite in ("true", "swap"):
            got = {
                (r.table, r.label, str(r.x) if pd.notna(r.x) else "None", r.split)
                for r in results[results.satellite == satellite].itertuples()
            }
            assert expected <= got, satellite
        swapped = results[(results.satellite == "swap") & (results.satellite_input != "none")]
        assert swapped[["swap_dpsi_diff_deg", "swap_dphi_boot_lo_deg"]].notna().all().all()
        control = swapped[swapped.satellite_input == "blank"]
        # it sees no image; on flight/* the swapped image has another footprint (its city has
        # a footprint of its own, benchmark.data.swap), which the matching encoder's context
        # carries, so only there a blank control's prediction may move
        same_footprint = control[~control.split.str.startswith("flight/")]
        assert len(same_footprint) and (same_footprint.swap_dpsi_diff_deg == 0).all()
        trained = results[results.label != "Constant (train mean)"]
        assert trained[["dphi_deg", "dE_m"]].notna().all().all()

    def test_validation_beside_test(self, full_run):
        tmp, _ = full_run
        results = pd.read_csv(tmp / "reports" / "results.csv")
        val = results[results.role == "val"]
        assert set(val.split) >= {"standard/val", "towns/val"}
        assert not val.train_split.str.startswith("height").any()  # heights have no val split
        table1 = (tmp / "reports" / "table1.md").read_text()
        assert "δφ geodesic (°) val" in table1 and "`standard/val` for `standard/train`" in table1
        fig5 = (tmp / "reports" / "fig5.md").read_text().splitlines()
        header = next(x for x in fig5 if x.startswith("| split |")).split(" | ")
        i = header.index("δφ geodesic (°) val")  # shown, but the height models have none
        rows = [x.split(" | ") for x in fig5 if x.startswith("| `height")]
        assert rows and all(r[i] == "–" for r in rows)

    def test_provenance(self, full_run, smoke_dataset):
        import hashlib

        from benchmark.runner.report.provenance import compare_provenance

        tmp, _ = full_run
        reports = tmp / "reports"
        record = json.loads((reports / "provenance.json").read_text())
        manifest = hashlib.sha256((smoke_dataset / "manifest.json").read_bytes()).hexdigest()
        assert record["dataset"]["manifest_sha256"] == manifest
        assert "[provenance.md](provenance.md)" in (reports / "README.md").read_text()
        assert compare_provenance(reports / "provenance.json", record) == []
        units = record["units"]
        assert units, "reproduce must pass workdir= to write_reports (per-unit digests)"
        for key, digests in units.items():
            ckpt = tmp / "runs" / "units" / key / "train" / "checkpoint.pt"
            assert (
                digests["checkpoint_file_sha256"] == hashlib.sha256(ckpt.read_bytes()).hexdigest()
            )
            csv = tmp / "runs" / "units" / key / "eval" / "standard__test.csv"
            if csv.is_file():
                got = digests["predictions"]["standard__test.csv"]
                assert got == hashlib.sha256(csv.read_bytes()).hexdigest()

    def test_unit_files_are_those_of_uavbench_train(self, full_run, smoke_dataset):
        """One train-then-evaluate path: every unit directory has the layout of a
        ``uavbench train`` output, and its saved config gives back the unit's key."""
        from benchmark.tracking import manifest_sha256
        from benchmark.training import load_train_config, run_key

        tmp, _ = full_run
        manifest = manifest_sha256(smoke_dataset)
        unit_dirs = sorted((tmp / "runs" / "units").iterdir())
        assert unit_dirs
        for unit_dir in unit_dirs:
            cfg = load_train_config(unit_dir / "config.yaml")
            assert run_key(cfg, manifest) == unit_dir.name
            assert (unit_dir / "train" / "checkpoint.pt").is_file()
            assert (unit_dir / "history.json").is_file()
            # the worker's heartbeat of its last epoch (the driver's progress line reads it)
            beat = json.loads((unit_dir / "progress.json").read_text())
            assert beat == {"epoch": cfg.optim.epochs, "epochs": cfg.optim.epochs}
            names = {p.name for p in (unit_dir / "eval").iterdir()}
            split = cfg.data.val_split or cfg.data.train_split.replace("train", "test")
            stem = split.replace("/", "__")
            assert {f"{stem}.csv", f"{stem}.json", f"{stem}__swap.csv"} <= names, unit_dir

    def test_paper_numbers_beside_ours(self, full_run):
        tmp, _ = full_run
        table1 = (tmp / "reports" / "table1.md").read_text()
        assert "| Pd/Re-Net | 1.34 |" in table1  # paper Table 1, dtheta of Pd/Re-Net
        table6 = (tmp / "reports" / "table6.md").read_text()
        assert "65.60" in table6 and "95.60" in table6

    def test_tracked_runs(self, full_run):
        tmp, _ = full_run
        runs = run_statuses(tmp)
        nested = [r for r in runs if r.get("parent_run_id")]
        jobs = sum(len(s.jobs()) for s in load_specs())
        assert sum(r["status"] == "FINISHED" for r in nested) >= jobs
        tags = next(r["tags"] for r in nested if r["tags"].get("table") == "table1")
        for key in (
            "table",
            "head",
            "encoder",
            "seed",
            "git_commit",
            "dataset_manifest",
            "run_key",
        ):
            assert key in tags
        # One training run per unit (experiment uavbench-smoke/training), FINISHED, with the
        # real start and end; every table row points at its unit's training run.
        training = [r for r in runs if r["experiment"] == "uavbench-smoke/training"]
        units = list((tmp / "runs" / "units").iterdir())
        assert len(training) == len(units) and {r["status"] for r in training} == {"FINISHED"}
        assert all(r["end_time_ms"] > r["start_time_ms"] for r in training)
        ids = {r["run_id"] for r in training}
        assert all(r["tags"]["training_run_id"] in ids for r in nested if "unit" in r["tags"])

    def test_second_invocation_runs_nothing(self, full_run, smoke_dataset, capsys, monkeypatch):
        """From Python this time (the README's lines): the same frozen config the CLI builds."""
        tmp, _ = full_run
        monkeypatch.chdir(tmp)
        config = ReproduceConfig(
            profile="smoke", data=smoke_dataset, out=tmp / "reports", workdir=tmp / "runs",
            tracker="local", quiet=True, executor=ExecutorConfig(workers=1),
        )  # fmt: skip
        assert run_reproduction(config).ok
        out = capsys.readouterr().out
        counts = re.search(r"(\d+) training runs \((\d+) already in the tracking store\)", out)
        assert counts and counts[1] == counts[2] and int(counts[1]) >= 33

    def test_second_invocation_keeps_the_numbers_and_train_times(
        self, full_run, smoke_dataset, monkeypatch
    ):
        tmp, _ = full_run
        monkeypatch.chdir(tmp)
        assert reproduce(tmp, smoke_dataset, "--workers", "1") == 0
        # The first invocation's frame, reloaded from the reports (reported per unit).
        first = pd.read_csv(tmp / "reports" / "results.csv")
        assert reproduce(tmp, smoke_dataset, "--workers", "1") == 0
        again = pd.read_csv(tmp / "reports" / "results.csv")
        keys = ["table", "label", "x", "split", "satellite", "seed"]
        merged = first.merge(again, on=keys, suffixes=("", "_again"))
        assert len(merged) == len(first) == len(again)
        trained = merged[merged["unit"].notna()]  # the constant predictor rows train nothing
        assert len(trained) > 0 and (trained["train_seconds"] > 0).all()
        pd.testing.assert_series_equal(
            merged["train_seconds"], merged["train_seconds_again"], check_names=False
        )
        pd.testing.assert_series_equal(
            merged["dphi_deg"], merged["dphi_deg_again"], check_names=False
        )

    def test_a_unit_run_again_for_its_fusion_files_keeps_its_train_time(
        self, full_run, smoke_dataset, monkeypatch
    ):
        """A unit whose jobs are all in the store but whose fusion files are gone runs again
        (nothing is trained): the files come back, and its training time stays the stored one,
        not the seconds its re-evaluation took."""
        tmp, _ = full_run
        monkeypatch.chdir(tmp)
        units = tmp / "runs" / "units"
        found = sorted(units.glob("*/eval/*__volume_joint_sequence.json")) or sorted(
            units.glob("*/eval/*__sequence.json")
        )
        assert found
        target = found[0]
        unit = target.parent.parent.name
        first = pd.read_csv(tmp / "reports" / "results.csv")
        for path in target.parent.glob(target.stem + ".*"):  # its csv and json
            path.unlink()
        assert reproduce(tmp, smoke_dataset, "--workers", "1") == 0
        assert target.is_file()
        again = pd.read_csv(tmp / "reports" / "results.csv")
        before = first.loc[first["unit"] == unit, "train_seconds"]
        after = again.loc[again["unit"] == unit, "train_seconds"]
        assert len(before) > 0 and len(after) == len(before)
        assert set(after) == set(before)


class TestReproduceFailures:
    def test_non_finite_loss_marks_run_failed(self, tmp_path, smoke_dataset, monkeypatch, capsys):
        smoke = profiles_module.PROFILES["smoke"]
        optim = dataclasses.replace(smoke.optim, lr=1e30, name="sgd")
        broken = dataclasses.replace(smoke, optim=optim)
        monkeypatch.setitem(profiles_module.PROFILES, "smoke", broken)
        monkeypatch.chdir(tmp_path)
        assert reproduce(tmp_path, smoke_dataset, "--only", "table3", "--workers", "2") == 1
        out = capsys.readouterr().out
        assert "FAILED" in out and "non-finite" in out.lower()
        statuses = [r["status"] for r in run_statuses(tmp_path)]
        assert "FAILED" in statuses and "FINISHED" not in statuses
        # The reports are written all the same, the failed rows shown as failed (issue 14).
        table3 = (tmp_path / "reports" / "table3.md").read_text()
        assert "## Failed training runs" in table3 and "non-finite" in table3.lower()
        row = next(line for line in table3.splitlines() if line.startswith("| Pd/Re-Net |"))
        assert "| failed |" in row and "not run" not in row
        readme = (tmp_path / "reports" / "README.md").read_text()
        assert "4 row(s) failed to train" in readme and "| failed | " in readme

    def test_unknown_table_exits_2(self, tmp_path, smoke_dataset, capsys):
        assert reproduce(tmp_path, smoke_dataset, "--only", "table42") == 2
        assert "unknown table" in capsys.readouterr().err


class TestReproduceInterrupted:
    def test_ctrl_c_one_message_no_worker_tracebacks_runs_killed(
        self, tmp_path, smoke_dataset, monkeypatch
    ):
        """Ctrl-C as a terminal sends it (SIGINT to the whole process group) while a worker has
        a training run open: one clean message, no traceback, exit 130, no run left RUNNING."""
        proc, out = ctrl_c_while_training(
            tmp_path, smoke_dataset, "--only", "table3", open_timeout_s=120, exit_timeout_s=60
        )
        assert proc.returncode == 130, out
        assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
        assert out.count("interrupted: finished runs are kept") == 1, out
        statuses = [r["status"] for r in run_statuses(tmp_path)]
        assert "RUNNING" not in statuses and "KILLED" in statuses, statuses
        training = tmp_path / "tracking-local" / "uavbench-smoke_training"

        # The same command again continues the killed training runs (same run, start kept):
        # one run per unit (table3's 4 rows), every one FINISHED.
        def training_runs() -> dict[str, dict]:
            return {p.parent.name: json.loads(p.read_text()) for p in training.glob("*/run.json")}

        killed = {k: r for k, r in training_runs().items() if r["status"] == "KILLED"}
        monkeypatch.chdir(tmp_path)
        assert reproduce(tmp_path, smoke_dataset, "--only", "table3", "--workers", "1") == 0
        after = training_runs()
        assert len(after) == 4 and {r["status"] for r in after.values()} == {"FINISHED"}
        assert set(killed) <= set(after)
        for key, record in killed.items():
            assert after[key]["start_time_ms"] == record["start_time_ms"]
