"""The worked example of docs/adding-a-head.md is a correct head (checked against
scipy and the Cayley transform's closed form). ``tests/test_add_head_guide.py`` runs the whole
guide (file, training, table) in a scratch copy of the repository."""

from __future__ import annotations

import re
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.models import create_head, create_model, list_heads
from benchmark.models import registry as registry_module

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "adding-a-head.md"
TITLE = "# Adding a head in one file"
NAME = "re_net_cayley"


def readme_section() -> str:
    text = GUIDE.read_text(encoding="utf-8")
    assert text.startswith(TITLE), f"{GUIDE} does not start with {TITLE!r}"
    return text[len(TITLE) :]


def readme_example() -> str:
    blocks = re.findall(r"```python\n(.*?)```", readme_section(), flags=re.DOTALL)
    assert blocks, "the section has no python code block"
    return blocks[0]


@pytest.fixture
def example_head(monkeypatch):
    list_heads()
    monkeypatch.setattr(registry_module, "_HEADS", dict(registry_module._HEADS))
    assert NAME not in registry_module._HEADS, (
        f"{NAME!r} is a real head now: pick another example for the guide"
    )
    module = types.ModuleType("readme_example_head")
    exec(compile(readme_example(), str(GUIDE), "exec"), module.__dict__)
    return module


def cayley_reference(c: np.ndarray) -> np.ndarray:
    """``(I - [c]x)^-1 (I + [c]x)`` per row of ``c (B, 3)``, by a linear solve."""
    out = []
    for v in c:
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        out.append(np.linalg.solve(np.eye(3) - K, np.eye(3) + K))
    return np.stack(out)


class TestReadmeExample:
    def test_registers_and_trains(self, example_head):
        assert NAME in list_heads("attitude")
        torch.manual_seed(0)
        model = create_model(variant="a-f", width=0.25, input_size=32, attitude=NAME)
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

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_decode_is_the_cayley_transform(self, example_head, batch):
        """decode(raw) = Cayley transform of scale * raw (closed form by a linear solve) = the
        rotation by 2 atan|c| about c (scipy)."""
        head = create_head(NAME, in_features=4, scale=2.0).double()
        raw = torch.randn(batch, 3, generator=torch.Generator().manual_seed(batch)).double()
        c = 2.0 * raw.numpy()
        R = head.decode(raw).numpy()
        np.testing.assert_allclose(R, cayley_reference(c), atol=1e-12)
        norm = np.linalg.norm(c, axis=1, keepdims=True)
        rotvec = c / norm * 2 * np.arctan(norm)
        np.testing.assert_allclose(R, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)

    def test_option_and_loss(self, example_head):
        """``scale`` is a real option (same raw, other rotation), checked (> 0); the loss is the
        chordal distance, zero at the label."""
        raw = torch.tensor([[0.3, -0.2, 0.5]], dtype=torch.float64)
        one = create_head(NAME, in_features=4, scale=1.0).double()
        three = create_head(NAME, in_features=4).double()
        assert three.scale == 3.0
        angle = Rotation.from_matrix(one.decode(raw)[0].numpy()).magnitude()
        assert angle == pytest.approx(2 * np.arctan(np.linalg.norm(raw.numpy())), abs=1e-12)
        assert Rotation.from_matrix(three.decode(raw)[0].numpy()).magnitude() > angle
        assert float(one.loss(raw, one.decode(raw))) == pytest.approx(0.0, abs=1e-20)
        R = torch.tensor(Rotation.from_rotvec([0.0, 0.0, 1.0]).as_matrix())[None]
        expected = ((one.decode(raw) - R) ** 2).sum()
        assert float(one.loss(raw, R)) == pytest.approx(float(expected), rel=1e-12)
        with pytest.raises(ValueError, match="scale must be > 0"):
            create_head(NAME, in_features=4, scale=0.0)

    def test_guide_names_the_file_it_registers(self):
        """The file the guide says to save is named after the registered head."""
        section = readme_section()
        saved = re.search(r"Save this as `(baselines/\w+\.py)`", section)
        assert saved is not None and saved.group(1) == f"baselines/{NAME}.py"
        assert f'@register_head("{NAME}")' in readme_example()
