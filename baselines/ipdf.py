"""Implicit-PDF (Murphy, Esteves, Jampani, Ramalingam and Makadia, ICML 2021).

Representation: an MLP ``f(x, R)`` scores a (feature, rotation) pair; the predicted density w.r.t.
the normalised Haar measure on SO(3) is ``p(R | x) = exp f(x, R) / int exp f(x, R') dR'``, with the
integral taken over an equivolumetric grid. Architecture (IPDF's): the feature vector and the
rotation's encoding each go through a linear layer to ``hidden`` units, are summed, then
``layers`` ReLU + linear layers end in one score. The feature half is computed once per sample and
the rotation half once per grid rotation, so scoring a grid costs ``B * M * hidden`` per layer after
the sum. Rotation encoding: the 9 entries of R (row-major) and, for ``l < frequencies``, their
``sin(2^l pi r)`` and ``cos(2^l pi r)`` (IPDF's positional encoding of the flattened matrix; with
the default 3 frequencies 63 numbers; the finest period, 0.5 in a matrix entry, is ~30 deg).

Grids: unit quaternions of the super-Fibonacci spiral (``super_fibonacci``), uniform for the Haar
measure as rotations: ``n_train`` (4096, spacing (8 pi^2 / N)^(1/3) = 12 deg) for the training
loss, ``n_eval`` (2^15, 7.7 deg) for everything else. Measured cost, one script timing the heads
side by side (one thread on this shared 2-core CPU, hidden 256, layers 1, the quick reproduction's
model: 96 px, width 0.25, variant a-f): one training step at batch 20 (forward, loss with the two
auxiliary heads, backward, Adam) 345 ms min / 405 median against 175 / 209 for ``re_net_r`` (the
head alone on 1024 features: 46 / 48 ms against 3 / 3); evaluating a batch of 64 (forward, decode,
loss, log_prob, uncertainty) 0.50 s against 0.18 s, ~9 s for 1200 pairs. ``layers=2`` adds a
256 x 256 product per grid rotation and measured 5-10x slower in evaluation, hence the default 1.
The fused ``_ReluScores`` halved the head's training cost (93 -> 46 ms alone).

Training (IPDF's likelihood): the query set is the label plus the training grid; the loss is the
cross-entropy of the label against it, ``-log softmax([f(R_gt), f(R_1..N)])_0``, mean over the
batch. Minimising it raises the label's score against the grid, i.e. the label's likelihood. In
training mode the grid is turned by one Haar-random rotation per call (``R_k Q``, Q from a
normalised Gaussian quaternion drawn from torch's global generator, so a seeded run is
reproducible); IPDF's training queries likewise change from step to step. In eval mode it is the
fixed grid (a deterministic loss value). A fixed training grid only pins the score down at the same
4096 rotations, 12 deg apart: measured on 8 dataset-like labels (Adam lr 1e-3, 300 steps) the
decoded rotations missed by up to 6.1 deg with a fixed grid, 1.9 deg with the turned one (0.47 deg
with ``refine_steps=100``).

``log_prob(raw, R) = f(x, R) - logsumexp_k f(x, R_k) + log N`` on the evaluation grid: the density
w.r.t. the normalised Haar measure (each grid rotation stands for a cell of volume 1/N), so a
uniform prediction scores 0.

Grid contract (``is_probabilistic``): ``distribution(raw)`` is the softmax of the scores over the
evaluation grid (B, n_eval). ``target_distribution(R)`` is a narrow kernel on that grid,
``softmax_k(4 target_kappa (q . q_k)^2)`` (a matrix Fisher kernel with ``F = target_kappa R``,
angular std ~1/sqrt(2 target_kappa) = 5.7 deg per axis at the default 50); it is what
``decode_distribution`` must recover, not a training target (training uses the likelihood).
``decode_distribution(p)``: the grid argmax, refined within ``DECODE_RADIUS`` grid spacings of it
by the principal eigenvector of ``sum p_k q_k q_k^T`` (the mode of the local mass, sign-free in q);
a distribution with several modes decodes to the highest one. ``decode(raw)`` is
``decode_distribution(distribution(raw))`` and then, with ``refine_steps > 0`` (default 0, which
keeps the contract's identity exact), that many Adam steps (lr ``REFINE_LR`` rad) of gradient
ascent on ``f(x, R0 exp([d]x))`` over the local rotation vector d, IPDF's gradient refinement.

Uncertainty: the normalised entropy ``H(p) / log N`` of the grid distribution, in [0, 1] (1 =
uniform).

Discontinuities: none in the representation (a function on SO(3) itself, scored at the matrix);
the argmax jumps between modes when two are (nearly) equally high, which is inherent to any mode
decoder of a multimodal density.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from benchmark.geometry import quat_to_rotmat, rotmat_to_quat, rotvec_to_rotmat, super_fibonacci
from benchmark.models import AttitudeHead, GridDistribution, register_head
from benchmark.models.heads import check_option

DECODE_RADIUS = 3.5  # neighbourhood of the argmax, in grid spacings (8 pi^2 / N)^(1/3) rad
REFINE_LR = 2e-3  # rad per Adam step of the gradient refinement
CHUNK_ELEMENTS = 2**20  # B * grid chunk * hidden floats per scoring step (4 MB in float32)


def positional_encoding(R: Tensor, frequencies: int) -> Tensor:
    """``(..., 3, 3) -> (..., 9 (1 + 2 frequencies))``: the entries and their sin/cos at
    ``2^l pi``."""
    r = R.flatten(-2)
    parts = [r]
    for level in range(frequencies):
        parts += [torch.sin((2**level * math.pi) * r), torch.cos((2**level * math.pi) * r)]
    return torch.cat(parts, dim=-1)


def _check_int(value: object, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"ipdf: {name} must be an int >= {minimum}, got {value!r}")
    return value


def _relu_sums(e: Tensor, r: Tensor):
    """Yield ``(start, relu(e[:, None] + r[start:start + n][None]))`` chunk by chunk, each in the
    same reused (B, n, hidden) buffer (fresh multi-MB tensors per chunk cost page faults that
    measured several times the arithmetic)."""
    chunk = max(1, CHUNK_ELEMENTS // max(1, e.shape[0] * e.shape[1]))
    buffer = e.new_empty(e.shape[0], min(chunk, r.shape[0]), e.shape[1])
    for start in range(0, r.shape[0], chunk):
        part = r[start : start + chunk]
        summed = buffer[:, : part.shape[0]]
        torch.add(e[:, None], part[None], out=summed)
        yield start, summed.relu_()


class _ReluScores(torch.autograd.Function):
    """``s_bk = w . relu(e_b + r_k)``: (B, h), (M, h), (h,) -> (B, M), for the 1-layer tail.

    Nothing of size B * M * h is kept: the backward recomputes each chunk's activations and uses
    ``d s_bk / d e_b = d s_bk / d r_k = w * [e_b + r_k > 0]``, ``d s_bk / d w = relu(e_b + r_k)``
    (the ReLU's derivative at 0 taken as 0, as torch's).
    """

    @staticmethod
    def forward(ctx, e: Tensor, r: Tensor, w: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(e, r, w)
        out = e.new_empty(e.shape[0], r.shape[0])
        for start, hidden in _relu_sums(e, r):
            out[:, start : start + hidden.shape[1]] = hidden @ w
        return out

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, Tensor, Tensor]:  # type: ignore[override]
        e, r, w = ctx.saved_tensors
        grad_e, grad_r, grad_w = torch.zeros_like(e), torch.empty_like(r), torch.zeros_like(w)
        for start, hidden in _relu_sums(e, r):
            g = grad[:, start : start + hidden.shape[1]]  # (B, n)
            grad_w += torch.einsum("bn,bnh->h", g, hidden)
            active = hidden.gt_(0)  # in place: 1.0 where the ReLU passes, else 0.0
            grad_e += torch.einsum("bn,bnh->bh", g, active)
            grad_r[start : start + hidden.shape[1]] = torch.einsum("bn,bnh->nh", g, active)
        return grad_e * w, grad_r * w, grad_w


@register_head("ipdf")
class ImplicitPDF(GridDistribution, AttitudeHead):
    """Args: in_features; hidden (256); layers (1, after the sum); frequencies (3); n_train
    (4096); n_eval (2^15); refine_steps (0); target_kappa (50, > 0).

    raw: ``{"embedding": (B, hidden)}`` (the feature half of the first layer) and, from a forward
    in eval mode, ``"logits": (B, n_eval)`` scores on the evaluation grid (computed on demand
    otherwise).
    """

    paper_name = "Implicit-PDF (Murphy et al. 2021)"

    def __init__(
        self,
        in_features: int,
        hidden: int = 256,
        layers: int = 1,
        frequencies: int = 3,
        n_train: int = 4096,
        n_eval: int = 2**15,
        refine_steps: int = 0,
        target_kappa: float = 50.0,
    ) -> None:
        super().__init__(in_features)
        hidden = _check_int(hidden, "hidden", 1)
        layers = _check_int(layers, "layers", 1)
        self.frequencies = _check_int(frequencies, "frequencies", 0)
        n_train = _check_int(n_train, "n_train", 8)
        n_eval = _check_int(n_eval, "n_eval", 8)
        self.refine_steps = _check_int(refine_steps, "refine_steps", 0)
        self.target_kappa = check_option(target_kappa, "target_kappa", "ipdf")
        self.feature_layer = nn.Linear(in_features, hidden)
        self.rotation_layer = nn.Linear(9 * (1 + 2 * self.frequencies), hidden, bias=False)
        # After the sum and its ReLU (applied in _tail): layers - 1 hidden layers, then the score.
        tail: list[nn.Module] = []
        for _ in range(layers - 1):
            tail += [nn.Linear(hidden, hidden), nn.ReLU()]
        self.tail = nn.Sequential(*tail, nn.Linear(hidden, 1))
        for name, n in (("train", n_train), ("eval", n_eval)):
            q = super_fibonacci(n, dtype=torch.float64)
            R = quat_to_rotmat(q)
            self.register_buffer(f"{name}_quat", q.float(), persistent=False)
            self.register_buffer(f"{name}_rotmat", R.float(), persistent=False)
            code = positional_encoding(R, self.frequencies).float()
            self.register_buffer(f"{name}_code", code, persistent=False)

    # -- scoring -------------------------------------------------------------------------------
    def forward(self, features: Tensor) -> dict[str, Tensor]:
        """(B, F) -> raw (class docstring); eval mode adds the evaluation-grid logits."""
        raw = {"embedding": self.feature_layer(features)}
        if not self.training:
            raw["logits"] = self.grid_scores(raw["embedding"], self.eval_code)
        return raw

    def score(self, embedding: Tensor, R: Tensor) -> Tensor:
        """``f(x, R)`` for one rotation per sample: (B, hidden), (B, 3, 3) -> (B,)."""
        code = positional_encoding(R.to(embedding.dtype), self.frequencies)
        return self._tail(embedding + self.rotation_layer(code))

    def _tail(self, summed: Tensor) -> Tensor:
        """ReLU of the summed first layer, the rest of the MLP: (..., hidden) -> (...)."""
        # In place without autograd (evaluation): the grid's (B, chunk, hidden) activations are
        # the whole cost, and a second buffer of them doubles the memory traffic.
        hidden = torch.relu_(summed) if not torch.is_grad_enabled() else torch.relu(summed)
        return self.tail(hidden).squeeze(-1)

    def grid_scores(self, embedding: Tensor, code: Tensor) -> Tensor:
        """``f(x, R_k)`` for every grid rotation: (B, hidden), (M, D) codes -> (B, M).

        With ``layers=1`` the sum, ReLU and score are fused (``_ReluScores``); otherwise chunked
        over the grid (at most ``CHUNK_ELEMENTS`` activations per step; autograd keeps them all).
        """
        rotation = self.rotation_layer(code.to(embedding.dtype))  # (M, hidden)
        if len(self.tail) == 1:
            last = self.tail[0]
            return _ReluScores.apply(embedding, rotation, last.weight[0]) + last.bias
        batch, hidden = embedding.shape
        chunk = max(1, CHUNK_ELEMENTS // max(1, batch * hidden))
        parts = [self._tail(embedding[:, None] + part[None]) for part in rotation.split(chunk)]
        return torch.cat(parts, dim=-1)

    def _eval_logits(self, raw: dict[str, Tensor]) -> Tensor:
        logits = raw.get("logits")
        if logits is None:
            logits = self.grid_scores(raw["embedding"], self.eval_code)
        return logits

    # -- contract ------------------------------------------------------------------------------
    def loss(self, raw: dict[str, Tensor], R_gt: Tensor) -> Tensor:
        """Cross-entropy of the label against {label} + training grid, mean over the batch."""
        embedding = raw["embedding"]
        at_label = self.score(embedding, R_gt)
        code = self.train_code
        if self.training:  # IPDF: the grid turned by a fresh Haar-random rotation every step
            q = torch.randn(4, dtype=torch.float64)
            turn = quat_to_rotmat(q / torch.linalg.vector_norm(q)).to(self.train_rotmat.dtype)
            code = positional_encoding(self.train_rotmat @ turn, self.frequencies)
        on_grid = self.grid_scores(embedding, code)
        logits = torch.cat([at_label[:, None], on_grid], dim=-1)
        return -torch.log_softmax(logits, dim=-1)[:, 0].mean()

    def log_prob(self, raw: dict[str, Tensor], R: Tensor) -> Tensor:
        """(B,) ``f(R) - logsumexp_k f(R_k) + log N`` (normalised Haar measure; uniform = 0)."""
        logits = self._eval_logits(raw)
        at_R = self.score(raw["embedding"], R)
        return at_R - torch.logsumexp(logits, dim=-1) + math.log(logits.shape[-1])

    def log_prob_many(self, raw: dict[str, Tensor], R: Tensor) -> Tensor:
        """``log_prob`` of ``R (B, K, 3, 3)``, K rotations per sample -> ``(B, K)``: the
        evaluation grid's normaliser once per sample, not once per rotation."""
        logits = self._eval_logits(raw)
        code = positional_encoding(R.to(raw["embedding"].dtype), self.frequencies)  # (B, K, D)
        at_R = self._tail(raw["embedding"][:, None] + self.rotation_layer(code))  # (B, K)
        norm = torch.logsumexp(logits, dim=-1) - math.log(logits.shape[-1])
        return at_R - norm[:, None]

    def distribution(self, raw: dict[str, Tensor]) -> Tensor:
        """(B, n_eval) probabilities over the evaluation grid."""
        return super().distribution(self._eval_logits(raw))

    def target_distribution(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> (B, n_eval): ``softmax_k(4 target_kappa (q . q_k)^2)``."""
        q = rotmat_to_quat(R)
        dots = q @ self.eval_quat.to(q.dtype).T
        return torch.softmax(4 * self.target_kappa * dots**2, dim=-1)

    def decode_distribution(self, p: Tensor) -> Tensor:
        """(B, n_eval) -> (B, 3, 3): argmax, refined by the local principal quaternion axis."""
        grid = self.eval_quat.to(p.dtype)
        if p.shape[-1] != grid.shape[0]:
            raise ValueError(
                f"ipdf: a distribution over the {grid.shape[0]}-point evaluation grid is needed, "
                f"got shape {tuple(p.shape)}"
            )
        best = grid[p.argmax(-1)]  # (B, 4)
        spacing = (8 * math.pi**2 / grid.shape[0]) ** (1 / 3)
        # |q . q*| >= cos(angle / 2): within DECODE_RADIUS spacings of the argmax rotation.
        near = (best @ grid.T).abs() >= math.cos(DECODE_RADIUS * spacing / 2)
        weights = torch.where(near, p, torch.zeros_like(p))
        scatter = (weights[..., None] * grid).transpose(-1, -2) @ grid  # (B, 4, 4)
        axis = torch.linalg.eigh(scatter).eigenvectors[..., -1]
        return quat_to_rotmat(axis)

    def decode(self, raw: dict[str, Tensor]) -> Tensor:
        """(B, 3, 3): ``decode_distribution(distribution(raw))``, then ``refine_steps`` Adam steps
        of gradient ascent on the score."""
        R0 = super().decode(raw)  # GridDistribution: decode_distribution(distribution(raw))
        if self.refine_steps == 0:
            return R0
        embedding = raw["embedding"].detach()
        delta = torch.zeros(R0.shape[0], 3, dtype=R0.dtype, requires_grad=True)
        optimizer = torch.optim.Adam([delta], lr=REFINE_LR)
        with torch.enable_grad():
            for _ in range(self.refine_steps):
                optimizer.zero_grad()
                score = self.score(embedding, R0 @ rotvec_to_rotmat(delta))
                (-score.sum()).backward(inputs=[delta])
                optimizer.step()
        return (R0 @ rotvec_to_rotmat(delta)).detach()

    def uncertainty(self, raw: dict[str, Tensor]) -> Tensor:
        """(B,) normalised entropy ``-sum p log p / log N`` in [0, 1]."""
        log_p = torch.log_softmax(self._eval_logits(raw), dim=-1)
        entropy = -(log_p.exp() * log_p).sum(-1)
        return (entropy / math.log(log_p.shape[-1])).clamp(0, 1)
