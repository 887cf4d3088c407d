"""Implicit-PDF head (baselines/ipdf.py) against independent references: a numpy re-implementation
of the scoring MLP, brute force over the evaluation grid, Monte Carlo over scipy's Haar-uniform
rotations, scipy's entropy, and the grid's own definition (super-Fibonacci)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats
from scipy.spatial.transform import Rotation

import baselines.ipdf as ipdf
from benchmark.geometry import quat_to_rotmat, super_fibonacci
from benchmark.models import create_head

F = 12
SMALL = {"n_train": 256, "n_eval": 4096, "hidden": 32}  # fast variants where size is irrelevant


def make(dtype=torch.float64, **options):
    torch.manual_seed(0)
    return create_head("ipdf", in_features=F, **{**SMALL, **options}).to(dtype).eval()


def feats(batch: int, seed: int = 0) -> torch.Tensor:
    return torch.randn(batch, F, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))


def haar(n: int, seed: int) -> torch.Tensor:
    return torch.tensor(Rotation.random(n, random_state=seed).as_matrix())


def numpy_scores(head, x: np.ndarray, R: np.ndarray) -> np.ndarray:
    """f(x, R) for every (sample, rotation) pair, (B, F), (M, 3, 3) -> (B, M), from the weights."""
    state = {k: v.detach().double().numpy() for k, v in head.state_dict().items()}
    r = R.reshape(len(R), 9)
    code = np.concatenate(
        [r]
        + [f(2**level * np.pi * r) for level in range(head.frequencies) for f in (np.sin, np.cos)],
        axis=1,
    )
    feature = x @ state["feature_layer.weight"].T + state["feature_layer.bias"]
    rotation = code @ state["rotation_layer.weight"].T
    hidden = np.maximum(feature[:, None, :] + rotation[None], 0)
    return hidden @ state["tail.0.weight"][0] + state["tail.0.bias"][0]


def angle_deg(A: torch.Tensor, B: torch.Tensor) -> np.ndarray:
    return np.degrees(
        (
            Rotation.from_matrix(A.detach().numpy()).inv() * Rotation.from_matrix(B.numpy())
        ).magnitude()
    )


class TestPositionalEncoding:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_row_major_entries_then_sin_cos(self, batch):
        R = haar(batch, seed=batch)
        code = ipdf.positional_encoding(R, 2).numpy()
        r = R.numpy().reshape(batch, 9)
        expected = np.concatenate(
            [r, np.sin(np.pi * r), np.cos(np.pi * r), np.sin(2 * np.pi * r), np.cos(2 * np.pi * r)],
            axis=1,
        )
        np.testing.assert_allclose(code, expected, atol=1e-12)


class TestScores:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_numpy_mlp(self, batch):
        head = make()
        x = feats(batch)
        grid = quat_to_rotmat(super_fibonacci(4096, dtype=torch.float64))
        raw = head(x)
        expected = numpy_scores(head, x.numpy(), grid.numpy())
        # The grid buffers are built in float32 (the model's dtype) and cast: ~1e-8 apart.
        np.testing.assert_allclose(raw["logits"].detach().numpy(), expected, atol=1e-6)
        R = haar(batch, seed=3)
        at_R = head.score(raw["embedding"], R).detach().numpy()
        np.testing.assert_allclose(at_R, numpy_scores(head, x.numpy(), R.numpy()).diagonal())

    def test_convention_grids_are_super_fibonacci(self):
        head = make()
        for grid, n in ((head.eval_quat, 4096), (head.train_quat, 256)):
            expected = super_fibonacci(n, dtype=torch.float64)
            torch.testing.assert_close(grid, expected, atol=1e-7, rtol=0)

    def test_chunking_does_not_change_scores(self, monkeypatch):
        head = make()
        x = feats(3)
        whole = head(x)["logits"]
        monkeypatch.setattr(ipdf, "CHUNK_ELEMENTS", 1000)
        torch.testing.assert_close(head(x)["logits"], whole)


class TestReluScores:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_gradcheck_float64_all_inputs(self, batch, monkeypatch):
        monkeypatch.setattr(ipdf, "CHUNK_ELEMENTS", 40)  # several chunks, a short last one
        g = torch.Generator().manual_seed(batch)
        e, r, w = (
            torch.randn(*s, generator=g, dtype=torch.float64) for s in ((batch, 4), (11, 4), (4,))
        )
        inputs = (e.requires_grad_(), r.requires_grad_(), w.requires_grad_())
        assert torch.autograd.gradcheck(ipdf._ReluScores.apply, inputs)

    def test_parameter_gradients_match_plain_autograd(self):
        head = make().train()
        x, R = feats(3), haar(3, seed=1)
        torch.manual_seed(0)
        head.loss(head(x), R).backward()
        fused = {k: p.grad.clone() for k, p in head.named_parameters()}
        head.zero_grad()
        # The same loss with the tail evaluated by torch's own autograd (no fused function).
        embedding = head.feature_layer(x)
        torch.manual_seed(0)
        q = torch.randn(4, dtype=torch.float64)
        turn = quat_to_rotmat(q / q.norm())
        code = ipdf.positional_encoding(head.train_rotmat @ turn, head.frequencies)
        grid = head.tail(torch.relu(embedding[:, None] + head.rotation_layer(code)[None]))[..., 0]
        logits = torch.cat([head.score(embedding, R)[:, None], grid], dim=-1)
        (-torch.log_softmax(logits, -1)[:, 0].mean()).backward()
        for k, p in head.named_parameters():
            torch.testing.assert_close(fused[k], p.grad, msg=k)


class TestLogProb:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_definition(self, batch):
        head = make()
        x = feats(batch)
        R = haar(batch, seed=4)
        grid = quat_to_rotmat(super_fibonacci(4096, dtype=torch.float64)).numpy()
        scores = numpy_scores(head, x.numpy(), grid)
        at_R = numpy_scores(head, x.numpy(), R.numpy()).diagonal()
        expected = at_R - np.log(np.exp(scores).sum(-1)) + np.log(4096)
        np.testing.assert_allclose(head.log_prob(head(x), R).detach().numpy(), expected, atol=1e-6)

    @pytest.mark.parametrize("sharpness", [1.0, 20.0])
    def test_monte_carlo_haar_normalisation(self, sharpness):
        # The default 2^15 grid; the score scaled up to a peaked density (sharpness 20: max density
        # ~100x uniform) still integrates to 1 over scipy's uniform rotations within 3 %.
        head = make(n_eval=2**15, n_train=256, hidden=64)
        with torch.no_grad():
            head.tail[0].weight.mul_(sharpness)
            raw = head(feats(2, seed=7))
            R = haar(6000, seed=8)
            for i in range(2):
                one = {k: v[i : i + 1].expand(len(R), *v.shape[1:]) for k, v in raw.items()}
                density = torch.exp(head.log_prob(one, R))
                se = density.std().item() / math.sqrt(len(R))
                assert density.max() > sharpness  # it is peaked
                assert density.mean().item() == pytest.approx(1.0, abs=5 * se + 0.03)

    def test_convention_uniform_scores_zero(self):
        head = make()
        with torch.no_grad():
            head.tail[0].weight.zero_()
        raw = head(feats(3))
        torch.testing.assert_close(head.log_prob(raw, haar(3, 1)), torch.zeros(3).double())
        torch.testing.assert_close(head.uncertainty(raw), torch.ones(3).double())


class TestDecode:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_brute_force_over_the_grid(self, batch):
        # The decode starts at the grid rotation with the highest score (numpy brute force) and
        # moves at most DECODE_RADIUS grid spacings from it.
        head = make(hidden=64)
        x = feats(batch, seed=5)
        grid = quat_to_rotmat(super_fibonacci(4096, dtype=torch.float64))
        best = grid[numpy_scores(head, x.numpy(), grid.numpy()).argmax(-1)]
        spacing = math.degrees((8 * math.pi**2 / 4096) ** (1 / 3))
        assert (angle_deg(head.decode(head(x)), best) <= ipdf.DECODE_RADIUS * spacing).all()

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_target_decodes_to_the_label(self, batch):
        head = make(n_eval=2**15)
        R = haar(batch, seed=6)
        assert angle_deg(head.decode_distribution(head.target_distribution(R)), R).max() < 0.3

    def test_decode_equals_decode_distribution_without_refinement(self):
        head = make()
        raw = head(feats(4))
        torch.testing.assert_close(
            head.decode(raw), head.decode_distribution(head.distribution(raw))
        )

    def test_refinement_climbs_the_score(self):
        plain, refined = make(hidden=64), make(hidden=64, refine_steps=50)
        x = feats(5, seed=2)
        raw = plain(x)
        before = plain.score(raw["embedding"], plain.decode(raw))
        after = plain.score(raw["embedding"], refined.decode(raw))
        assert (after >= before - 1e-9).all() and (after > before + 1e-6).any()

    def test_wrong_grid_size(self):
        with pytest.raises(ValueError, match="4096-point evaluation grid"):
            make().decode_distribution(torch.full((2, 100), 0.01))


class TestLoss:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_eval_mode_is_the_labels_cross_entropy_on_the_fixed_grid(self, batch):
        head = make()
        x, R = feats(batch), haar(batch, seed=9)
        grid = quat_to_rotmat(super_fibonacci(256, dtype=torch.float64)).numpy()
        logits = np.concatenate(
            [
                numpy_scores(head, x.numpy(), R.numpy()).diagonal()[:, None],
                numpy_scores(head, x.numpy(), grid),
            ],
            axis=1,
        )
        expected = -(logits[:, 0] - np.log(np.exp(logits).sum(-1))).mean()
        assert head.loss(head(x), R).item() == pytest.approx(expected, abs=1e-6)

    def test_training_turns_the_grid_reproducibly(self):
        head = make().train()
        x, R = feats(3), haar(3, seed=2)
        losses = []
        for seed in (0, 0, 1):
            torch.manual_seed(seed)
            losses.append(head.loss(head(x), R).item())
        assert losses[0] == losses[1] != losses[2]
        assert head.eval().loss(head(x), R).item() not in losses

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_gradcheck_float64(self, batch):
        head = make().train()
        R = haar(batch, seed=batch)

        def loss(x: torch.Tensor) -> torch.Tensor:
            with torch.random.fork_rng():
                torch.manual_seed(0)
                return head.loss(head(x), R)

        assert torch.autograd.gradcheck(loss, (feats(batch).requires_grad_(),), atol=1e-6)


class TestUncertainty:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_normalised_entropy_against_scipy(self, batch):
        head = make()
        raw = head(feats(batch))
        p = head.distribution(raw).detach().numpy()
        expected = stats.entropy(p, axis=-1) / math.log(4096)
        np.testing.assert_allclose(head.uncertainty(raw).detach().numpy(), expected, atol=1e-10)


class TestOptions:
    @pytest.mark.parametrize(
        "option,value",
        [
            ("hidden", 0),
            ("layers", 0),
            ("frequencies", -1),
            ("n_train", 4),
            ("n_eval", 2.5),
            ("refine_steps", -1),
            ("target_kappa", 0.0),
            ("hidden", True),
        ],
    )
    def test_bad_option(self, option, value):
        with pytest.raises(ValueError, match=f"{option}.*{value!r}"):
            create_head("ipdf", in_features=F, **{option: value})

    def test_layers_adds_hidden_layers(self):
        head = create_head("ipdf", in_features=F, layers=3, hidden=16, n_eval=64, n_train=64)
        assert sum(isinstance(m, torch.nn.Linear) for m in head.tail) == 3
        assert head.eval()(torch.randn(2, F))["logits"].shape == (2, 64)
