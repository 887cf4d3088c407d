"""The README's worked example "Adding a head in one file" really runs."""

from __future__ import annotations

import re
import types
from pathlib import Path

import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.models import create_model, list_heads
from benchmark.models import registry as registry_module

README = Path(__file__).resolve().parents[2] / "README.md"
SECTION = "## Adding a head in one file"


def readme_example() -> str:
    text = README.read_text(encoding="utf-8")
    assert SECTION in text, f"README.md has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert blocks, "the section has no python code block"
    return blocks[0]


@pytest.fixture
def example_head(monkeypatch):
    list_heads()
    monkeypatch.setattr(registry_module, "_HEADS", dict(registry_module._HEADS))
    module = types.ModuleType("readme_example_head")
    exec(compile(readme_example(), str(README), "exec"), module.__dict__)
    return module


class TestReadmeExample:
    def test_registers_and_trains(self, example_head):
        assert "re_net_6d" in list_heads("attitude")
        torch.manual_seed(0)
        model = create_model(variant="a-f", width=0.25, input_size=32, attitude="re_net_6d")
        uav, sat = torch.rand(4, 3, 32, 32), torch.rand(4, 3, 32, 32)
        R = torch.tensor(Rotation.random(4, random_state=0).as_matrix(), dtype=torch.float32)
        T = torch.randn(4, 3) * 50
        terms = model.loss(model.train()(uav, sat), R, T)
        assert {"att_aux1", "att_aux2"} <= set(terms) and torch.isfinite(terms["total"])
        terms["total"].backward()
        R_hat, _ = model.decode(model.eval()(uav, sat))
        torch.testing.assert_close(
            R_hat.transpose(-1, -2) @ R_hat, torch.eye(3).expand(4, 3, 3), atol=1e-5, rtol=0
        )
        torch.testing.assert_close(torch.linalg.det(R_hat), torch.ones(4), atol=1e-5, rtol=0)

    def test_decode_matches_scipy_for_exact_columns(self, example_head):
        from benchmark.models import create_head

        head = create_head("re_net_6d", in_features=4).double()
        rot = Rotation.random(3, random_state=1)
        M = torch.tensor(rot.as_matrix())
        raw = torch.cat([M[:, :, 0] * 2.0, M[:, :, 1] + 0.5 * M[:, :, 0]], dim=-1)
        torch.testing.assert_close(head.decode(raw), M)
