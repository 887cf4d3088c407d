"""A real MLflow tracking server on loopback, shared by the tests of this directory.

Reuse elsewhere (e.g. a reproduction test) with the same three lines::

    from benchmark.tracking.server import MlflowServer
    with MlflowServer(f"sqlite:///{tmp / 'mlflow.db'}", tmp / "artifacts") as server:
        ...  # point the tracker at server.url
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from benchmark.tracking.server import MlflowServer


@pytest.fixture(scope="module")
def mlflow_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[MlflowServer]:
    """Started once per test module (about 8 s), stopped (whole process group) at the end."""
    tmp = tmp_path_factory.mktemp("mlflow-server")
    server = MlflowServer(
        f"sqlite:///{tmp / 'mlflow.db'}",
        tmp / "artifacts",
        log_path=tmp / "server.log",
    )
    with server:
        yield server
