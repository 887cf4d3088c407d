"""``uavbench bench accelerator``: does this machine's accelerator run the benchmark, and how fast.

One command, one line per figure, on a machine with nothing but the repository, its install
command (``pip install -e .``) and a torch build for the device (CUDA, MPS or the CPU):

1. a smoke reproduction (what ``uavbench reproduce --profile smoke --only table3`` runs, in a
   fresh interpreter) in a temporary directory with its own dataset, work dir, reports and sqlite
   MLflow store. Training units use ``TrainConfig``'s defaults, ``device=auto`` and
   ``precision=auto`` (CUDA in bf16 where supported, else MPS, else the CPU in fp32); the line
   reports the device, precision and accelerator that the runs' MLflow tags record, so it shows
   where the units really ran;
2. ``bench train`` at the paper's size (224 px, width 1.0, batch 20 over 4 satellite images): our
   training loop in fp32 and bf16 (where supported) on ``--device``, pairs/s, bf16/fp32, and the
   share of the measured convolution ceiling (``benchmark.bench.ceiling``);
3. inference latency per pair (batch 1, eval mode, as ``uavbench model-info`` measures it).

``--fast`` shrinks 2 and 3 to tiny sizes (tests; the reproduction is the smoke profile's anyway);
``--data DIR`` reuses a smoke dataset instead of rendering one. Exit 0 when everything ran, 1 when
the reproduction failed (its log's last lines are printed). :func:`bench_accelerator` returns the
lines and whether the reproduction ran; the command prints them and picks the exit code.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from benchmark.bench.fresh_process import FreshProcessError, run_fresh


@dataclass(frozen=True)
class AcceleratorBenchConfig:
    """``bench accelerator``: ``device`` and ``precision`` (comma list; None: fp32 and bf16 where
    supported) by name for the bench and latency lines; the ``table`` of the smoke reproduction,
    an existing smoke dataset ``data`` to reuse, ``keep`` its files there (None: a temporary
    directory), ``reproduce``: run it at all; ``steps`` timed training steps, ``threads`` torch
    threads (None: torch's), ``fast``: tiny bench and latency sizes."""

    device: str = "auto"
    precision: str | None = None
    table: str = "table3"
    data: Path | None = None
    keep: Path | None = None
    reproduce: bool = True
    steps: int = 3
    threads: int | None = None
    fast: bool = False


def run_reproduction(config: AcceleratorBenchConfig, root: Path) -> tuple[bool, list[str]]:
    """Run the smoke reproduction under ``root``; ``(ok, lines)``."""
    from benchmark.runner.execute.pool import ExecutorConfig
    from benchmark.runner.reproduction import ReproduceConfig, reproduce

    data = config.data if config.data is not None else root / "data"
    run = ReproduceConfig(
        profile="smoke", only=(config.table,), data=data, workdir=root / "runs",
        out=root / "reports", tracker="mlflow", tracking_uri=f"sqlite:///{root / 'mlflow.db'}",
        quiet=True, executor=ExecutorConfig(workers=1),
    )  # fmt: skip
    # In a fresh interpreter, as a user starts it; its own cache, no tracking URI of ours.
    log = root / "reproduce.log"
    start = time.perf_counter()
    try:
        result = run_fresh(
            reproduce, run, env={"UAVBENCH_CACHE": str(root / "cache")},
            unset=("MLFLOW_TRACKING_URI",), cwd=root, log=log,
        )  # fmt: skip
        ok, outcome = result.ok, f"{len(result.failures)} unit(s) failed"
    except FreshProcessError as err:
        ok, outcome = False, err.error or f"died with exit {err.exitcode}"
    seconds = time.perf_counter() - start
    if not ok:
        tail = log.read_text(errors="replace").splitlines()[-15:] if log.is_file() else []
        return False, [
            f"smoke reproduction ({config.table}): FAILED, {outcome} after {seconds:.0f} s; "
            f"last lines of {log}:",
            *(f"  {line}" for line in tail),
        ]
    where = run_devices(f"sqlite:///{root / 'mlflow.db'}")
    report = root / "reports" / f"{config.table}.md"
    return True, [
        f"smoke reproduction ({config.table}): ok in {seconds:.0f} s; trained models on {where}; "
        f"report {report if config.keep else report.name}"
    ]


def run_devices(uri: str) -> str:
    """``device, precision (accelerator) xN`` of the trained models in the store ``uri``: their
    MLflow tags, one count per distinct ``model_key`` (a table's row run repeats its unit's
    tags); several values are joined by ' / '."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    models: dict[str, str] = {}
    for exp in client.search_experiments():
        for run in client.search_runs([exp.experiment_id], max_results=1000):
            tags = run.data.tags
            if "device" in tags:
                precision, name = tags.get("precision", "?"), tags.get("accelerator", "?")
                models[tags.get("model_key", run.info.run_id)] = (
                    f"{tags['device']}, {precision} ({name})"
                )
    if not models:
        return "(no run recorded its device)"
    counts: dict[str, int] = {}
    for where in models.values():
        counts[where] = counts.get(where, 0) + 1
    return " / ".join(f"{k} x{n}" for k, n in counts.items())


def bench_lines(
    config: AcceleratorBenchConfig, device: torch.device, precisions: list[str]
) -> list[str]:
    """``bench train`` at 224 px, width 1.0 (``--fast``: 48 px, width 0.25, batch 4) in each
    precision, and the conv ceiling; one line each."""
    from benchmark.bench import train as bench

    size, width, batch, sats = (48, 0.25, 4, 2) if config.fast else (224, 1.0, 20, 4)
    train = bench.TrainBenchConfig(
        batch_size=batch,
        distinct_sat=sats,
        steps=config.steps,
        warmup=1,
        plain=False,
        base=False,
        ceiling_batch=2 if config.fast else None,
    )
    results, ceilings, _ = bench.measure_profiled(size, width, train, device, precisions)
    by = {r.precision: r for r in results}
    lines = []
    for r in results:
        ratio = (
            f", {r.pairs_per_s / by['fp32'].pairs_per_s:.2f}x fp32"
            if r.precision != "fp32" and "fp32" in by
            else ""
        )
        share = f", {100 * r.ceiling_share:.0f}% of its conv ceiling" if r.ceiling_share else ""
        lines.append(
            f"train {size} px width {width:g} batch {batch} {r.precision}: {r.pairs_per_s:.2f} "
            f"pairs/s ({r.gflops:.0f} GFLOP/s{share}{ratio})"
        )
    for precision, gflops in ceilings.items():
        lines.append(f"conv ceiling {precision}: {gflops:.0f} GFLOP/s")
    if "fp32" in by:
        pairs = 15e6  # the paper profile: 26 runs x 24,000 pairs x 30 epochs ~ 15 million steps
        best = max(results, key=lambda r: r.pairs_per_s)
        lines.append(
            f"paper profile estimate: {pairs / best.pairs_per_s / 3600:.1f} h of training at "
            f"{best.pairs_per_s:.2f} pairs/s ({best.precision}, 15 million pair-steps, one "
            "process)" + (" [--fast: tiny model, not the paper's]" if config.fast else "")
        )
    return lines


def latency_lines(
    config: AcceleratorBenchConfig, device: torch.device, precisions: list[str]
) -> list[str]:
    """Median inference latency per pair (batch 1, eval, decoding included) per precision."""
    import statistics

    from benchmark.models import create_model
    from benchmark.models.info import measure_latency

    size, width, repeats = (48, 0.25, 2) if config.fast else (224, 1.0, 10)
    lines = []
    for precision in precisions:
        torch.manual_seed(0)
        model = create_model(width=width, input_size=size)
        times = measure_latency(model, size, repeats, 2, device, precision)
        lines.append(
            f"inference latency {size} px width {width:g} {precision}: "
            f"{1e3 * statistics.median(times):.1f} ms/pair (batch 1, median of {repeats})"
        )
    return lines


@dataclass(frozen=True)
class AcceleratorBenchResult:
    """What :func:`bench_accelerator` found on ``device`` in ``precisions``: whether the smoke
    reproduction ran (``ok``; True when skipped) and its lines (``reproduction``, empty when
    skipped), the training and conv-ceiling lines (``bench``), the inference latency lines
    (``latency``), the precision plan's ``notes`` (also in the opening lines) and the load
    averages at the end (``end_load``)."""

    device: torch.device
    precisions: tuple[str, ...]
    notes: tuple[str, ...]
    ok: bool
    reproduction: tuple[str, ...]
    bench: tuple[str, ...]
    latency: tuple[str, ...]
    end_load: str

    def lines(self) -> list[str]:
        """A line per figure: reproduction, training, ceilings, latency; then the end load."""
        return [*self.reproduction, *self.bench, *self.latency, f"end: {self.end_load}"]


def bench_accelerator(config: AcceleratorBenchConfig) -> AcceleratorBenchResult:
    """Run the check of ``config``; returns a line per figure and whether the reproduction ran.
    The opening lines (device, torch, load; the CPU's bf16 line; the precision notes) go to
    :func:`benchmark.progress.status` before the minutes of work. InputError: a device or
    precision this machine lacks."""
    from benchmark.bench.train import load_text, resolve
    from benchmark.models.device import accelerator_name
    from benchmark.progress import status

    device, precisions, notes = resolve(config.device, config.precision)
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    cuda = torch.version.cuda or "no"
    status(
        f"accelerator check: {device} ({accelerator_name(device)}); torch {torch.__version__}, "
        f"CUDA build {cuda}, {torch.get_num_threads()} torch threads; {load_text()}"
    )
    if device.type == "cpu":  # native bf16 or not, and the ISA/kernels a training conv ran
        from benchmark.bench.ceiling import cpu_bf16_line

        status(cpu_bf16_line(("fp32", "bf16")))
    for note in notes:
        status(note)
    ok, reproduction = True, []
    if config.reproduce:
        root = config.keep or Path(tempfile.mkdtemp(prefix="uavbench-accel-"))
        root.mkdir(parents=True, exist_ok=True)
        try:
            ok, reproduction = run_reproduction(config, root)
        finally:
            if config.keep is None:
                shutil.rmtree(root, ignore_errors=True)
    bench = bench_lines(config, device, precisions)
    latency = latency_lines(config, device, precisions)
    return AcceleratorBenchResult(
        device, tuple(precisions), tuple(notes), ok, tuple(reproduction), tuple(bench),
        tuple(latency), load_text(),
    )  # fmt: skip
