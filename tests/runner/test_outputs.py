"""Provenance digests of a reproduction (checked against independent sha256 computations) and the
comparison of two provenance records."""

from __future__ import annotations

import hashlib
import json

import pytest
import torch

from benchmark.runner.execute.provenance import collect_provenance, state_dict_sha256
from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan.repro_profiles import get_repro_profile
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.runner.report.provenance import (
    VOLATILE,
    Difference,
    compare_provenance,
    flatten,
    write_provenance,
)

SPLITS = ["standard/train", "standard/val", "standard/test", "generalized/test"]


def save_checkpoint(path, state, seconds: float, root: str) -> None:
    """A checkpoint shaped like the trainer's (format 1): weights plus run-specific fields."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(
        {"format": 1, "config": {"data": {"root": root}}, "config_hash": "x", "epoch": 1,
         "model_config": None, "model": state, "optimizer": None, "rng": {},
         "history": [{"epoch": 1.0, "epoch_time_s": seconds}]},
        path,
    )  # fmt: skip


def model_state(seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "encoder.w": torch.randn(4, 3, generator=g),
        "head.b": torch.randn(5, generator=g, dtype=torch.float64),
        "norm.count": torch.tensor(7),
        "half.w": torch.randn(2, 2, generator=g).to(torch.bfloat16),
    }


def naive_state_sha256(state: dict[str, torch.Tensor]) -> str:
    """The documented recipe spelt out with numpy byte views (bfloat16 via its int16 bits)."""
    h = hashlib.sha256()
    for name in sorted(state):
        t = state[name]
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}\n".encode())
        t = t.view(torch.int16) if t.dtype == torch.bfloat16 else t
        h.update(t.numpy().astype(t.numpy().dtype.newbyteorder("<")).tobytes())
    return h.hexdigest()


@pytest.fixture()
def reproduction(tmp_path):
    """Two table1 units with a checkpoint and predictions files; a dataset manifest."""
    data = tmp_path / "data"
    data.mkdir()
    (data / "manifest.json").write_text(json.dumps({"files": {"uav.parquet": "abc"}}))
    specs = load_specs(None, ["table1"])
    units = plan_units(specs, get_repro_profile("smoke"), [0], data, SPLITS, "d" * 64)[:2]
    workdir = tmp_path / "runs"
    for i, unit in enumerate(units):
        unit_dir = workdir / "units" / unit.key
        save_checkpoint(unit_dir / "train" / "checkpoint.pt", model_state(i), 1.5 + i, str(data))
        (unit_dir / "eval").mkdir(parents=True)
        (unit_dir / "eval" / "standard__test.csv").write_text(f"index,dphi_deg\n0,{i}.5\n")
        (unit_dir / "eval" / "standard__val.csv").write_text("index,dphi_deg\n0,2\n")
    results = {u.key: UnitResult(u.key, True) for u in units}
    return units, results, data, workdir


class TestStateDigest:
    def test_matches_the_documented_recipe(self):
        state = model_state(3)
        assert state_dict_sha256(state) == naive_state_sha256(state)

    def test_independent_of_order_and_serialisation(self, tmp_path):
        state = model_state(1)
        reversed_state = dict(reversed(list(state.items())))
        assert state_dict_sha256(state) == state_dict_sha256(reversed_state)
        torch.save(state, tmp_path / "s.pt")
        assert state_dict_sha256(torch.load(tmp_path / "s.pt")) == state_dict_sha256(state)

    def test_one_ulp_changes_it(self):
        state = model_state(1)
        bumped = dict(state)
        bumped["head.b"] = torch.nextafter(state["head.b"], torch.full_like(state["head.b"], 9))
        assert state_dict_sha256(state) != state_dict_sha256(bumped)

    def test_not_a_tensor(self):
        with pytest.raises(TypeError, match="'x' is a int"):
            state_dict_sha256({"x": 3})


class TestCollect:
    def test_digests_recomputed(self, reproduction, tmp_path):
        units, results, data, workdir = reproduction
        record = collect_provenance(units, results, data, workdir)
        manifest = hashlib.sha256((data / "manifest.json").read_bytes()).hexdigest()
        assert record["dataset"]["manifest_sha256"] == manifest
        for i, unit in enumerate(units):
            got = record["units"][unit.key]
            unit_dir = workdir / "units" / unit.key
            ckpt = (unit_dir / "train" / "checkpoint.pt").read_bytes()
            assert got["checkpoint_file_sha256"] == hashlib.sha256(ckpt).hexdigest()
            assert got["model_state_sha256"] == naive_state_sha256(model_state(i))
            files = {
                n: hashlib.sha256((unit_dir / "eval" / n).read_bytes()).hexdigest()
                for n in ("standard__test.csv", "standard__val.csv")
            }
            assert got["predictions"] == files
            listing = "".join(f"{n} {files[n]}\n" for n in sorted(files))
            assert got["predictions_sha256"] == hashlib.sha256(listing.encode()).hexdigest()
        for key in ("python", "torch", "numpy", "scipy", "pandas", "torch_cpu_capability"):
            assert record["software"][key], key
        assert record["software"]["torch"] == torch.__version__
        assert record["machine"]["cpu_model"] and "cpu_flags" in record["machine"]
        assert record["machine"]["cpu_signature"]  # family, model, stepping, ... or "unknown"

    def test_same_weights_other_run_same_state_digest(self, reproduction):
        """The checkpoint file is not reproducible (epoch wall time, dataset path); the weights
        digest is, and the comparison ignores the file digest."""
        units, results, data, workdir = reproduction
        a = collect_provenance(units, results, data, workdir)
        ckpt = workdir / "units" / units[0].key / "train" / "checkpoint.pt"
        save_checkpoint(ckpt, model_state(0), 99.0, "/elsewhere/data")
        b = collect_provenance(units, results, data, workdir)
        ua, ub = a["units"][units[0].key], b["units"][units[0].key]
        assert ua["checkpoint_file_sha256"] != ub["checkpoint_file_sha256"]
        assert ua["model_state_sha256"] == ub["model_state_sha256"]
        assert compare_provenance(a, b) == []

    def test_without_workdir(self, reproduction):
        units, results, data, _ = reproduction
        record = collect_provenance(units, results, data, None)
        assert record["units"] == {} and "no workdir" in record["units_note"]

    def test_files_written_and_linked(self, reproduction, tmp_path):
        units, results, data, workdir = reproduction
        record = collect_provenance(units, results, data, workdir)
        out = tmp_path / "out"
        out.mkdir()
        md, js = write_provenance(record, out)
        assert json.loads(js.read_text()) == json.loads(json.dumps(record))
        text = md.read_text()
        for unit in units:
            u = record["units"][unit.key]
            assert f"| `{unit.key}` |" in text and u["model_state_sha256"] in text


class TestCompare:
    def test_lists_every_difference(self, reproduction, tmp_path):
        units, results, data, workdir = reproduction
        a = collect_provenance(units, results, data, workdir)
        b = json.loads(json.dumps(a))
        key = units[1].key
        b["units"][key]["model_state_sha256"] = "0" * 64
        b["software"]["numpy"] = "0.0"
        del b["units"][units[0].key]
        b["written"] = "another day"  # volatile: ignored
        (tmp_path / "a.json").write_text(json.dumps(a))
        diffs = compare_provenance(tmp_path / "a.json", b)
        keys = [d.key for d in diffs]
        assert keys == sorted(keys)
        assert Difference("software.numpy", a["software"]["numpy"], "0.0") in diffs
        assert (
            Difference(
                f"units.{key}.model_state_sha256", a["units"][key]["model_state_sha256"], "0" * 64
            )
            in diffs
        )
        gone = [d for d in diffs if d.key.startswith(f"units.{units[0].key}.")]
        assert gone and all(d.b is None for d in gone)
        removed = [k for k in flatten(a) if k.startswith(f"units.{units[0].key}.")]
        assert len(gone) == len(removed) - 1  # all but the (volatile) checkpoint file digest
        assert "written" not in keys
        assert "(absent)" in str(gone[0])

    def test_identical_records(self, reproduction):
        units, results, data, workdir = reproduction
        a = collect_provenance(units, results, data, workdir)
        assert compare_provenance(a, a, ignore=()) == []
        assert "written" in VOLATILE

    def test_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match=r"provenance\.json"):
            compare_provenance(tmp_path / "nope.json", {})
