"""The stored-reference computations of the training tests, and how far other CPU kernels move them.

Two tests compare training results with numbers stored on one AVX2 machine:
``test_devices.py::TestCpuDefaultsUnchanged`` (:func:`devices_numbers`) and
``test_loop.py::TestSameNumbersAsBeforeIssue13`` (:func:`loop_numbers`). Both import their
computation from here, so what this script measures is exactly what the tests compute.

A float32 training run is bit-reproducible on one machine but not across instruction sets: oneDNN
(convolutions), MKL (matrix products) and ATen's vectorised kernels (reductions, elementwise ops)
pick AVX2, AVX-512 or AMX code at run time, and a different vector width sums in a different order.
Two epochs of SGD/Adam amplify the last-bit differences. To size the tolerance without an AVX-512
machine, ``python tests/training/cross_isa.py`` reruns the computations in subprocesses with the
other kernels forced (the variables must be set before torch is imported) and prints the largest
difference of each number against the default run::

    ONEDNN_MAX_CPU_ISA=SSE41 | AVX     oneDNN convolution kernels
    MKL_ENABLE_INSTRUCTIONS=AVX | SSE4_2   MKL's sgemm
    ATEN_CPU_CAPABILITY=default        ATen's vectorised ops without AVX2

(``--json FILE`` writes everything; ``--quick`` skips the loop test's four runs.)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent

# Tolerances of the stored-reference checks, from the measurement below (AMD EPYC, AVX2, torch
# 2.13.0+cpu, 2026-12-02; largest difference over the forced kernels onednn-avx, onednn-sse41,
# aten-default and all-sse against the default AVX2 run; MKL_ENABLE_INSTRUCTIONS changed nothing):
#   devices, last epoch's losses: 7.2e-6 relative on that machine and on an AVX-512 AMD EPYC;
#     an Intel Xeon with AVX-512 and avx512_bf16 (2026-12-02, stop 25) is 5.9e-5 away
#     (val_loss_tran; the training losses within 8.9e-6), where MKL_ENABLE_INSTRUCTIONS does
#     change the numbers (all-sse 9.3e-4 from its own default) -> 5e-4, a margin of 8x over the
#     farthest CPU seen. Only the losses: they average every pair. The evaluation's per-frame
#     metrics on 6 validation pairs are not a cross-CPU truth (on that Xeon: median dphi 5.5e-4,
#     dgamma 1.3e-2 relative, the rank correlation of 6 frames -0.49 -> -0.31), so
#     ``test_devices`` checks them bit for bit between ``auto`` and ``cpu/fp32`` on one machine
#     and not against a stored number;
#   loop, decoded R entries: 2.35e-3 absolute (the AVX-512: 1.7e-3) -> 1e-2, 4x;
#   loop, decoded T: 0.34 m absolute (|T| up to 67 m; Adam turns last-bit differences of tiny
#     gradients into whole steps of lr) -> 1.5 m, 4.5x.
DEVICES_LOSS_REL = 5e-4
LOOP_R_ATOL = 1e-2
LOOP_T_ATOL_M = 1.5

VARIANTS: dict[str, dict[str, str]] = {
    "default": {},
    "onednn-avx": {"ONEDNN_MAX_CPU_ISA": "AVX"},
    "onednn-sse41": {"ONEDNN_MAX_CPU_ISA": "SSE41"},
    "mkl-avx": {"MKL_ENABLE_INSTRUCTIONS": "AVX"},
    "mkl-sse42": {"MKL_ENABLE_INSTRUCTIONS": "SSE4_2"},
    "aten-default": {"ATEN_CPU_CAPABILITY": "default"},
    "all-sse": {
        "ONEDNN_MAX_CPU_ISA": "SSE41",
        "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
        "ATEN_CPU_CAPABILITY": "default",
    },
}

# Override sets of test_loop.py::TestSameNumbersAsBeforeIssue13 (with optim.name=adam).
LOOP_OVERRIDES: list[tuple[str, ...]] = [
    (),
    ("model.attitude=re_net_r", "model.variant=/"),
    ("model.attitude=pd_net_e", "model.variant=/", "model.attitude_options.kappa=5"),
    ("model.translation=re_net_t", "model.variant=a"),
]


def devices_numbers(
    out: Path, *overrides: str
) -> tuple[dict[str, float], dict[str, float], object]:
    """``tiny_config(*overrides)`` trained on ``TinyPairs(12, seed=0)`` with validation on
    ``TinyPairs(6, seed=1)``, one torch thread, then evaluated at batch 4: ``(last epoch's record,
    evaluation summary, trained model)`` (timing keys dropped)."""
    import torch
    from tiny_pairs import TinyPairs, tiny_config

    from benchmark.evaluation.evaluate import evaluate
    from benchmark.training import model_factory, train

    torch.set_num_threads(1)
    cfg = tiny_config(*overrides)
    val = TinyPairs(6, seed=1)
    res = train(cfg, model_factory(cfg, 32), TinyPairs(12, seed=0), val, out, progress=False)
    last = {k: v for k, v in res.history[-1].items() if k not in ("epoch_time_s", "pairs_per_s")}
    summary, _ = evaluate(res.model.eval(), val, batch_size=4)
    return last, {k: float(v) for k, v in summary.items()}, res.model


def loop_numbers(out: Path, overrides: tuple[str, ...]) -> tuple[list[float], list[float], object]:
    """test_loop's reference computation: ``tiny_config(*overrides, "optim.name=adam")`` trained
    on ``TinyPairs(12, seed=0)`` (validation ``TinyPairs(6, seed=1)``), then the first three
    validation pairs decoded: ``(R.flatten()[:4], T.flatten()[:2] metres, trained model)``."""
    import torch
    from tiny_pairs import TinyPairs, tiny_config

    from benchmark.training import model_factory, train

    cfg = tiny_config(*overrides, "optim.name=adam")
    train_set, val = TinyPairs(12, seed=0), TinyPairs(6, seed=1)
    model = train(cfg, model_factory(cfg, 32), train_set, val, out, progress=False).model.eval()
    with torch.no_grad():
        R, T = model.decode(model(val.uav[:3], val.sat[val.sat_id[:3]]))
    return R.flatten()[:4].tolist(), T.flatten()[:2].tolist(), model


def _child(quick: bool) -> dict[str, object]:
    import torch

    torch.set_num_threads(1)
    result: dict[str, object] = {"capability": torch.backends.cpu.get_cpu_capability()}
    with tempfile.TemporaryDirectory() as tmp:
        last, summary, _ = devices_numbers(Path(tmp) / "devices")
        result["devices"] = {"last": last, "eval": summary}
        if not quick:
            loop = {}
            for i, overrides in enumerate(LOOP_OVERRIDES):
                R, T, _ = loop_numbers(Path(tmp) / f"loop{i}", overrides)
                loop[" ".join(overrides) or "(defaults)"] = {"R": R, "T": T}
            result["loop"] = loop
    return result


def _rel(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300) if a != b else 0.0


def compare(base: dict, other: dict) -> dict[str, float]:
    """Largest differences of ``other`` against ``base``: relative over the devices test's
    numbers, absolute over the loop test's decoded R entries and T metres."""
    out = {}
    for part in ("last", "eval"):
        a, b = other["devices"][part], base["devices"][part]
        out[f"devices_{part}_max_rel"] = max(_rel(a[k], b[k]) for k in b if math.isfinite(b[k]))
        out[f"devices_{part}_median_dphi_rel"] = _rel(
            a.get("val_median_dphi_deg", a.get("median_dphi_deg", 0.0)),
            b.get("val_median_dphi_deg", b.get("median_dphi_deg", 0.0)),
        )
    if "loop" in base and "loop" in other:
        out["loop_R_max_abs"] = max(
            abs(x - y)
            for key in base["loop"]
            for x, y in zip(other["loop"][key]["R"], base["loop"][key]["R"], strict=True)
        )
        out["loop_T_max_rel"] = max(
            _rel(x, y)
            for key in base["loop"]
            for x, y in zip(other["loop"][key]["T"], base["loop"][key]["T"], strict=True)
        )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="the devices test only")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(HERE))
    if args.child:
        print(json.dumps(_child(args.quick)))
        return 0
    runs = {}
    for name in args.variants.split(","):
        env = {**os.environ, "OMP_NUM_THREADS": "1", **VARIANTS[name]}
        cmd = [sys.executable, __file__, "--child"] + (["--quick"] if args.quick else [])
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        runs[name] = json.loads(done.stdout.strip().splitlines()[-1])
        print(f"{name}: ATen capability {runs[name]['capability']}", flush=True)
    diffs = {name: compare(runs["default"], run) for name, run in runs.items() if name != "default"}
    for name, d in diffs.items():
        print(name, " ".join(f"{k}={v:.3g}" for k, v in d.items()))
    if args.json:
        args.json.write_text(json.dumps({"runs": runs, "diffs": diffs}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
