"""Same dataset bytes on every x86-64 CPU (issue 20).

Two checks. Dynamic: the smoke dataset rendered in a fresh interpreter with every library forced
to its baseline instruction set (numpy, OpenBLAS, numba, torch, OpenCV, Arrow, libjpeg-turbo) has
the manifest of the default in-process render (the session's ``smoke_dataset``). On an AVX-512
machine this compares the AVX-512 kernels with the baseline ones, which is exactly the bug of
issue 20; on AVX2 it compares AVX2 with SSE. Static: the simulator and the dataset-writing code
call no run-time-dispatched floating-point kernel except through ``benchmark.sim.detmath``, so
the property does not rot between runs on an AVX-512 machine.
"""

from __future__ import annotations

import ast
import hashlib
import json
from pathlib import Path

import pytest

from benchmark.bench.isa import lower_isa_env, probe, render_manifest

ROOT = Path(__file__).resolve().parents[2]

# numpy functions whose float kernels are dispatched per instruction set (SVML or numpy's own
# AVX2/AVX-512 code: transcendentals), or that call BLAS/LAPACK/pocketfft (products, linalg,
# fft, convolve/correlate through dot, polyfit through lstsq, cov through dot).
NUMPY_DISPATCHED = {
    *("sin", "cos", "tan", "arcsin", "arccos", "arctan", "arctan2", "sinh", "cosh", "tanh"),
    *("arcsinh", "arccosh", "arctanh", "exp", "exp2", "expm1", "log", "log2", "log10", "log1p"),
    *("logaddexp", "logaddexp2", "power", "float_power", "hypot", "cbrt", "angle", "sinc", "i0"),
    *("dot", "vdot", "inner", "matmul", "tensordot", "einsum", "kron", "convolve", "correlate"),
    *("polyfit", "cov", "corrcoef", "linalg", "fft"),
}
# The OpenCV calls left are integer-exact: INTER_AREA resize of uint8 images (integer sums for
# the integer factors of the satellite images, OpenCV's non-dispatched area code otherwise) and
# JPEG coding (libjpeg-turbo's integer DCT is bit-exact across its SIMD paths); plus constants.
CV2_ALLOWED = {
    *("resize", "INTER_AREA", "imencode", "imdecode", "IMWRITE_JPEG_QUALITY", "IMREAD_COLOR"),
    "setNumThreads",
}
# torch: only to give a render worker one thread (no torch arithmetic reaches the dataset).
TORCH_ALLOWED = {"set_num_threads"}
# scipy: compiled C without run-time dispatch (ndimage filters, the k-d tree).
SCIPY_ALLOWED = {"scipy.ndimage.uniform_filter", "scipy.ndimage.maximum_filter"}
SCIPY_ALLOWED |= {"scipy.spatial.cKDTree"}
# Readers that produce no dataset bytes: the torch Dataset, previews (the benches live in
# benchmark/bench/).
NOT_WRITING = {"dataset.py", "preview.py"}


def scanned_files() -> list[Path]:
    sim = [p for p in sorted((ROOT / "benchmark/sim").glob("*.py")) if p.name != "detmath.py"]
    data = [p for p in sorted((ROOT / "benchmark/data").glob("*.py")) if p.name not in NOT_WRITING]
    return sim + data


def dotted(node: ast.AST) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        return ".".join([node.id, *reversed(parts)])
    return None


def _is_njit(fn: ast.FunctionDef) -> bool:
    for dec in fn.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if (dotted(target) or "").split(".")[-1] in ("njit", "jit", "vectorize"):
            return True
    return False


def violations(path: Path) -> list[str]:
    """``line: what`` for every call that may round differently on another instruction set."""
    tree = ast.parse(path.read_text(), str(path))
    njit_lines: set[int] = set()
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef) and _is_njit(fn):
            njit_lines |= set(range(fn.lineno, (fn.end_lineno or fn.lineno) + 1))
    scipy_names: dict[str, str] = {}
    out = []
    for node in ast.walk(tree):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Import | ast.ImportFrom):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "torch":
                out.append(f"{line}: from torch import (kernels follow the ATen CPU capability)")
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("scipy"):
                for a in node.names:
                    full = f"{node.module}.{a.name}"
                    scipy_names[a.asname or a.name] = full
                    if full not in SCIPY_ALLOWED:
                        out.append(f"{line}: imports {full}")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
            out.append(f"{line}: '@' (BLAS); use detmath.matmul")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
            exp, base = node.right, node.left
            int_exp = isinstance(exp, ast.Constant) and type(exp.value) is int
            if int_exp and (exp.value == 2 or line in njit_lines):
                continue  # numpy squares exactly; numba raises to an int by multiplying
            if isinstance(base, ast.Constant) and type(base.value) is int:
                continue  # 2 ** k on integers
            out.append(f"{line}: '**' (libm/SVML pow); use detmath.power or x * x")
        elif isinstance(node, ast.Attribute):
            name = dotted(node) or ""
            head, _, rest = name.partition(".")
            if head in ("np", "numpy") and rest.split(".")[0] in NUMPY_DISPATCHED:
                out.append(f"{line}: {name} (dispatched per instruction set); use detmath")
            elif head == "cv2" and rest not in CV2_ALLOWED:
                out.append(f"{line}: {name} (OpenCV SIMD dispatch)")
            elif head == "torch" and rest not in TORCH_ALLOWED:
                out.append(f"{line}: {name} (torch kernels follow the ATen CPU capability)")
            elif node.attr == "dot" and head not in ("np", "numpy"):
                out.append(f"{line}: .dot (BLAS); use detmath.matmul")
        elif isinstance(node, ast.Call):
            attr = node.func.attr if isinstance(node.func, ast.Attribute) else ""
            name = dotted(node.func) or f"....{attr}"
            if attr in ("argsort", "sort_values"):
                kinds = [k.value for k in node.keywords if k.arg == "kind"]
                if not (
                    kinds and isinstance(kinds[0], ast.Constant) and kinds[0].value == "stable"
                ):
                    out.append(
                        f"{line}: {name} without kind='stable' (numpy's SIMD quicksort orders "
                        "ties by instruction set)"
                    )
    return sorted(set(out), key=lambda s: int(s.split(":")[0]))


class TestNoDispatchedFloatKernels:
    @pytest.mark.parametrize("path", scanned_files(), ids=lambda p: p.relative_to(ROOT).as_posix())
    def test_only_detmath_and_exact_operations(self, path):
        bad = violations(path)
        assert not bad, f"{path.relative_to(ROOT)}:\n  " + "\n  ".join(bad)

    def test_the_scan_finds_what_it_forbids(self, tmp_path):
        src = tmp_path / "bad.py"
        src.write_text(
            "import numpy as np\nimport cv2\nimport torch\nfrom scipy.linalg import svd\n"
            "t = torch.sin(x)\n"
            "a = np.sin(x) + np.linalg.norm(x) + x @ y + x ** 1.5 + x.dot(y) + np.exp(1)\n"
            "b = cv2.GaussianBlur(x, (0, 0), 1.0)\nc = np.argsort(x)\nd = x ** 2 + 2 ** k\n"
            "e = f(x).sort_values('a')\n"
        )
        bad = "\n".join(violations(src))
        for what in ("torch.sin", "scipy.linalg.svd", "np.sin", "np.linalg", "'@'", "'**'", ".dot"):
            assert what in bad, what
        for what in ("np.exp", "cv2.GaussianBlur", "np.argsort without", "sort_values without"):
            assert what in bad, what
        assert bad.count("'**'") == 1  # x ** 2 and 2 ** k are exact


def test_forced_baseline_isa_render_has_the_default_manifest(smoke_dataset, tmp_path):
    env = lower_isa_env()
    effect = probe(env)
    # The variables took effect (numpy 1.x names such as AVX2 are silently ignored by numpy 2.4).
    assert effect["numpy"] == "baseline" and effect["numba"] == "generic", effect
    assert effect["opencv"] == "baseline" and effect["arrow"] == "none", effect
    assert effect["aten"] == "DEFAULT", effect
    forced, sha = render_manifest(
        tmp_path / "forced", env, profile="smoke", workers=1, seed=0, size=None
    )
    default_bytes = (smoke_dataset / "manifest.json").read_bytes()
    default = json.loads(default_bytes)
    differ = sorted(
        f for f, e in forced["files"].items() if default["files"][f]["sha256"] != e["sha256"]
    )
    assert sha == hashlib.sha256(default_bytes).hexdigest(), (
        f"the smoke dataset rendered under {env} differs from the default render in {differ}"
    )


def test_written_metadata_holds_no_machine_facts(smoke_dataset):
    """The manifest, the config and the parquet files' key-value metadata name the code and the
    library versions only: no host, CPU, user, path or date that would differ between machines."""
    import getpass
    import platform
    import socket
    import time

    import pyarrow.parquet as pq

    from benchmark.machine import cpu_model

    texts = {n: (smoke_dataset / n).read_text() for n in ("manifest.json", "config.json")}
    for name in ("uav.parquet", "sat.parquet", "pairs.parquet"):
        meta = pq.read_metadata(smoke_dataset / name)
        texts[name] = meta.created_by + "".join(
            k.decode() + v.decode(errors="replace") for k, v in (meta.metadata or {}).items()
        )
    facts = {socket.gethostname(), cpu_model(), platform.node(), getpass.getuser()}
    facts |= {str(smoke_dataset.parent), time.strftime("%Y-%m-%d"), time.strftime("%Y%m%d")}
    for name, text in texts.items():
        found = sorted(f for f in facts if len(f) >= 4 and f in text)
        assert not found, f"{name} holds machine facts {found}"


class TestBenchIsa:
    def test_registered_as_a_bench_target(self):
        from benchmark.commands.bench import TARGET_HELP, TARGETS

        assert TARGETS["isa"] == "benchmark.commands.bench_isa" and "isa" in TARGET_HELP

    def test_unknown_setting_or_profile_is_a_usage_error(self):
        from benchmark.commands.bench import run_target
        from benchmark.errors import InputError

        def main(argv: list[str]) -> int:
            return run_target("isa", argv)

        with pytest.raises(InputError, match=r"unknown --only \['nope'\]; expected some of"):
            main(["--only", "nope"])
        with pytest.raises(InputError, match="unknown --profile 'tiny'"):
            main(["--profile", "tiny"])

    def test_the_library_refuses_naming_its_config_fields(self):
        """``bench_isa`` itself (a Python caller's entry) names ``IsaBenchConfig``'s fields, not
        the flags, and refuses before rendering anything."""
        from benchmark.bench.isa import IsaBenchConfig, bench_isa
        from benchmark.errors import InputError, UsageError

        for config, field in (
            (IsaBenchConfig(only=("nope",)), r"unknown IsaBenchConfig.only \['nope'\]"),
            (IsaBenchConfig(profile="tiny"), "unknown IsaBenchConfig.profile 'tiny'"),
            (IsaBenchConfig(workers=0), "IsaBenchConfig.workers must be >= 1"),
        ):
            with pytest.raises(InputError, match=field) as error:
                bench_isa(config)
            assert not isinstance(error.value, UsageError) and "--" not in str(error.value)

    def test_result_lines_and_verdict(self):
        """The rows render as the command prints them; ``same`` is false exactly when a row's
        files differ from the default's, and the verdict and the differing files say so."""
        from benchmark.bench.isa import IsaBenchResult, IsaRow

        effect = {"numpy": "X86_V3", "aten": "AVX2"}
        default = IsaRow("default", "a" * 64, True, 1.25, {}, effect, ())
        numba = IsaRow("numba", "b" * 64, False, 2.0, {"NUMBA_CPU_NAME": "generic"}, effect,
                       ("uav/000.npy", "uav/001.npy"))  # fmt: skip
        assert default.lines() == [
            f"default   {'a' * 16}  same      1.2 s  (none)",
            "          in effect: numpy X86_V3, aten AVX2",
        ]
        assert IsaBenchResult((default,)).same
        assert IsaBenchResult((default,)).lines()[-1] == "all digests equal"
        differ = IsaBenchResult((default, numba))
        assert not differ.same
        assert differ.lines()[2] == f"numba     {'b' * 16}  DIFFERS   2.0 s  NUMBA_CPU_NAME=generic"
        assert differ.lines()[-2:] == [
            "numba: files differing from default: uav/000.npy, uav/001.npy",
            "digests differ: the bytes depend on the CPU",
        ]

    def test_settings_name_only_what_this_cpu_dispatches(self):
        from numpy._core import _multiarray_umath as m

        from benchmark.bench.isa import lower_isa_settings

        settings = lower_isa_settings()
        npy = settings.get("numpy", {}).get("NPY_DISABLE_CPU_FEATURES", "").split()
        assert all(f in m.__cpu_dispatch__ and m.__cpu_features__[f] for f in npy)
        assert settings["numba"] == {"NUMBA_CPU_NAME": "generic"}
        assert lower_isa_env()["OPENBLAS_CORETYPE"] == "Prescott"
