"""The matching encoder (issue 21): it reads the heading from the pair by matching a bird's-eye
view of the UAV image against the satellite image at every yaw and position.

After OrienterNet (Sarlin et al., CVPR 2023): neural bird's-eye view, rotated templates,
exhaustive correlation into a score volume over (yaw, N, E), trained by the NLL of the true pose.
Written for this benchmark's geometry (``benchmark.models.matching_geometry``); no code copied.

Pipeline, per pair (``B`` pairs, ``C = out_channels``):

1. Two small CNNs (5 convolutions each, GroupNorm, ReLU): the UAV image -> ``(C, S/2, S/2)``
   (2 x 2 average pooling after the first layer), the satellite image -> ``(C, S/2, S)`` (pooled
   along rows only, since a 2 x 1 km footprint squashed to a square has 2x finer rows).
   With ``grey_gradient``, two fixed channels join each map: the grey level and its gradient
   magnitude, standardised per image, times a learned gain (``matching_pixels.grey_gradient``;
   what the geometry oracle correlates, and what does not depend on a city style's palette).
   With ``photometric > 0``, training images get random colours first (per image, UAV and
   satellite independently; ``matching_pixels.photometric_jitter``): labels stay exact.
2. A gravity branch on the UAV trunk predicts pitch, roll and the height above the ground
   (a hidden layer of ``gravity_dim`` features; they no longer go to the heads).
3. Protocol (option ``protocol``): ``"gravity_aided"`` builds the bird's-eye view from the
   context's sensor priors (IMU pitch/roll, altimeter height; noise in
   ``benchmark.data.dataset.PRIOR_SIGMA``); ``"vision_only"`` (the paper's) from the gravity
   branch's prediction at evaluation, and from the same priors in training (teacher forcing: the
   matcher learns on near-true geometry while the gravity branch learns to predict it).
   ``train_view_noise_deg`` / ``train_view_noise_m`` (off by default) add Gaussian noise to the
   training view's pitch and roll / height, so that the matcher also learns on views as wrong
   as the gravity branch's; evaluation never adds any.
4. Templates: for each of ``n_yaw`` yaws, a disc of radius ``template_m`` of ground cells of
   ``cell_m`` metres, projected into the UAV image and sampled (one bilinear interpolation per
   cell); satellite features resampled to the same north-up metric grid; both L2-normalised per
   cell. The score of (yaw, position) is the template's mean cosine similarity with the grid at
   that position, times a learned temperature; positions within ``search_m`` (square) of the
   image centre and inside its footprint are candidates. ``log_softmax`` over all (yaw, N, E)
   gives the pose volume. With ``height_planes = P > 0`` the view is height-aware: a 1 x 1
   convolution of the UAV trunk gives every pixel a distribution over ``P`` horizontal planes
   (``0, s, .., (P - 1) s`` metres above the ground, ``s = plane_spacing_m``) and "on no plane",
   and each cell collects the features where its column meets each plane, weighted by the
   pixel's probability of that plane (``matching_ops.bev_templates_planes``): roofs land where
   the satellite shows them instead of ``altitude / (altitude - h)`` times farther out.
   With ``altitude_offsets_m = (d_1, .., d_S)`` the volume has a scale dimension: the
   templates are built at ``S`` altitudes ``h + d_s`` around the view's altitude ``h`` and one
   ``log_softmax`` runs over (altitude, yaw, N, E); the heads see the altitude marginal. On
   flat ground the altitude only scales the bird's-eye view about the point below the UAV (a
   ray's ground offset is ``h`` times its direction's slope), so a wrong height shrinks or
   stretches the template against the satellite grid, and the hypotheses let the match pick
   the scale. Searched where the altitude is uncertain: in training (around the prior plus a
   uniform jitter of one spacing, so the true height falls anywhere between hypotheses) and in
   vision-only evaluation (around the gravity branch's height, which at 96 px is barely better
   than the flights' mean); gravity-aided evaluation trusts the altimeter and builds one view.
5. Features for the heads (fixed length, see :attr:`MatchingEncoder.feature_names`): the yaw
   marginal's circular mean (cos, sin), the expected position, its spread and the arg-max
   position (units of ``search_m``), peak log-probability and normalised entropy, the gravity
   values (predicted, and prior or predicted), the estimate of ``dU`` from the height (km) and
   the satellite height (km), the joint arg-max's yaw refined over its neighbouring bins (cos,
   sin), the mass near the yaw and position arg-max, and those estimates times their mass. Not
   the yaw marginal itself nor the gravity branch's features: with them the heads overfit the
   training pairs (measured on standard/val, see ``_summary``).

The encoder's own loss (``loss``): ``volume_nll_weight`` x the NLL of the pose volume at the true
pose (the cross-entropy with the true pose smoothed over neighbouring cells and yaw bins by
Gaussians of ``smoothing`` cells / bins) + ``gravity_weight`` x the gravity branch's robust
(smooth L1) error on pitch, roll (per 2 deg) and height (per 5 m). ``volume_nll_weight=0`` leaves
the matcher to the heads' loss (the paper's protocol of one loss per head). With
``altitude_offsets_m`` the NLL is that of the joint volume at the true pose and height (the
height target a Gaussian of half the hypotheses' smallest spacing, :meth:`volume_nll_altitudes`).
"""

from __future__ import annotations

import inspect
import itertools
import math
import typing
from collections.abc import Callable, Mapping
from typing import Any

import torch
import torch.nn.functional as nnf
from torch import Tensor, nn

from benchmark.geometry import SAT_R_N, rotmat_to_euler
from benchmark.models.encoder import parse_variant
from benchmark.models.matching_ops import (
    bev_templates,
    bev_templates_planes,
    correlate,
    sat_grid,
    unit_channels,
)
from benchmark.models.matching_options import PROTOCOLS, MatchingOptions
from benchmark.models.matching_pixels import (
    denormalize,
    grey_gradient,
    normalize,
    photometric_jitter,
)
from benchmark.models.norm import Float32GroupNorm
from benchmark.models.pair_encoder import PairEncoder, PairEncoding, PoseVolumeAxes
from benchmark.models.registry import register_encoder

__all__ = ["PROTOCOLS", "MatchingEncoder", "MatchingOptions", "matching"]

GRAVITY_SCALE = (math.radians(2.0), math.radians(2.0), 5.0)  # loss units: 2 deg, 2 deg, 5 m
MASKED = -1.0e4  # log-score of excluded positions (finite: 0 * MASKED stays 0 in the loss)
TEMPERATURE_GAIN = 10.0  # learning-rate multiplier of the log-temperature
ALTITUDE_PRIOR_M = 100.0  # the gravity branch's initial height (flights: 80-120 m)


def _trunk(channels: int, out_channels: int, pool: tuple[int, int]) -> nn.ModuleDict:
    def block(cin: int) -> nn.Sequential:
        return nn.Sequential(
            nn.Conv2d(cin, channels, 3, padding=1, bias=False),
            Float32GroupNorm(min(4, channels), channels),
            nn.ReLU(inplace=True),
        )

    return nn.ModuleDict(
        {
            "stem": block(3),
            "pool": nn.AvgPool2d(kernel_size=(pool[1], pool[0]), stride=(pool[1], pool[0])),
            "body": nn.Sequential(block(channels), block(channels), block(channels)),
            "out": nn.Conv2d(channels, out_channels, 1),
        }
    )


def _run_trunk(trunk: nn.ModuleDict, x: Tensor) -> tuple[Tensor, Tensor]:
    hidden = trunk["body"](trunk["pool"](trunk["stem"](x)))
    return hidden, trunk["out"](hidden)


def _context_value(context: Mapping[str, Tensor], key: str, shape: tuple, ref: Tensor) -> Tensor:
    if key not in context:
        raise ValueError(
            f"matching encoder: context has no {key!r} (got {sorted(context)}); pass the items' "
            "'context' dict of benchmark.data.PairDataset"
        )
    value = torch.as_tensor(context[key]).to(device=ref.device, dtype=ref.dtype)
    if value.shape != shape:
        raise ValueError(f"matching encoder: context[{key!r}] must have shape {shape}, got "
                         f"{tuple(value.shape)}")  # fmt: skip
    return value


class MatchingEncoder(PairEncoder):
    """See the module docstring; options are those of :func:`matching`."""

    def __init__(self, input_size: int, options: MatchingOptions | None = None) -> None:
        """``input_size`` (even, >= 16) px of the images; ``options`` by group
        (:class:`~benchmark.models.matching_options.MatchingOptions`, each group checked when
        built; None: every default). The registered factory ``matching`` takes them flat."""
        super().__init__()
        options = MatchingOptions() if options is None else options
        if input_size < 16 or input_size % 2:
            raise ValueError(f"matching encoder: input_size must be even and >= 16, got "
                             f"{input_size}")  # fmt: skip
        self.options = options
        loss, geo, cam, net, aug = (options.loss, options.geometry, options.camera,
                                    options.network, options.augmentation)  # fmt: skip
        protocol, channels, out_channels = loss.protocol, net.channels, net.out_channels
        gravity_dim, temperature = net.gravity_dim, net.temperature
        alt_offsets = geo.altitude_offsets_m
        self.min_input_size = input_size
        self.input_size = input_size
        self.protocol = protocol
        self.volume_nll_weight = float(loss.volume_nll_weight)
        self.gravity_weight = float(loss.gravity_weight)
        self.n_yaw = int(geo.n_yaw)
        self.cell_m = float(geo.cell_m)
        self.search_cells = geo.search_cells
        self.template_cells = geo.template_cells
        self.smoothing = float(loss.smoothing)
        self.correlation = net.correlation
        self.defaults = {
            "fov": math.radians(cam.default_fov_deg),
            "sat_footprint_m": cam.default_footprint_m,
            "sat_height_m": float(cam.default_sat_height_m),
        }
        self.uav_stride, self.sat_stride = (2, 2), (1, 2)
        self.uav_trunk = _trunk(channels, out_channels, self.uav_stride)
        self.sat_trunk = _trunk(channels, out_channels, self.sat_stride)
        self.gravity_conv = nn.Sequential(
            nn.Conv2d(channels, channels, 3, stride=2, padding=1),
            nn.ReLU(inplace=True),
            nn.AdaptiveAvgPool2d(6),
            nn.Flatten(),
            nn.Linear(36 * channels, 64),
            nn.ReLU(inplace=True),
            nn.Linear(64, gravity_dim),
            nn.ReLU(inplace=True),
        )
        self.gravity_out = nn.Linear(gravity_dim, 3)
        nn.init.zeros_(self.gravity_out.weight)
        nn.init.zeros_(self.gravity_out.bias)
        # tau = exp(TEMPERATURE_GAIN * s): Adam moves s by ~lr per step, so without the gain the
        # temperature could change by only ~30 % in an epoch of 300 steps at lr 1e-3.
        self.log_temperature = nn.Parameter(torch.tensor(math.log(temperature) / TEMPERATURE_GAIN))
        yaws = torch.arange(self.n_yaw, dtype=torch.float64) * (2 * math.pi / self.n_yaw)
        self.register_buffer("yaws", yaws.float(), persistent=False)
        n = self.search_cells
        offsets = torch.arange(-n, n + 1, dtype=torch.float32) * self.cell_m
        self.register_buffer("pos_e", offsets.clone(), persistent=False)  # column x -> dE
        self.register_buffer("pos_n", offsets.flip(0).clone(), persistent=False)  # row y -> dN
        self.feature_names = [
            "yaw_cos", "yaw_sin", "E_mean", "N_mean", "E_std", "N_std", "E_argmax", "N_argmax",
            "peak_logp", "entropy", "pitch_pred", "roll_pred", "alt_pred", "pitch_used",
            "roll_used", "alt_used", "dU_est_km", "sat_height_km", "yaw_argmax_cos",
            "yaw_argmax_sin", "yaw_peak_mass", "pos_peak_mass", "yaw_argmax_cos_w",
            "yaw_argmax_sin_w", "E_argmax_w", "N_argmax_w",
        ]  # fmt: skip
        self.feature_dim = len(self.feature_names)
        self.photometric = float(aug.photometric)
        self.grey_gradient = bool(net.grey_gradient)
        if self.grey_gradient:
            # log-gain of the fixed grey and gradient channels against the learned ones (created
            # last, so that the default encoder's parameters and their seeded values stay as they
            # were before the option existed)
            self.grey_gradient_log_gain = nn.Parameter(torch.zeros(2))
        self.height_planes = int(geo.height_planes)
        self.plane_spacing_m = float(geo.plane_spacing_m)
        # The bird's-eye view clamps the altitude here: less than 5 m above the top plane would
        # put the horizon at the image centre and nothing on the ground. A float, not read from
        # the plane_heights buffer, so the forward pass needs no host read.
        self.min_altitude_m = 5.0 + max(self.height_planes - 1, 0) * self.plane_spacing_m
        self.altitude_offsets_m = alt_offsets
        # Extra Gaussian noise on the training view's pitch, roll (rad) and height (m), on top of
        # the sensor priors': vision-only evaluation builds the view from the gravity branch,
        # whose errors are larger than the IMU's and the altimeter's.
        self.train_view_sigma = (
            math.radians(aug.train_view_noise_deg),
            math.radians(aug.train_view_noise_deg),
            float(aug.train_view_noise_m),
        )
        # The training jitter's width and the height target's scale (twice its sigma).
        self.altitude_spacing_m = min(
            (b - a for a, b in itertools.pairwise(alt_offsets)), default=0.0
        )
        self.register_buffer(
            "altitude_offsets", torch.tensor(alt_offsets, dtype=torch.float32), persistent=False
        )
        if self.height_planes:
            heights = torch.arange(self.height_planes, dtype=torch.float32) * self.plane_spacing_m
            self.register_buffer("plane_heights", heights, persistent=False)
            # Per-pixel logits over the planes and "on no plane" (created last, like the gain
            # above). Zero weights and a ground-plane bias: the untrained view is the flat one
            # (q = e^3 / (e^3 + P) ~ 0.77 on the ground for 6 planes), so training starts from
            # the matcher without planes and learns where the city stands up.
            self.plane_logits = nn.Conv2d(channels, self.height_planes + 1, 1)
            nn.init.zeros_(self.plane_logits.weight)
            with torch.no_grad():
                self.plane_logits.bias.zero_()
                self.plane_logits.bias[0] = 3.0

    # --- geometry inputs -------------------------------------------------------------------
    def _geometry(self, context: Mapping[str, Tensor] | None, ref: Tensor) -> dict[str, Tensor]:
        b = ref.shape[0]
        if context is None:
            if self.protocol == "gravity_aided":
                raise ValueError("matching encoder (gravity_aided): no context given; the "
                                 "protocol needs the items' prior_attitude and "
                                 "prior_altitude_m")  # fmt: skip
            d = self.defaults
            return {
                "fov": ref.new_full((b,), d["fov"]),
                "sat_footprint_m": ref.new_tensor(d["sat_footprint_m"]).expand(b, 2),
                "sat_height_m": ref.new_full((b,), d["sat_height_m"]),
            }
        out = {
            "fov": _context_value(context, "fov", (b,), ref),
            "sat_footprint_m": _context_value(context, "sat_footprint_m", (b, 2), ref),
            "sat_height_m": _context_value(context, "sat_height_m", (b,), ref),
        }
        if "prior_attitude" in context or self.protocol == "gravity_aided":
            out["prior_attitude"] = _context_value(context, "prior_attitude", (b, 2), ref)
            out["prior_altitude_m"] = _context_value(context, "prior_altitude_m", (b,), ref)
        return out

    def forward(
        self,
        uav: Tensor,
        sat: Tensor,
        sat_index: Tensor,
        context: Mapping[str, Tensor] | None = None,
    ) -> PairEncoding:
        """``uav (B, 3, S, S)``, ``sat (M, 3, S, S)`` normalised; ``sat_index (B,)`` int64 rows of
        ``sat``; ``context`` as ``PairDataset`` collates it (``None``: the defaults, vision-only
        only). Returns the features ``(B, F)`` and, in ``extras``, ``log_volume (B, K, P, P)``
        (log-probabilities over yaw, row = north first, column = east), ``gravity (B, 3)``
        (predicted pitch, roll rad, height m) and ``sat_height_m (B,)``."""
        if uav.shape[-2:] != (self.input_size, self.input_size) or sat.shape[-2:] != uav.shape[-2:]:
            raise ValueError(f"matching encoder: built for {self.input_size} px images, got uav "
                             f"{tuple(uav.shape)} and sat {tuple(sat.shape)}")  # fmt: skip
        geo = self._geometry(context, uav)
        if self.training and self.photometric > 0:
            uav = normalize(photometric_jitter(denormalize(uav), self.photometric))
            sat = normalize(photometric_jitter(denormalize(sat), self.photometric))
        uav_hidden, uav_feat = _run_trunk(self.uav_trunk, uav)
        _, sat_feat = _run_trunk(self.sat_trunk, sat)
        if self.grey_gradient:
            gain = self.grey_gradient_log_gain.exp()[None, :, None, None]
            uav_feat = torch.cat([uav_feat, grey_gradient(uav, self.uav_stride) * gain], 1)
            sat_feat = torch.cat([sat_feat, grey_gradient(sat, self.sat_stride) * gain], 1)
        sat_feat = sat_feat[sat_index]
        g = self.gravity_conv(uav_hidden)
        raw = self.gravity_out(g)
        predicted = torch.stack(
            [raw[:, 0] * 0.3, raw[:, 1] * 0.3, ALTITUDE_PRIOR_M + 10.0 * raw[:, 2]], dim=1
        )  # pitch, roll rad; height m (scaled so the initial layer sees unit targets)
        use_prior = "prior_attitude" in geo and (self.protocol == "gravity_aided" or self.training)
        if use_prior:
            used = torch.cat([geo["prior_attitude"], geo["prior_altitude_m"][:, None]], dim=1)
        else:
            used = predicted
        if self.training and any(self.train_view_sigma):
            used = used + torch.randn_like(used) * used.new_tensor(self.train_view_sigma)
        joint_extras: dict[str, Tensor] = {}
        if self.altitude_offsets_m and (self.training or self.protocol == "vision_only"):
            centre = used[:, 2].detach()
            if self.training:  # the true height anywhere between two hypotheses, not on one
                centre = centre + (torch.rand_like(centre) - 0.5) * self.altitude_spacing_m
            altitudes = (centre[:, None] + self.altitude_offsets.to(centre)).clamp(
                min=self.min_altitude_m
            )  # (B, S)
            joint = self.match_altitudes(
                uav_feat, sat_feat, used[:, 0], used[:, 1], altitudes, geo["fov"],
                geo["sat_footprint_m"],
            )  # fmt: skip
            log_volume = torch.logsumexp(joint, dim=1)
            joint_extras = {"log_volume_joint": joint, "altitudes": altitudes}
        else:
            logits = self.plane_logits(uav_hidden) if self.height_planes else None
            log_volume = self.match(
                uav_feat, sat_feat, used[:, 0], used[:, 1],
                used[:, 2].clamp(min=self.min_altitude_m), geo["fov"], geo["sat_footprint_m"],
                plane_logits=logits,
            )  # fmt: skip
        # The heads see the values the protocol has at test time: in vision-only training the
        # bird's-eye view uses the priors, but the features carry the prediction twice.
        shown = used if self.protocol == "gravity_aided" else predicted
        feats = self._summary(log_volume, predicted, shown, geo["sat_height_m"])
        extras = {
            "log_volume": log_volume,
            "gravity": predicted,
            "sat_height_m": geo["sat_height_m"],
            **joint_extras,
        }
        return PairEncoding(features=feats, extras=extras)

    def pose_volume_axes(self) -> PoseVolumeAxes:
        """``log_volume``'s axes: ``n_yaw`` yaw bins from 0 (rad), rows north from ``+search``
        down, columns east from ``-search`` up, ``cell_m`` apart (``pos_n``, ``pos_e``)."""
        return PoseVolumeAxes(
            yaw=self.yaws.detach().clone(), north=self.pos_n.detach().clone(),
            east=self.pos_e.detach().clone(), cell_m=self.cell_m,
        )  # fmt: skip

    def match(
        self,
        uav_feat: Tensor,
        sat_feat: Tensor,
        pitch: Tensor,
        roll: Tensor,
        altitude: Tensor,
        fov: Tensor,
        footprint_m: Tensor,
        uav_stride: tuple[int, int] | None = None,
        sat_stride: tuple[int, int] | None = None,
        plane_logits: Tensor | None = None,
    ) -> Tensor:
        """The pose volume ``log p (B, K, P, P)`` (yaw, row = north first, column = east) of
        feature maps ``uav_feat (B, C, h, w)`` and ``sat_feat (B, C, h', w')`` (one satellite map
        per pair; strides default to the trunks'), for the camera ``pitch, roll`` (rad),
        ``altitude`` (m above the ground), ``fov`` (rad), all ``(B,)``, and the satellite
        footprint ``(B, 2)`` metres. Features are L2-normalised per cell here. With
        ``height_planes``, ``plane_logits (B, P + 1, h, w)`` on the UAV features' grid lift them
        onto the planes (``matching_ops.bev_templates_planes``); the score is then the mean
        cosine weighted by each cell's plane probability. On flat ground it is
        :meth:`match_altitudes` with one altitude."""
        if not self.height_planes:
            return self.match_altitudes(
                uav_feat, sat_feat, pitch, roll, altitude[:, None], fov, footprint_m, uav_stride,
                sat_stride,
            )[:, 0]  # fmt: skip
        if plane_logits is None:
            raise ValueError("matching encoder: height_planes is set, so match() needs the "
                             "plane_logits of the UAV features")  # fmt: skip
        templates, mask = bev_templates_planes(
            unit_channels(uav_feat), plane_logits, self.plane_heights,
            uav_stride or self.uav_stride, self.input_size, self.yaws, self.template_cells,
            self.cell_m, pitch, roll, altitude, fov,
        )  # fmt: skip
        grid = self._sat_grid(sat_feat, sat_stride, footprint_m)
        scores = self._scores(templates, mask, grid, footprint_m)
        return torch.log_softmax(scores.flatten(1), dim=1).view_as(scores)

    def match_altitudes(
        self,
        uav_feat: Tensor,
        sat_feat: Tensor,
        pitch: Tensor,
        roll: Tensor,
        altitudes: Tensor,
        fov: Tensor,
        footprint_m: Tensor,
        uav_stride: tuple[int, int] | None = None,
        sat_stride: tuple[int, int] | None = None,
    ) -> Tensor:
        """The joint volume ``log p (B, S, K, P, P)`` over (altitude, yaw, north, east) for the
        altitude hypotheses ``altitudes (B, S)`` metres above the ground; other arguments as
        :meth:`match` (flat ground; :meth:`match` is this with ``S = 1``). One ``log_softmax``
        over all ``S K P P`` cells, so the hypotheses compete: ``logsumexp`` over ``S`` is the
        pose volume, the sum over ``(K, P, P)`` of ``exp`` the altitude's posterior. The
        satellite grid is resampled once; each altitude's bank of ``K`` templates is correlated
        on its own (one correlation of all ``S K`` templates made a training step 1.3x slower on
        this CPU: its spectra no longer fit the cache)."""
        size, r = self.input_size, self.template_cells
        stride = uav_stride or self.uav_stride
        feats = unit_channels(uav_feat)
        grid = self._sat_grid(sat_feat, sat_stride, footprint_m)
        banks = []
        for altitude in altitudes.unbind(1):
            templates, mask = bev_templates(
                feats, stride, size, self.yaws, r, self.cell_m, pitch, roll, altitude, fov
            )
            banks.append(self._scores(templates, mask, grid, footprint_m))
        scores = torch.stack(banks, dim=1)  # (B, S, K, P, P)
        return torch.log_softmax(scores.flatten(1), dim=1).view_as(scores)

    def _sat_grid(
        self, sat_feat: Tensor, sat_stride: tuple[int, int] | None, footprint_m: Tensor
    ) -> Tensor:
        """The satellite features on the north-up metric grid, L2-normalised per cell,
        ``(B, C, G, G)``."""
        n, r = self.search_cells, self.template_cells
        grid = sat_grid(sat_feat, sat_stride or self.sat_stride, self.input_size, footprint_m,
                        n + r, self.cell_m)  # fmt: skip
        return unit_channels(grid)

    def _scores(self, templates: Tensor, mask: Tensor, grid: Tensor, footprint_m: Tensor) -> Tensor:
        """Masked scores ``(B, K, P, P)`` of ``templates (B, K, C, t, t)`` with their valid
        cells ``mask (B, K, t, t)`` against the satellite ``grid (B, C, G, G)``: each template's
        mean cosine over its valid cells times the temperature; positions off the footprint get
        ``MASKED``."""
        corr = correlate(grid, templates, self.correlation)  # (B, K, P, P)
        # valid cells per template (their total plane probability with height planes)
        count = mask.flatten(2).sum(-1).clamp(min=1).to(corr.dtype)
        scores = corr / count[..., None, None] * (TEMPERATURE_GAIN * self.log_temperature).exp()
        half = 0.5 * footprint_m
        inside = (self.pos_n.abs()[None, :, None] <= half[:, 1, None, None]) & (
            self.pos_e.abs()[None, None, :] <= half[:, 0, None, None]
        )  # (B, P, P)
        return torch.where(inside[:, None], scores, scores.new_tensor(MASKED))

    def _summary(
        self, log_volume: Tensor, predicted: Tensor, used: Tensor, sat_height: Tensor
    ) -> Tensor:
        p = log_volume.exp()
        yaw_p = p.sum(dim=(2, 3))  # (B, K)
        pos_p = p.sum(dim=1)  # (B, P, P)
        scale = self.search_cells * self.cell_m
        pe = pos_p.sum(1)  # (B, P) over columns (east)
        pn = pos_p.sum(2)  # (B, P) over rows (north)
        e_mean = (pe * self.pos_e).sum(1)
        n_mean = (pn * self.pos_n).sum(1)
        e_std = ((pe * (self.pos_e - e_mean[:, None]).square()).sum(1) + 1e-6).sqrt()
        n_std = ((pn * (self.pos_n - n_mean[:, None]).square()).sum(1) + 1e-6).sqrt()
        flat = pos_p.flatten(1).argmax(1)
        width = pos_p.shape[-1]
        e_arg, n_arg = self.pos_e[flat % width], self.pos_n[flat // width]
        peak, joint = log_volume.flatten(1).max(1)
        entropy = -(p * log_volume).flatten(1).sum(1) / math.log(log_volume[0].numel())
        # The matcher's own estimate, in a form one linear layer can copy: the yaw marginal's
        # circular mean (above) is pulled between modes and the marginal itself needs an arg-max
        # the heads' MLP cannot do, so add the joint arg-max's yaw bin refined by the marginal's
        # weighted mean over it and its two neighbours (sub-bin; the bins are 10 deg wide), as
        # (cos, sin), and how much mass sits there (the heads' cue to trust it). Same for the
        # position: the position marginal's mass in the 3 x 3 cells around the arg-max.
        k_arg = joint // (width * width)  # (B,) yaw bin of the joint arg-max
        offs = torch.arange(-1, 2, device=k_arg.device)
        nb = yaw_p.gather(1, torch.remainder(k_arg[:, None] + offs, self.n_yaw))  # (B, 3)
        nb_mass = nb.sum(1)
        bin_w = 2 * math.pi / self.n_yaw
        yaw_ref = self.yaws[k_arg] + bin_w * (nb * offs.to(nb.dtype)).sum(1) / nb_mass.clamp_min(
            1e-12
        )
        r_arg, c_arg = flat // width, flat % width
        padded = nnf.pad(pos_p, (1, 1, 1, 1))  # zero border: a 3 x 3 block never wraps
        rows = (r_arg[:, None] + 1 + offs)[:, :, None].expand(-1, -1, width + 2)
        block = padded.gather(1, rows)  # (B, 3, P + 2)
        block = block.gather(2, (c_arg[:, None] + 1 + offs)[:, None, :].expand(-1, 3, -1))
        pos_mass = block.flatten(1).sum(1)  # (B,)
        # Not the yaw marginal itself nor the gravity branch's features: with them the heads fit
        # the training pairs (on frozen features of a trained matcher, fresh heads reach 4 deg
        # median yaw on standard/train but 12 deg on standard/val; without them 8.5 deg on val).
        cols = [
            (yaw_p * self.yaws.cos()).sum(1, keepdim=True),
            (yaw_p * self.yaws.sin()).sum(1, keepdim=True),
            torch.stack([e_mean, n_mean, e_std, n_std, e_arg, n_arg], 1) / scale,
            torch.stack([peak / 10.0, entropy], 1),
            predicted * predicted.new_tensor([1.0, 1.0, 0.01]),
            used * used.new_tensor([1.0, 1.0, 0.01]),
            torch.stack([(used[:, 2] - sat_height) / 1000.0, sat_height / 1000.0], 1),
            torch.stack([yaw_ref.cos(), yaw_ref.sin(), nb_mass, pos_mass], 1),
            # The same estimates times their mass: under the heads' squared-error loss the best
            # output is E[pose | features] ~ mass * estimate + (1 - mass) * prior mean when the
            # mass is near the chance that the estimate is right; a product the MLP would have to
            # learn is handed to it as one linear input.
            torch.stack([yaw_ref.cos(), yaw_ref.sin()], 1) * nb_mass[:, None],
            torch.stack([e_arg, n_arg], 1) / scale * pos_mass[:, None],
        ]
        return torch.cat(cols, dim=1)

    # --- the encoder's own loss -------------------------------------------------------------
    @staticmethod
    def true_pose(R_gt: Tensor, T_gt: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``(yaw, pitch, roll)`` rad of the UAV from ``R_uav^sat (B, 3, 3)`` (``R_uav^n =
        R_uav^sat R_sat^n``, Eq. 2) and ``T (B, 3)`` metres (returned as given)."""
        R_uav_n = R_gt @ SAT_R_N.to(R_gt)
        yaw, pitch, roll = rotmat_to_euler(R_uav_n)
        return yaw, pitch, roll, T_gt

    def volume_nll(self, log_volume: Tensor, yaw: Tensor, east: Tensor, north: Tensor) -> Tensor:
        """``(B,)`` NLL of the pose ``(yaw rad, east m, north m)`` (UAV minus the satellite
        image's centre) under ``log_volume (B, K, P, P)``: the cross-entropy with the pose
        smoothed by Gaussians of ``smoothing`` bins in yaw (wrapped) and ``smoothing`` cells in
        E and N (normalised in log space, so a pose beyond the searched square puts its mass on
        the nearest candidates). Cells with ``log p <= MASKED / 2`` are the ones :meth:`match`
        excluded (off the footprint) and get no target mass."""
        log_t = self._log_pose_target(yaw, east, north)
        return self._cross_entropy(log_t, log_volume)

    def volume_nll_altitudes(
        self,
        log_joint: Tensor,
        altitudes: Tensor,
        yaw: Tensor,
        east: Tensor,
        north: Tensor,
        height: Tensor,
    ) -> Tensor:
        """``(B,)`` NLL of the pose and the height ``height (B,)`` m above the ground under the
        joint volume ``log_joint (B, S, K, P, P)`` of :meth:`match_altitudes` at ``altitudes
        (B, S)``: :meth:`volume_nll`'s smoothed pose target times a Gaussian over the hypotheses
        of sigma half their smallest spacing (a height midway between two hypotheses splits its
        mass between them), normalised over all cells together."""
        sigma = 0.5 * (self.altitude_spacing_m or 10.0)
        log_a = -0.5 * ((altitudes - height[:, None]) / sigma).square()  # (B, S)
        log_t = self._log_pose_target(yaw, east, north)[:, None] + log_a[:, :, None, None, None]
        return self._cross_entropy(log_t, log_joint)

    def _log_pose_target(self, yaw: Tensor, east: Tensor, north: Tensor) -> Tensor:
        """Unnormalised log target ``(B, K, P, P)``: Gaussians of ``smoothing`` bins in yaw
        (wrapped) and ``smoothing`` cells in E and N around the pose."""
        bin_w = 2 * math.pi / self.n_yaw
        dyaw = torch.remainder(self.yaws[None] - yaw[:, None] + math.pi, 2 * math.pi) - math.pi
        sy = self.smoothing * bin_w
        sp = self.smoothing * self.cell_m
        return (
            (-0.5 * (dyaw / sy).square())[:, :, None, None]
            + (-0.5 * ((self.pos_n[None] - north[:, None]) / sp).square())[:, None, :, None]
            + (-0.5 * ((self.pos_e[None] - east[:, None]) / sp).square())[:, None, None, :]
        )

    @staticmethod
    def _cross_entropy(log_target: Tensor, log_volume: Tensor) -> Tensor:
        """``(B,)`` cross-entropy of the target ``softmax(log_target)`` with ``log_volume`` (same
        shape, ``(B, ...)``); cells the match excluded (``log p <= MASKED / 2``) get no mass."""
        log_t = log_target + (log_volume <= MASKED / 2).to(log_target.dtype) * MASKED
        target = torch.softmax(log_t.flatten(1), dim=1)
        return -(target * log_volume.flatten(1)).sum(1)

    def loss(self, extras: Mapping[str, Tensor], R_gt: Tensor, T_gt: Tensor) -> dict[str, Tensor]:
        """``enc = volume_nll_weight * enc_volume + gravity_weight * enc_gravity`` (batch means):
        ``enc_volume`` the NLL of the true pose (:meth:`volume_nll`; of the true pose and height
        when ``extras`` holds the altitude search's joint volume, :meth:`volume_nll_altitudes`),
        ``enc_gravity`` the smooth-L1 error of the predicted pitch, roll (per 2 deg) and height
        (per 5 m; height = ``dU + sat_height_m``). Both are always reported; a weight of 0 takes
        a term out of the gradient."""
        lv = extras["log_volume"]
        yaw, pitch, roll, T = self.true_pose(R_gt.to(lv.dtype), T_gt.to(lv.dtype))
        height = T[:, 2] + extras["sat_height_m"]
        if "log_volume_joint" in extras:  # the altitude search: the joint NLL, pose and height
            nll = self.volume_nll_altitudes(
                extras["log_volume_joint"], extras["altitudes"], yaw, T[:, 0], T[:, 1], height
            ).mean()
        else:
            nll = self.volume_nll(lv, yaw, T[:, 0], T[:, 1]).mean()
        truth = torch.stack([pitch, roll, height], 1)
        scale = truth.new_tensor(GRAVITY_SCALE)
        grav = nnf.smooth_l1_loss(extras["gravity"] / scale, truth / scale, reduction="none")
        grav = grav.sum(1).mean()
        enc = self.volume_nll_weight * nll + self.gravity_weight * grav
        return {"enc": enc, "enc_volume": nll, "enc_gravity": grav}

    def decode_volume(self, log_volume: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The volume's arg-max ``(yaw rad, east m, north m)``, each ``(B,)``."""
        p = log_volume.shape[-1]
        flat = log_volume.flatten(1).argmax(1)
        return self.yaws[flat // (p * p)], self.pos_e[flat % p], self.pos_n[(flat // p) % p]


# Arguments every encoder factory takes (``build_model`` passes them; not options).
_FACTORY_ARGS = ("variant", "width", "input_size")


def _published_options(factory: Callable[..., Any]) -> Callable[..., Any]:
    """Publish :class:`MatchingOptions`' flat options (names, defaults, annotations) as the
    signature of a factory written with ``**options``, so that they are declared once, in the
    option groups. ``ModelConfig`` reads options from the factory's signature
    (``model_config.option_parameters``: unknown names refused, values typed by annotation), and
    ``inspect.signature`` honours ``__signature__``."""
    own = inspect.signature(factory)
    fixed = [p for n, p in own.parameters.items() if n in _FACTORY_ARGS]
    options = MatchingOptions.parameters()
    factory.__signature__ = own.replace(parameters=[*fixed, *options])  # type: ignore[attr-defined]
    factory.__annotations__ = {
        **{p.name: p.annotation for p in options},
        **{n: v for n, v in typing.get_type_hints(factory).items() if n != "options"},
    }
    return factory


@register_encoder("matching")
@_published_options
def matching(
    variant: str = "/", width: float = 1.0, input_size: int = 96, **options: Any
) -> MatchingEncoder:
    """The matching encoder (module docstring). ``variant`` must be ``"/"``: the encoder has one
    level (no SE branches, no auxiliary fusion levels). ``width`` is accepted and ignored: the
    profiles' GoogLeNet width multiplier does not apply; ``channels`` / ``out_channels`` size
    the CNNs. ``options``: the flat names of :class:`MatchingOptions`' groups, with their
    defaults (the factory's published signature lists them): the protocol and loss
    (:class:`MatchingLoss`), the bird's-eye view and volume (:class:`MatchingGeometry`), the
    geometry assumed without a context (:class:`MatchingCamera`), the networks and the
    correlation (:class:`MatchingNetwork`) and the training augmentation
    (:class:`MatchingAugmentation`)."""
    spec = parse_variant(variant)
    if spec.fusion or spec.attention:
        raise ValueError(
            f"matching encoder: variant {variant!r} is a GoogLeNet variant (SE / fusion levels); "
            "the matching encoder has one level: set variant to '/'"
        )
    return MatchingEncoder(input_size, MatchingOptions.from_flat(options))
