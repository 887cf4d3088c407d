"""The rendered scene of ``scene.py``, built once per session (a 1.5 km x 1 km town, 96 px)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def scene(tmp_path_factory):
    from scene import build_scene

    return build_scene(tmp_path_factory.mktemp("reference-town"))
