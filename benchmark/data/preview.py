"""``uavbench preview DATASET``: a contact sheet PNG of UAV/satellite pairs with their poses.

Each pair shows the UAV image and its satellite image; on the satellite image the UAV position
(from the translation label) is a red dot and its camera heading (yaw) a red arrow, so a glance
tells whether labels and imagery agree: the arrow should point at what the UAV image shows.
When the dataset records illumination (pairs columns ``sun_az`` and ``sat_sun_az``, radians
clockwise from north), each image's sun azimuth is printed in degrees: the UAV frame and its
satellite image are lit at independent times of day.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from benchmark.errors import InputError

if TYPE_CHECKING:
    from benchmark.data.dataset import PairDataset


def sat_pixel(
    dE: float, dN: float, footprint: tuple[float, float], size: int
) -> tuple[float, float]:
    """Pixel ``(u, v)`` of a point ``(dE, dN)`` metres from the centre of a north-up satellite
    image covering ``footprint = (E, N)`` metres, resized to ``size x size`` (pixel centres on
    integers, v downwards = south)."""
    u = (dE / footprint[0] + 0.5) * size - 0.5
    v = (0.5 - dN / footprint[1]) * size - 0.5
    return u, v


def sun_azimuth_deg(row: object, column: str) -> float | None:
    """The sun azimuth of ``row[column]`` (radians clockwise from north) in degrees [0, 360), or
    None when the dataset has no such column (or the value is missing)."""
    v = getattr(row, column, None)
    if v is None or not math.isfinite(float(v)):
        return None
    return math.degrees(float(v)) % 360.0


def _sun_text(az_deg: float | None) -> str:
    return "" if az_deg is None else f", sun az {az_deg:.0f} deg"


def contact_sheet(ds: PairDataset, indices: list[int], out: Path, title: str) -> None:
    """Render pairs ``indices`` of PairDataset ``ds`` to ``out`` (PNG), two pairs per row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per_row = 2
    rows = math.ceil(len(indices) / per_row)
    fig, axes = plt.subplots(
        rows, 2 * per_row, figsize=(4 * per_row * 2 * 0.9, 4.3 * rows), squeeze=False
    )
    sats = ds.sat_table.set_index("sat_index")
    for ax in axes.ravel():
        ax.axis("off")
    for slot, i in enumerate(indices):
        r = ds.poses.iloc[i]
        ax_u, ax_s = (
            axes[slot // per_row, 2 * (slot % per_row)],
            axes[slot // per_row, 2 * (slot % per_row) + 1],
        )
        ax_u.imshow(ds.uav_image(i), interpolation="nearest")
        sat = ds.sat_images[int(r.sat_index)]
        ax_s.imshow(sat, interpolation="nearest")
        s = sats.loc[int(r.sat_index)]
        size = sat.shape[0]
        u, v = sat_pixel(r.dE, r.dN, (s.footprint_E_m, s.footprint_N_m), size)
        # camera heading in (E, N): (-sin yaw, cos yaw); the image squashes E and N differently
        dx = -math.sin(r.yaw) / s.footprint_E_m
        dy = -math.cos(r.yaw) / s.footprint_N_m
        norm = math.hypot(dx, dy)
        arrow = 0.12 * size
        ax_s.plot([u], [v], "o", color="red", ms=4)
        ax_s.annotate(
            "",
            xy=(u + arrow * dx / norm, v + arrow * dy / norm),
            xytext=(u, v),
            arrowprops=dict(arrowstyle="->", color="red", lw=1.5),
        )
        ax_s.set_xlim(-0.5, size - 0.5)
        ax_s.set_ylim(size - 0.5, -0.5)
        uav_sun = _sun_text(sun_azimuth_deg(r, "sun_az"))
        sat_sun = _sun_text(sun_azimuth_deg(r, "sat_sun_az"))
        ax_u.set_title(f"#{i} {r.city} c{r.centre} f{r.flight} fr{r.frame}{uav_sun}", fontsize=8)
        ax_s.set_title(
            f"sat {int(r.sat_index)} ({s.variant}, {s.height_m:.0f} m){sat_sun}", fontsize=8
        )
        ax_u.text(
            0.0,
            -0.02,
            f"E {r.E:.0f} N {r.N:.0f} U {r.U:.0f} m\n"
            f"yaw {math.degrees(r.yaw):.1f} pitch {math.degrees(r.pitch):.1f} "
            f"roll {math.degrees(r.roll):.1f} deg\n"
            f"T = [{r.dE:.0f}, {r.dN:.0f}, {r.dU:.0f}] m",
            transform=ax_u.transAxes,
            va="top",
            fontsize=7,
            family="monospace",
        )
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)


def pick_indices(n_items: int, n: int, seed: int) -> list[int]:
    """``n`` distinct items, spread over the split (sorted), deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    return sorted(rng.choice(n_items, size=min(n, n_items), replace=False).tolist())


@dataclass(frozen=True)
class PreviewConfig:
    """A contact sheet of ``n`` pairs of ``split`` of ``dataset`` picked with ``seed``, written
    to ``out`` (None: ``DATASET/preview_<split>.png``)."""

    dataset: Path
    split: str = "standard/train"
    n: int = 8
    out: Path | None = None
    seed: int = 0


@dataclass(frozen=True)
class PreviewResult:
    """The contact sheet written: its PNG ``out``, holding ``n_pairs`` pairs of ``split``."""

    out: Path
    n_pairs: int
    split: str

    def lines(self) -> list[str]:
        """One line: where the sheet was written and what it shows."""
        return [f"wrote {self.out} ({self.n_pairs} pairs of {self.split})"]


def preview(config: PreviewConfig) -> PreviewResult:
    """Write the contact sheet of ``config``; returns where and what (InputError: no such
    split/dataset)."""
    from benchmark.data.dataset import PairDataset, list_splits
    from benchmark.data.format import DatasetError

    try:
        splits = list_splits(config.dataset)
        if config.split not in splits:
            raise InputError(f"unknown split {config.split!r}; {config.dataset} has {splits}")
        ds = PairDataset(config.dataset, config.split, verify="size")
    except DatasetError as err:
        raise InputError(str(err)) from err
    out = config.out or config.dataset / f"preview_{config.split.replace('/', '_')}.png"
    indices = pick_indices(len(ds), config.n, config.seed)
    title = (
        f"{config.dataset.name} [{config.split}] {len(ds)} pairs, "
        f"{ds.manifest['image_size']} px; red: UAV position and heading"
    )
    contact_sheet(ds, indices, out, title)
    return PreviewResult(out, len(indices), config.split)
