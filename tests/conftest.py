"""Session fixtures shared across test folders."""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pytest

from tests.cpu_kinds import AVX2_ONLY

# --cpu-flags avx2: the CPU flags the project reads (precision_support.cpu_flags) become an
# AVX2-only machine's, in this process (DEVELOPERS.md, "The other CPU kind, on this one"; pair it
# with the environment that gives AVX2 kernels). Tests that compare the flags with the hardware
# take the fixture real_cpu_flags and are skipped then.
FAKE_CPU_FLAGS = {"avx2": AVX2_ONLY}


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--cpu-flags",
        choices=sorted(FAKE_CPU_FLAGS),
        default=None,
        help="run as on a CPU of this kind (its flags only; kernels follow the environment)",
    )


def pytest_configure(config: pytest.Config) -> None:
    kind = config.getoption("--cpu-flags")
    if kind is not None:
        from benchmark.models import precision_support

        flags = frozenset(FAKE_CPU_FLAGS[kind])
        precision_support.cpu_flags = lambda: set(flags)


@pytest.fixture
def real_cpu_flags(request: pytest.FixtureRequest) -> None:
    """For a test that checks the flags against the hardware (/proc/cpuinfo, torch's cpuinfo):
    skipped under ``--cpu-flags``, where they differ on purpose."""
    if request.config.getoption("--cpu-flags") is not None:
        pytest.skip("the CPU flags are faked (--cpu-flags)")


@pytest.fixture(scope="session")
def smoke_dataset(tmp_path_factory):
    """A ``smoke`` dataset (real worlds and renderer, tiny images), rendered once per session."""
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.writer import simulate_dataset

    root = tmp_path_factory.mktemp("smoke-dataset") / "ds"
    cache = tmp_path_factory.mktemp("smoke-cities")
    simulate_dataset(root, DATA_PROFILES["smoke"], 0, workers=1, cache_dir=cache, progress=False)
    return root


@pytest.fixture(autouse=True)
def _no_leaked_tracking_uri():
    """``mlflow.set_tracking_uri`` also writes ``MLFLOW_TRACKING_URI`` into ``os.environ``: a test
    that tracks to a server must not point every later test (and ``uavbench ui``'s default) at a
    server that is gone."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    yield
    if before is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = before
