"""Table 6 measurements: cached per model, input size, torch and machine, reused on rerun."""

from __future__ import annotations

import dataclasses
import io
import json

import pytest
import torch

from benchmark.models.info import model_info
from benchmark.models.model_config import ModelConfig
from benchmark.progress import Progress
from benchmark.runner.execute.costs import (
    cached_measure,
    cost_configs,
    cost_identity,
    cost_key,
    cost_rows,
    measure,
    measure_costs,
)
from benchmark.runner.plan.repro_profiles import get_repro_profile
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.report.costs import cost_table

CFG = ModelConfig(attitude="re_net_r", variant="/", width=0.25, input_size=32)


class FakeMeasure:
    """Counts calls; returns a record that names the config it measured."""

    def __init__(self) -> None:
        self.calls: list[ModelConfig] = []

    def __call__(self, cfg: ModelConfig) -> dict:
        self.calls.append(cfg)
        n = len(self.calls)
        return {"head": cfg.attitude, "input_size": cfg.input_size, "latency_ms": 1.5 * n}


class TestIdentity:
    def test_what_determines_a_measurement(self, monkeypatch):
        base = cost_key(cost_identity(CFG))
        assert base == cost_key(cost_identity(dataclasses.replace(CFG)))  # same config, same key
        others = [
            dataclasses.replace(CFG, input_size=64),
            dataclasses.replace(CFG, width=0.5),
            dataclasses.replace(CFG, attitude_options={"hidden": 512}),
        ]
        assert len({base, *(cost_key(cost_identity(c)) for c in others)}) == 4
        assert cost_key(cost_identity(CFG, repeats=20)) != base
        monkeypatch.setattr(torch, "get_num_threads", lambda: 7)  # latency depends on threads
        assert cost_key(cost_identity(CFG)) != base
        monkeypatch.setattr(torch, "__version__", "0.0.0")
        assert cost_identity(CFG)["torch"] == "0.0.0"

    def test_needs_input_size(self):
        with pytest.raises(ValueError, match="input_size"):
            cost_identity(dataclasses.replace(CFG, input_size=None))


class TestCache:
    def test_measured_once_then_read(self, tmp_path):
        fake = FakeMeasure()
        first, fresh = cached_measure(CFG, tmp_path, measure_fn=fake)
        assert fresh and len(fake.calls) == 1
        files = list(tmp_path.glob("*.json"))
        assert [f.stem for f in files] == [cost_key(cost_identity(CFG))]
        again, fresh = cached_measure(CFG, tmp_path, measure_fn=fake)
        assert not fresh and again == first and len(fake.calls) == 1
        redo, fresh = cached_measure(CFG, tmp_path, remeasure=True, measure_fn=fake)
        assert fresh and redo["latency_ms"] == 3.0 and len(fake.calls) == 2
        assert cached_measure(CFG, tmp_path, measure_fn=fake)[0] == redo  # overwritten

    def test_other_config_other_file(self, tmp_path):
        fake = FakeMeasure()
        cached_measure(CFG, tmp_path, measure_fn=fake)
        cached_measure(dataclasses.replace(CFG, input_size=64), tmp_path, measure_fn=fake)
        assert len(fake.calls) == 2 and len(list(tmp_path.glob("*.json"))) == 2

    def test_no_cache_dir_always_measures(self, tmp_path):
        fake = FakeMeasure()
        for _ in range(2):
            assert cached_measure(CFG, None, measure_fn=fake)[1]
        assert len(fake.calls) == 2

    def test_edited_file_is_measured_again(self, tmp_path):
        fake = FakeMeasure()
        cached_measure(CFG, tmp_path, measure_fn=fake)
        path = next(tmp_path.glob("*.json"))
        stored = json.loads(path.read_text())
        stored["identity"]["torch"] = "another"
        path.write_text(json.dumps(stored))
        assert cached_measure(CFG, tmp_path, measure_fn=fake)[1] and len(fake.calls) == 2


class TestMeasure:
    def test_is_model_info(self):
        record = measure(CFG, repeats=2, warmup=1)
        info = model_info(head="re_net_r", variant="/", width=0.25, input_size=32, repeats=2,
                          warmup=1)  # fmt: skip
        assert record["parameters"] == info.parameters
        assert record["mflops_inference"] == info.mflops_inference
        assert record["input_size"] == 32 and record["latency_ms"] > 0


class TestCostRows:
    def test_new_measurements_reported_once(self, tmp_path):
        spec = load_specs(None, ["table6"])[0]
        fake, measured, steps = FakeMeasure(), [], []

        def rows():
            return cost_rows(spec, 32, 0.25, "smoke", tmp_path, measure_fn=fake,
                             on_step=lambda t, i, n: steps.append((i, n)),
                             on_measured=lambda label, r: measured.append(label))  # fmt: skip

        first = rows()
        assert len(fake.calls) == 4 and measured == [
            "Re-Net",
            "Re-Net",
            *[spec.rows[1].label] * 2,
        ]
        assert steps == [(i, 4) for i in range(4)]
        again = rows()  # a rerun: nothing measured, nothing to log, the same numbers
        assert len(fake.calls) == 4 and len(measured) == 4 and again == first
        assert [r[2] for r in first][:2] == ["paper config (224 px, width 1)",
                                             "smoke profile (32 px, width 0.25)"]  # fmt: skip


class FakeLogbook:
    def __init__(self) -> None:
        self.logged: list[tuple[str, str]] = []

    def log_cost(self, table: str, label: str, info: dict) -> None:
        self.logged.append((table, label))


class TestCostTable:
    def test_rows_from_the_cache_logged_once_with_progress(self, tmp_path):
        spec = load_specs(None, ["table6"])[0]
        profile = get_repro_profile("smoke")
        # Fill the cache as a first run would have (the same identities measure_costs computes).
        configs = cost_configs(spec, 32, profile.width, profile.name)
        assert len(configs) == 2 * len(spec.rows)
        assert {c.input_size for *_, c in configs} == {224, 32}
        for i, (*_, cfg) in enumerate(configs):
            record = dataclasses.asdict(_record(cfg, i))
            path = tmp_path / f"{cost_key(cost_identity(cfg))}.json"
            path.write_text(json.dumps({"identity": cost_identity(cfg), "record": record}))
        stream = io.StringIO()
        logbook = FakeLogbook()
        with Progress(3, "report", stream=stream) as bar:
            rows = measure_costs(spec, profile, 32, logbook, tmp_path, bar=bar)
        text = cost_table(spec, rows, tmp_path)
        assert logbook.logged == []  # read, not measured (a measurement is logged), not re-logged
        assert len(list(tmp_path.glob("*.json"))) == 4
        lines = stream.getvalue().splitlines()
        assert sum("table6: Re-Net, paper config (224 px, width 1) (1/4)" in x for x in lines) == 1
        assert any("(4/4)" in x for x in lines)
        rows = [x for x in text.splitlines() if x.startswith("| Re-Net |")]
        assert rows[0].split(" | ")[2] == "1,000" and rows[0].split(" | ")[-1] == "0.5 |"
        assert "reused by a rerun" in text


@dataclasses.dataclass
class _Record:
    head: str
    parameters: int
    size_mb: float
    mflops_inference: float
    mflops_dense_inference: float
    latency_ms: float
    threads: int


def _record(cfg: ModelConfig, i: int) -> _Record:
    """A stored record with recognisable numbers (1,000 parameters, latency 0.5 ms ...)."""
    return _Record(cfg.attitude, 1000 * (i + 1), 0.004, 1.0, 0.5, 0.5 + i, 1)
