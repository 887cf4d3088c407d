"""Issue 20: ``uavbench reproduce --only table1`` over a committed report of another dataset.

The earlier report is a copy of the committed ``reports/quick`` (quick profile, its own dataset
and commit: 1,100 rows of results.csv over 12 tables, figures, Table 6). Today's run is the smoke
profile on the session's smoke dataset, so none of the earlier units is today's. Training is a
test double (``fake_unit``: the constant predictor, written in the real predictions format) and
the heading-cue audit is stubbed, so the test checks the merge, not the models. Whatever
``--stale`` says, every file of the report directory, ``results.csv``, ``provenance.json`` and
the README must describe the same tables.
"""

from __future__ import annotations

import json
import re
import shutil
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

import benchmark.runner.execute.audit as audit_module
import benchmark.runner.execute.pool as pool_module
from benchmark.cli import main
from benchmark.data.swap import SATELLITE_MODES
from benchmark.evaluation.constant import mean_rotation
from benchmark.evaluation.metrics import predictions_frame, summarize, write_predictions_csv
from benchmark.runner.claims.evidence import NOT_RUN
from benchmark.runner.execute.worker import UnitResult, UnitTask, eval_key, split_filename
from benchmark.runner.plan.partial import BANNER_BEGIN, BANNER_END, EARLIER, short_commit
from benchmark.runner.plan.specs import load_specs

ROOT = Path(__file__).resolve().parents[2]
COMMITTED = ROOT / "reports" / "quick"
R_COLUMNS = [f"R{i}{j}" for i in range(3) for j in range(3)]
NOT_TABLES = {"README", "provenance", "heading_cue"}


def fake_unit(task: UnitTask) -> UnitResult:
    """A parameter-free model in place of training: the training split's mean pose, turned by a
    small rotation fixed by the unit key, on every evaluated split and satellite mode (it reads
    no image), written where ``train_and_evaluate`` writes predictions."""
    pairs = pd.read_parquet(Path(task.cfg.data.root) / "pairs.parquet")
    train = pairs[pairs["split"] == task.cfg.data.train_split]
    R_bar = mean_rotation(torch.tensor(train[R_COLUMNS].to_numpy().reshape(-1, 3, 3)))
    turn = Rotation.from_rotvec(np.radians([0, 0, zlib.crc32(task.key.encode()) % 30])).as_matrix()
    T_bar = torch.from_numpy(train[["dE", "dN", "dU"]].to_numpy().mean(0))
    metrics = {}
    for split in task.eval_splits:
        rows = pairs[pairs["split"] == split].reset_index(drop=True)
        n = len(rows)
        R_gt = torch.tensor(rows[R_COLUMNS].to_numpy().reshape(-1, 3, 3))  # copies: a
        T_gt = torch.tensor(rows[["dE", "dN", "dU"]].to_numpy())  # column view is read-only
        R_hat = (R_bar @ torch.from_numpy(turn)).expand(n, 3, 3)
        frame = predictions_frame(
            R_hat, R_gt, T_bar.expand(n, 3), T_gt, index=np.arange(n),
            extra={"flight": rows["flight"].tolist()},
        )  # fmt: skip
        for satellite in SATELLITE_MODES:
            key = eval_key(split, satellite)
            write_predictions_csv(frame, task.unit_dir / "eval" / f"{split_filename(key)}.csv")
            metrics[key] = summarize(frame)
    return UnitResult(task.key, True, metrics=metrics, seconds=1.0)


def stub_audit(data_root, **kwargs):
    return []  # no rows: the audit's datasets are not rendered in this test


@pytest.fixture
def committed(tmp_path, monkeypatch):
    """A copy of the committed quick report in ``tmp_path/reports``, training and the audit
    replaced by test doubles, the working directory ``tmp_path``."""
    out = tmp_path / "reports"
    shutil.copytree(COMMITTED, out)
    monkeypatch.setattr(pool_module, "run_unit", fake_unit)
    monkeypatch.setattr(audit_module, "heading_cue_rows", stub_audit)
    monkeypatch.chdir(tmp_path)
    earlier = json.loads((COMMITTED / "provenance.json").read_text())["git_commit"]
    return out, earlier


def reproduce(tmp_path, dataset, *extra: str) -> int:
    """`reproduce --only table1` (a later `--only` in `extra` wins) into tmp_path/reports."""
    return main([
        "reproduce", "--profile", "smoke", "--data", str(dataset), "--out",
        str(tmp_path / "reports"), "--workdir", str(tmp_path / "runs"), "--tracker", "null",
        "--quiet", "--workers", "1", "--only", "table1", *extra,
    ])  # fmt: skip


def table_files(out: Path) -> set[str]:
    return {p.stem for p in out.glob("*.md")} - NOT_TABLES


def section(readme: str, title: str) -> str:
    return readme.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def listed_tables(readme: str) -> dict[str, str]:
    """``name -> line`` of the README's *Tables and figures* list."""
    lines = section(readme, "Tables and figures").splitlines()
    return {m[1]: line for line in lines if (m := re.match(r"- \[(\w+)\]\(\1\.md\)", line))}


def assert_agrees(out: Path) -> None:
    """Every table file has rows in results.csv or is marked; every table with rows has its
    file; the README lists exactly the files, marking exactly the marked ones; no findings or
    claims line says "not run" of a table whose file is there."""
    results = pd.read_csv(out / "results.csv", dtype={"stale_from": str})
    results["stale_from"] = results["stale_from"].fillna("")
    files = table_files(out)
    marked = {n for n in files if (out / f"{n}.md").read_text().startswith(BANNER_BEGIN)}
    with_rows = set(results["table"])
    costs = {s.name for s in load_specs() if s.kind == "cost"}
    assert with_rows <= files, with_rows - files
    assert files - with_rows <= marked | costs, files - with_rows
    stale_rows = set(results.loc[results["stale_from"] != "", "table"])
    assert stale_rows == marked & with_rows
    assert set(results.loc[results["stale_from"] == "", "table"]).isdisjoint(marked)
    for png in out.glob("*.png"):
        assert png.stem in files and f"]({png.name})" in (out / f"{png.stem}.md").read_text()
    readme = (out / "README.md").read_text()
    listed = listed_tables(readme)
    assert set(listed) == files
    assert {n for n, line in listed.items() if "from an earlier run at" in line} == marked
    record = json.loads((out / "provenance.json").read_text())
    assert set(record.get("earlier_tables", {})) == marked
    findings = section(readme, "Findings")
    assert f"**{NOT_RUN}**" not in findings or not marked
    for name in files:
        assert f"table {name} " not in findings or name not in marked  # ranking sentences


class TestKeepTheEarlierTables:
    def test_marked_everywhere_claims_not_redecided_twice(
        self, committed, tmp_path, smoke_dataset, capsys
    ):
        out, commit = committed
        before = table_files(out)
        earlier = pd.read_csv(out / "results.csv")
        assert reproduce(tmp_path, smoke_dataset) == 0
        printed = capsys.readouterr().out
        # told before training starts: the block comes before the plan line
        assert printed.index("Partial rerun of table1") < printed.index("reproduce smoke:")
        block = printed.split("Partial rerun of table1", 1)[1].split("reproduce smoke:", 1)[0]
        assert f"(run at {short_commit(commit)}): its units were trained on another dataset" in (
            block
        )
        assert "--stale drop" in block

        assert table_files(out) == before  # nothing removed
        results = pd.read_csv(out / "results.csv", dtype={"stale_from": str})
        stale = results[results["stale_from"].notna()]
        # rows the committed report already kept from an even earlier run keep that commit;
        # the others now come from the committed report's run
        already = earlier.get("stale_from", pd.Series(dtype=str)).dropna().astype(str)
        assert set(stale["stale_from"]) == {commit} | set(already)
        assert len(stale) == (earlier["table"] != "table1").sum()  # every other row kept
        assert set(results.loc[results["stale_from"].isna(), "table"]) == {"table1"}
        # the kept numbers are the committed ones, unchanged
        kept = stale.drop(columns="stale_from").reset_index(drop=True)
        expected = earlier[earlier["table"] != "table1"].reset_index(drop=True)
        expected = expected.drop(columns=["stale_from"], errors="ignore")
        pd.testing.assert_frame_equal(kept[expected.columns], expected, check_dtype=False)
        for name in before - {"table1"}:
            text = (out / f"{name}.md").read_text()
            # a table the committed report already kept from an earlier run names that run
            own = already[earlier.loc[already.index, "table"] == name]
            at = own.iloc[0] if len(own) else commit
            assert text.startswith(BANNER_BEGIN) and f"`{short_commit(at)}`" in text, name
            committed_text = (COMMITTED / f"{name}.md").read_text()
            if committed_text.startswith(BANNER_BEGIN):  # its banner is rewritten, the rest kept
                committed_text = committed_text.split(BANNER_END, 1)[1]
            assert text.endswith(committed_text), name  # the rest as written then
        assert not (out / "table1.md").read_text().startswith(BANNER_BEGIN)

        readme = (out / "README.md").read_text()
        findings = section(readme, "Findings")
        assert f"**from an earlier run at `{short_commit(commit)}`, not re-decided**" in findings
        assert f"**{NOT_RUN}**" not in findings
        claims = section(readme, "Claims of the paper, checked")
        verdicts = re.findall(r"^\| (\d+) \|.*\| \*\*([^*]+)\*\* \|", claims, re.M)
        assert verdicts and NOT_RUN not in {v for _, v in verdicts}
        by_number = dict(verdicts)
        assert by_number["1"] != EARLIER  # the sanity claim reads table1 only: decided today
        assert by_number["3"] == EARLIER  # Tables 1-2: table2 is from the earlier run
        partial = section(readme, "Partial rerun")
        # one line per earlier run: the tables it kept, at its commit, and why
        stale_at = {name: commit for name in set(earlier["table"]) - {"table1"}}  # no cost table
        for row, at in already.items():
            stale_at[earlier.loc[row, "table"]] = at
        for at in set(stale_at.values()):
            tail = f" at `{short_commit(at)}`: its units were trained on another dataset"
            line = next(x for x in partial.splitlines() if tail in x)
            listed = set(re.findall(r"`([\w]+)`", line.split(tail, 1)[0]))
            assert listed == {n for n, c in stale_at.items() if c == at}, line
        # every table of the committed report: all of them (`uavbench reproduce`), or named
        # when a spec is newer than the committed report (the encoders table, issue 21)
        refresh = re.search(r"Refresh them with `uavbench reproduce(?: --only ([\w,]+))?`\.",
                            partial)  # fmt: skip
        assert refresh is not None
        if refresh.group(1) is not None:
            assert set(refresh.group(1).split(",")) == set(before)
        record = json.loads((out / "provenance.json").read_text())
        assert record["earlier_tables"]["table2"]["git_commit"] == commit
        committed_record = json.loads((COMMITTED / "provenance.json").read_text())
        # the committed report's own units, and those it already kept from an earlier run
        committed_units = {**committed_record.get("earlier_units", {}), **committed_record["units"]}
        stale_units = set(stale["unit"].dropna())
        assert set(record["earlier_units"]) == stale_units & set(committed_units)
        assert all(record["earlier_units"][k] == committed_units[k] for k in stale_units)
        provenance_md = (out / "provenance.md").read_text()
        assert "## Tables from an earlier run" in provenance_md
        assert f"| `table2` | `{commit}` |" in provenance_md
        assert f"{len(before - {'table1'})} table(s) kept from an earlier run" in section(
            readme, "Provenance"
        )
        assert_agrees(out)

        # A second partial rerun, at another commit in real life: the same report, one banner,
        # the earlier run's commit kept.
        first = {p.name: p.read_text() for p in out.glob("*.md") if p.stem not in NOT_TABLES}
        assert reproduce(tmp_path, smoke_dataset) == 0
        again = {p.name: p.read_text() for p in out.glob("*.md") if p.stem not in NOT_TABLES}
        assert again == first
        record = json.loads((out / "provenance.json").read_text())
        assert {t["git_commit"] for t in record["earlier_tables"].values()} == {commit} | set(
            already
        )
        assert_agrees(out)


class TestDropTheEarlierTables:
    def test_removed_with_files_rows_and_lines(self, committed, tmp_path, smoke_dataset, capsys):
        out, _commit = committed
        gone = table_files(out) - {"table1"}
        assert reproduce(tmp_path, smoke_dataset, "--stale", "drop") == 0
        assert "removed with their rows, files and README lines" in capsys.readouterr().out
        assert table_files(out) == {"table1"} and not list(out.glob("*.png"))
        results = pd.read_csv(out / "results.csv")
        assert set(results["table"]) == {"table1"} and results["stale_from"].isna().all()
        readme = (out / "README.md").read_text()
        findings = section(readme, "Findings")
        for name in gone:
            assert f"`{name}`" not in findings and f"table {name} " not in findings, name
        assert "towns/test" not in findings and EARLIER not in readme
        assert "Removed, with their rows, files and findings" in section(readme, "Partial rerun")
        assert "earlier_tables" not in json.loads((out / "provenance.json").read_text())
        assert_agrees(out)


class TestReportStageFailure:
    def test_a_failing_audit_leaves_the_report_as_it_was(
        self, committed, tmp_path, smoke_dataset, monkeypatch, capsys
    ):
        """The heading-cue audit (which may render datasets) runs before the first report file
        is written: when it fails, every file of the earlier report keeps its bytes."""
        from benchmark.errors import InputError

        out, _commit = committed
        before = {p.name: p.read_bytes() for p in out.iterdir()}

        def failing_audit(data_root, **kwargs):
            raise InputError("audit dataset refused (test)")

        monkeypatch.setattr(audit_module, "heading_cue_rows", failing_audit)
        assert reproduce(tmp_path, smoke_dataset) == 2
        assert "audit dataset refused (test)" in capsys.readouterr().err
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before


class TestLiveTables:
    def test_kept_live_and_rendered_again_from_their_rows(
        self, tmp_path, smoke_dataset, monkeypatch, capsys
    ):
        """``--only table1`` then ``--only table3`` on the same dataset: table1's units are
        today's, so it stays live (no mark), its file rendered again from its rows says what it
        said, and the claims on it are decided again."""
        monkeypatch.setattr(pool_module, "run_unit", fake_unit)
        monkeypatch.setattr(audit_module, "heading_cue_rows", stub_audit)
        monkeypatch.chdir(tmp_path)
        out = tmp_path / "reports"
        assert reproduce(tmp_path, smoke_dataset) == 0
        table1 = (out / "table1.md").read_text()
        capsys.readouterr()
        assert reproduce(tmp_path, smoke_dataset, "--only", "table3") == 0
        printed = capsys.readouterr().out
        assert "kept and decided again (today's units" in printed and ": table1" in printed
        assert (out / "table1.md").read_text() == table1
        results = pd.read_csv(out / "results.csv")
        assert set(results["table"]) == {"table1", "table3"}
        assert results["stale_from"].isna().all()
        readme = (out / "README.md").read_text()
        assert set(listed_tables(readme)) == {"table1", "table3"}
        assert "Kept from an earlier invocation and decided again" in readme
        assert EARLIER not in readme
        claims = section(readme, "Claims of the paper, checked")
        assert re.search(r"^\| 1 \|.*\| \*\*not resolved at this scale\*\* \|", claims, re.M)
        assert_agrees(out)
