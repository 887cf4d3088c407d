"""Paper Table 6's measurements (``kind: cost`` specs): size, MFLOPs and CPU latency, measured once
and cached, before the report is written (``benchmark.runner.report.costs`` renders them).

Each (spec row, configuration) is one measurement by ``benchmark.models.info.model_info``: the
paper's configuration (224 px, width 1.0) and the profile's (the dataset's input size, the
profile's width). A measurement at 224 px costs ~10-15 s on one CPU core (FLOP counting in eval
and training mode, 3 + 10 timed forward passes), so it is cached like a training unit: as
``<workdir>/costs/<key>.json``, ``key`` the hash of everything that determines the numbers (the
model config with its input size, repeats and warm-up, the torch version and thread count, the
machine's host name, CPU model and core count). A rerun reads the file instead of measuring;
``remeasure=True`` measures again and overwrites it (or delete ``<workdir>/costs/``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import torch

from benchmark.machine import cpu_model
from benchmark.models.model_config import ModelConfig
from benchmark.progress import Progress
from benchmark.runner.plan.repro_profiles import ReproProfile
from benchmark.runner.plan.specs import TableSpec

# (row label, paper model, configuration name, the measurement's record)
CostRow = tuple[str, str, str, dict[str, Any]]


class CostLog(Protocol):
    """Where a new measurement is logged (the reproduction's logbook)."""

    def log_cost(self, table: str, label: str, info: dict) -> None: ...


COST_FORMAT = 1  # bump when the measurement changes (then every cached file is stale)
REPEATS, WARMUP = 10, 3
PAPER_CONFIG = (224, 1.0)  # px, encoder width


def cost_identity(cfg: ModelConfig, repeats: int = REPEATS, warmup: int = WARMUP) -> dict:
    """What determines a measurement of ``cfg`` (its ``input_size`` set) on this machine."""
    if cfg.input_size is None:
        raise ValueError("cost_identity: the model config needs its input_size set")
    return {
        "format": COST_FORMAT,
        "model": cfg.to_dict(),
        "repeats": int(repeats),
        "warmup": int(warmup),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "host": platform.node(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
    }


def cost_key(identity: dict) -> str:
    """16 hex digits of the SHA-256 of the identity's canonical JSON."""
    text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def measure(cfg: ModelConfig, repeats: int = REPEATS, warmup: int = WARMUP) -> dict[str, Any]:
    """``model_info`` of ``cfg`` (``input_size`` set) as a plain dict (``ModelInfo`` fields)."""
    from benchmark.models.info import model_info

    info = model_info(
        head=cfg.attitude, encoder=cfg.encoder, variant=cfg.variant, width=cfg.width,
        input_size=int(cfg.input_size), translation=cfg.translation, repeats=repeats,
        warmup=warmup,
        options={"attitude_options": cfg.attitude_options,
                 "translation_options": cfg.translation_options,
                 "encoder_options": cfg.encoder_options},
    )  # fmt: skip
    return dataclasses.asdict(info)


def cached_measure(
    cfg: ModelConfig,
    cache_dir: Path | None,
    remeasure: bool = False,
    measure_fn: Callable[[ModelConfig], dict[str, Any]] = measure,
) -> tuple[dict[str, Any], bool]:
    """``(record, measured_now)``: the cached record of ``cfg`` in ``cache_dir`` when there is one
    (and not ``remeasure``), else a new measurement, written there. ``cache_dir`` None: always
    measure, cache nothing. A cache file of another identity (a hash collision, or an edited
    file) is measured again."""
    identity = cost_identity(cfg)
    path = Path(cache_dir) / f"{cost_key(identity)}.json" if cache_dir is not None else None
    if path is not None and path.is_file() and not remeasure:
        stored = json.loads(path.read_text())
        if stored.get("identity") == json.loads(json.dumps(identity)):
            return stored["record"], False
    record = measure_fn(cfg)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"identity": identity, "record": record}, indent=1) + "\n")
        tmp.replace(path)  # atomic: an interrupted write leaves no half file
    return record, True


def cost_configs(spec: TableSpec, input_size: int, width: float, profile_name: str) -> list:
    """``(row label, paper model, config name, ModelConfig)`` of every measurement of ``spec``:
    each row at the paper's configuration and at the profile's."""
    out = []
    configs = [("paper config", *PAPER_CONFIG), (f"{profile_name} profile", input_size, width)]
    for row in spec.rows:
        for name, size, w in configs:
            cfg = dataclasses.replace(row.model_config(w), input_size=int(size))
            out.append((row.label, row.paper_model, f"{name} ({size} px, width {w:g})", cfg))
    return out


def cost_rows(
    spec: TableSpec,
    input_size: int,
    width: float,
    profile_name: str,
    cache_dir: Path | None,
    remeasure: bool = False,
    on_step: Callable[[str, int, int], None] | None = None,
    on_measured: Callable[[str, dict[str, Any]], None] | None = None,
    measure_fn: Callable[[ModelConfig], dict[str, Any]] = measure,
) -> list[tuple[str, str, str, dict[str, Any]]]:
    """``(label, paper model, config name, record)`` per measurement, cached. ``on_step(text,
    i, n)`` is called before each (a progress line), ``on_measured(label, record)`` after each
    new measurement (the tracker logs it; a cached record was logged when it was measured)."""
    rows = []
    todo = cost_configs(spec, input_size, width, profile_name)
    for i, (label, paper_model, name, cfg) in enumerate(todo):
        if on_step is not None:
            on_step(f"{spec.name}: {label}, {name}", i, len(todo))
        record, fresh = cached_measure(cfg, cache_dir, remeasure, measure_fn)
        if fresh and on_measured is not None:
            on_measured(label, record)
        rows.append((label, paper_model, name, record))
    return rows


def measure_costs(
    spec: TableSpec,
    profile: ReproProfile,
    input_size: int,
    logbook: CostLog | None,
    cache_dir: Path | None = None,
    remeasure: bool = False,
    bar: Progress | None = None,
) -> list[CostRow]:
    """Table 6's rows of ``spec``: at the paper's configuration and at the profile's, cached in
    ``cache_dir``; only new measurements are logged to ``logbook`` (a cached one was logged when
    measured). ``bar`` shows which one is being measured."""

    def step(text: str, i: int, n: int) -> None:
        if bar is not None:
            bar.status(f"{text} ({i + 1}/{n})")

    def logged(label: str, record: dict) -> None:
        if logbook is not None:
            logbook.log_cost(spec.name, label, record)

    return cost_rows(spec, input_size, profile.width, profile.name, cache_dir, remeasure,
                     on_step=step, on_measured=logged)  # fmt: skip
