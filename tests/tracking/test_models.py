"""The servable wrapper (``benchmark.tracking.models``): one tensor in, one out, and the same
numbers as the evaluation's path (``model(uav, sat, None, context)`` then ``decode``)."""

from __future__ import annotations

import pytest
import torch

from benchmark.data import PairDataset
from benchmark.models import create_model
from benchmark.tracking.models import (
    CONTEXT_PLANES,
    WITH_CONTEXT,
    PosePredictor,
    pack_items,
    pack_pair,
    unpack_context,
)

SIZE = 32  # the smoke dataset's images


@pytest.fixture(scope="module")
def items(smoke_dataset):
    data = PairDataset(smoke_dataset, "standard/train", verify="size")
    return [data[i] for i in range(3)]


def matching_model(protocol: str) -> torch.nn.Module:
    torch.manual_seed(0)
    return create_model(
        encoder="matching",
        variant="/",
        input_size=SIZE,
        encoder_options={"protocol": protocol, "cell_m": 100.0, "template_m": 200.0},
    ).eval()


def reference(model, items, with_context: bool) -> torch.Tensor:
    """The evaluation's numbers: the model called on the collated items, then decoded."""
    uav = torch.stack([i["uav"] for i in items])
    sat = torch.stack([i["sat"] for i in items])
    context = None
    if with_context:
        context = {k: torch.stack([i["context"][k] for i in items]) for k in items[0]["context"]}
    with torch.no_grad():
        R, T = model.decode(model(uav, sat, None, context))
    return torch.cat([R.reshape(-1, 9), T], 1)


class TestPackItems:
    def test_context_planes_round_trip(self, items):
        pair = pack_items(items)
        assert pair.shape == (3, WITH_CONTEXT, SIZE, SIZE)
        assert pair.dtype == torch.float32
        context = unpack_context(pair)
        for key, _ in CONTEXT_PLANES:
            want = torch.stack([i["context"][key] for i in items])
            got = context[key]
            assert got.shape == want.shape
            torch.testing.assert_close(got, want)
        # each plane is constant: the packed number is the same at every pixel
        planes = pair[:, 6:]
        assert torch.equal(planes, planes[:, :, :1, :1].expand_as(planes))

    def test_missing_context_key_named(self, items):
        context = {"fov": torch.stack([i["context"]["fov"] for i in items])}
        uav = torch.stack([i["uav"] for i in items])
        with pytest.raises(ValueError, match="prior_attitude"):
            pack_pair(uav, uav, context)


class TestPosePredictor:
    @pytest.mark.parametrize("protocol", ["vision_only", "gravity_aided"])
    def test_with_context_equals_evaluation(self, items, protocol):
        model = matching_model(protocol)
        with torch.no_grad():
            got = PosePredictor(model)(pack_items(items))
        torch.testing.assert_close(got, reference(model, items, True), rtol=0, atol=0)

    def test_gravity_aided_without_context_says_what_is_missing(self, items):
        model = matching_model("gravity_aided")
        uav = torch.stack([i["uav"] for i in items])
        with pytest.raises(ValueError, match="prior_attitude"):
            PosePredictor(model)(pack_pair(uav, uav))

    def test_without_context_equals_evaluation_of_a_siamese_model(self, items):
        torch.manual_seed(0)
        model = create_model(input_size=SIZE, width=0.25).eval()
        uav = torch.stack([i["uav"] for i in items])
        sat = torch.stack([i["sat"] for i in items])
        with torch.no_grad():
            got = PosePredictor(model)(pack_pair(uav, sat))
        torch.testing.assert_close(got, reference(model, items, False), rtol=0, atol=0)

    def test_wrong_channels_named(self):
        with pytest.raises(ValueError, match=r"\(B, 13, H, W\)"):
            PosePredictor(torch.nn.Identity())(torch.zeros(1, 7, 8, 8))


def test_mlflow_round_trip_with_context(items, tmp_path):
    """Saved in the pytorch flavor and served by pyfunc: the gravity-aided model's numbers."""
    mlflow_pyfunc = pytest.importorskip("mlflow.pyfunc")
    from benchmark.tracking.models import save_pytorch_model

    model = matching_model("gravity_aided")
    example = pack_items(items).numpy()
    path = save_pytorch_model(model, example, tmp_path / "model")
    served = mlflow_pyfunc.load_model(str(path)).predict(example)
    torch.testing.assert_close(
        torch.from_numpy(served), reference(model, items, True), rtol=0, atol=1e-6
    )


def test_logged_models_input_example_carries_the_context(items, smoke_dataset):
    """What ``uavbench train`` and ``reproduce`` log beside a model: the first training pairs of
    the first joined split, with the context planes (a gravity-aided model needs them)."""
    from benchmark.training.config import DataConfig, TrainConfig
    from benchmark.training.tracked_run import model_input_example

    cfg = TrainConfig(
        data=DataConfig(root=str(smoke_dataset), train_split="standard/train+towns/train")
    )
    example = model_input_example(cfg, pairs=3)
    assert example.shape == (3, WITH_CONTEXT, SIZE, SIZE) and example.dtype == "float32"
    torch.testing.assert_close(torch.from_numpy(example), pack_items(items))
