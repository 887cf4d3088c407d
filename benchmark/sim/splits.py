"""The dataset plan: which UAV samples and satellite images exist and which pairs form each split.

Split definitions (paper Sec. 3.1, 3.3.2, 3.5; decisions where the paper is silent marked *):

- ``standard/{train,val,test}``: oxford + cambridge. Whole flights are assigned to one split*
  (val like test: its own flights around the same centres), so consecutive, near-identical video
  frames never straddle splits. A val/test flight is also redrawn if any of its samples is
  near-identical to any training sample (< ``LEAK_DIST_M`` apart with heading and pitch both within
  ``LEAK_ANGLE_DEG``)*.
- ``generalized/{train,val}`` are ``standard/{train,val}``; ``generalized/test`` is london.
- ``flight/pitch{0,-10,-50}``: industrial, pitch fixed, 70-90 m; the satellite image is rendered
  from ``changed_city`` (the same place at an earlier time) over a 2.5 km x 1.2 km footprint, and
  the UAV images get camera noise and blur (``camera_effects``). Test-only*: models are trained on
  ``standard/train``.
- ``height{h}/{train,test}`` (paper Fig. 5, one model per height*): whole-flight subsets of
  ``standard/train`` and ``standard/test`` paired with a satellite image shot from ``h`` metres
  above the centre's ground; the footprint grows with ``h`` (same camera, 2 km x 1 km at 1000 m).
  The UAV images are shared with the standard split, only the satellite image and dU change.
- ``pitch{hi}to{lo}/test`` (paper Fig. 6, view difference*): fresh oxford + cambridge test flights
  with pitch drawn inside one bin, e.g. ``pitch-10to-20`` = pitch in [-20, -10] deg; evaluated with
  a model trained on ``standard/train``; leak-checked against the training frames like the test set.
- ``frames/{train,val,test}`` (leakage audit, beyond the paper*): the frames of all standard
  flights re-split at random, as a naive split of video frames would (the paper does not say how it
  split its 30 fps videos); same sizes as ``standard/*``, so neighbouring frames of one flight land
  in train and test.
- ``towns/{train,val,test,london}`` (beyond the paper*): many small towns (``benchmark.sim.towns``),
  each with one centre; train, val and test towns are distinct towns of the training styles,
  london towns of the held-out style. Nothing of a test town is seen in training.
- ``confirm/{standard,towns,generalized}`` (issue 38, beyond the paper*): the confirmation draw
  ``d = profile.confirm_draw``, a second set of test flights nobody chooses anything on: new
  oxford + cambridge flights leak-checked like standard/test, new towns of the training styles
  (``town-confirm<d>-*``), new london flights; as large as standard/test, towns/test and
  generalized/test. Seed groups ``100 d + (0, 1, 2)``, so every draw has streams of its own. The
  groups come after every other group, so the other splits are the same with or without them.
- ``long/{standard,towns,london}`` (issue 39, beyond the paper*): test-only flights long enough
  for flight-fusion curves, ``profile.n_long_flights`` flights of ``long_samples_per_flight``
  samples every ``long_frame_stride`` video frames (quick: 32 samples every 2 s, 62 s): new
  oxford + cambridge flights around the standard centres, leak-checked like standard/test; flights
  over the towns/test towns (``long/towns`` exists when towns/test does); london flights. Seed
  groups ``LONG_GROUPS`` (90, 91, 92, not 100 d + k: those are the confirmation draws'), planned
  after every other group and paired last, so every other split keeps its flight numbers,
  illumination and satellite indices with or without them.

Every UAV sample carries the odometry since the previous sample of its flight (columns
``ODOMETRY_COLUMNS``: ``odo_dyaw`` rad, ``odo_dx odo_dy odo_dz`` m in the levelled heading frame
of the previous sample; NaN on a flight's first sample), measured with the profile's noise
figures (``benchmark.sim.odometry``); the pairs carry their UAV sample's.

Every flight has its own capture time (illumination state and fog) and every satellite image its
own, independent one (``benchmark.sim.illumination``).

Every seed is derived from the dataset seed with ``numpy.random.SeedSequence`` spawn keys, so the
plan is identical on every machine and any sample can be rendered alone (world and render seeds:
``benchmark.sim.seeds``).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from benchmark.geometry import SAT_R_N
from benchmark.sim import detmath
from benchmark.sim.camera import euler_to_rotmat_np
from benchmark.sim.flights import FlightSpec, generate_flight
from benchmark.sim.illumination import assign_illumination
from benchmark.sim.odometry import ODOMETRY_COLUMNS, odometry_noise, plan_odometry
from benchmark.sim.render import satellite_pose
from benchmark.sim.towns import TOWN_ROLES, Town, town_list

LEAK_DIST_M = 10.0
LEAK_ANGLE_DEG = 10.0
FRAME_SPLIT_STREAM = 0x46
SAT_ATTITUDE = (0.0, -math.pi / 2.0, 0.0)  # yaw, pitch, roll of the satellite camera (Eq. 5)

# The confirmation splits, in the order of the test splits they repeat (CONFIRMS).
CONFIRM_SPLITS = ("confirm/standard", "confirm/towns", "confirm/generalized")
CONFIRMS = dict(
    zip(("standard/test", "towns/test", "generalized/test"), CONFIRM_SPLITS, strict=True)
)
# The long test flights (issue 39): one split per family of test flights, in this order.
LONG_SPLITS = ("long/standard", "long/towns", "long/london")
# Their seed groups. Not 200-202: the confirmation draw d uses 100 d + (0, 1, 2), so draw 2 would
# fly the very curves of the long flights (flight_rng draws the same shape for any length).
LONG_GROUPS = (90, 91, 92)
R_COLUMNS = [f"R{i}{j}" for i in range(3) for j in range(3)]  # row-major R_uav^sat
POSE_COLUMNS = ["E", "N", "U", "yaw", "pitch", "roll"]


@dataclass(frozen=True)
class Group:
    """One family of flights rendered as UAV samples."""

    name: str  # e.g. "standard/test"
    gid: int  # seed group id, stable across versions
    styles: tuple[str, ...]
    n: int
    spec: FlightSpec
    camera_effects: bool = False
    leak_check: bool = False  # keep away from the standard/train samples


@dataclass
class Plan:
    """UAV samples, satellite images and pairs (pandas tables, one row each)."""

    uav: pd.DataFrame
    sat: pd.DataFrame
    pairs: pd.DataFrame
    splits: list[str] = field(default_factory=list)


def _groups(
    p: Any, styles_train: tuple[str, ...], london: str, industrial: str, towns: list[Town]
) -> list[Group]:
    def spec(held_out: bool = False, **kw: Any) -> FlightSpec:
        # held-out groups: more, shorter flights at the same number of pairs (Profile docs)
        samples = (p.eval_samples_per_flight if held_out else None) or p.samples_per_flight
        return FlightSpec(samples=samples, frame_stride=p.frame_stride, **kw)

    n_train = round(p.n_standard * p.standard_fractions[0])
    n_val = round(p.n_standard * p.standard_fractions[1])
    n_test = p.n_standard - n_train - n_val
    out = [
        Group("standard/train", 1, styles_train, n_train, spec()),
        Group("standard/val", 2, styles_train, n_val, spec(held_out=True), leak_check=True),
        Group("standard/test", 3, styles_train, n_test, spec(held_out=True), leak_check=True),
        Group("generalized/test", 4, (london,), p.n_generalized_test, spec(held_out=True)),
    ]
    for i, pitch in enumerate(p.flight_pitches_deg):
        out.append(
            Group(
                f"flight/pitch{pitch:g}",
                10 + i,
                (industrial,),
                p.n_flight_per_pitch,
                spec(pitch_deg=(pitch, pitch), altitude_m=tuple(p.flight_altitude_m)),
                camera_effects=True,
            )
        )
    edges = p.pitch_bin_edges_deg
    for b, (hi, lo) in enumerate(itertools.pairwise(edges)):
        out.append(
            Group(
                f"pitch{hi:g}to{lo:g}/test",
                30 + b,
                styles_train,
                p.n_pitch_per_bin,
                spec(held_out=True, pitch_deg=(lo, hi)),
                leak_check=True,
            )
        )
    for r, (role, n) in enumerate(zip(TOWN_ROLES, p.n_town_pairs, strict=True)):
        names = tuple(t.name for t in towns if t.role == role)
        out.append(Group(f"towns/{role}", 50 + r, names, n, spec(held_out=role != "train")))
    draw = int(getattr(p, "confirm_draw", 0))
    if draw:
        confirm_towns = tuple(t.name for t in towns if t.role == f"confirm{draw}")
        n_towns_test = p.n_town_pairs[TOWN_ROLES.index("test")]
        out += [
            Group(CONFIRM_SPLITS[0], 100 * draw, styles_train, n_test, spec(held_out=True),
                  leak_check=True),
            Group(CONFIRM_SPLITS[1], 100 * draw + 1, confirm_towns, n_towns_test,
                  spec(held_out=True)),
            Group(CONFIRM_SPLITS[2], 100 * draw + 2, (london,), p.n_generalized_test,
                  spec(held_out=True)),
        ]  # fmt: skip
    n_long = int(getattr(p, "n_long_flights", 0))
    if n_long:
        long_spec = FlightSpec(samples=p.long_samples_per_flight, frame_stride=p.long_frame_stride)
        n = n_long * long_spec.samples
        test_towns = tuple(t.name for t in towns if t.role == "test")
        families = (styles_train, test_towns, (london,))
        for name, gid, family in zip(LONG_SPLITS, LONG_GROUPS, families, strict=True):
            if family:  # no towns/test towns: no long/towns
                out.append(
                    Group(name, gid, family, n, long_spec, leak_check=name == LONG_SPLITS[0])
                )
    return [g for g in out if g.n > 0]


class _LeakIndex:
    """Nearest-neighbour test "is this pose near-identical to a training pose?" per city."""

    def __init__(self) -> None:
        self._rows: dict[str, list[np.ndarray]] = {}
        self._trees: dict[str, tuple[cKDTree, np.ndarray]] = {}

    def add(self, style: str, d: dict[str, np.ndarray]) -> None:
        self._rows.setdefault(style, []).append(np.stack([d[k] for k in POSE_COLUMNS], axis=1))
        self._trees.pop(style, None)

    def leaks(self, style: str, d: dict[str, np.ndarray]) -> bool:
        if style not in self._rows:
            return False
        if style not in self._trees:
            rows = np.concatenate(self._rows[style])
            self._trees[style] = (cKDTree(rows[:, :3]), rows)
        tree, rows = self._trees[style]
        tol = math.radians(LEAK_ANGLE_DEG)
        pts = np.stack([d["E"], d["N"], d["U"]], axis=1)
        for i, near in enumerate(tree.query_ball_point(pts, LEAK_DIST_M)):
            if not near:
                continue
            dyaw = rows[near, 3] - d["yaw"][i]
            dyaw = np.abs(detmath.arctan2(detmath.sin(dyaw), detmath.cos(dyaw)))  # wrapped
            dpitch = np.abs(rows[near, 4] - d["pitch"][i])
            if np.any((dyaw < tol) & (dpitch < tol)):
                return True
        return False


def _flights_for_group(
    g: Group, cities: dict[str, Any], seed: int, leak: _LeakIndex, first_flight: int
) -> list[dict[str, Any]]:
    """Flights of a group, round-robin over (style, centre) slots; the last one truncated."""
    slots = [(s, c) for s in g.styles for c in range(len(cities[s].flight_centres))]
    n_flights = math.ceil(g.n / g.spec.samples)
    rows = []
    for k in range(n_flights):
        style, centre = slots[k % len(slots)]
        city = cities[style]

        def accept(d: dict[str, np.ndarray], style: str = style) -> bool:
            return not (g.leak_check and leak.leaks(style, d))

        f = generate_flight(
            city, tuple(city.flight_centres[centre]), g.spec, seed=seed, group=g.gid, flight=k,
            accept=accept,
        )  # fmt: skip
        take = min(g.spec.samples, g.n - k * g.spec.samples)
        d = {key: getattr(f, key)[:take] for key in (*POSE_COLUMNS, "frame", "time_s")}
        if g.name == "standard/train":
            leak.add(style, d)
        rows.append(dict(style=style, centre=centre, flight=first_flight + k, data=d, take=take))
    return rows


def sat_position(city: Any, centre: np.ndarray, height_m: float) -> tuple[float, float, float]:
    """Satellite capture point: ``height_m`` above the ground at the flight centre (paper 3.1),
    exactly where ``benchmark.sim.render_satellite`` puts its camera."""
    pos, attitude = satellite_pose(city, np.asarray(centre, np.float64), height_m=float(height_m))
    if not np.allclose(attitude, SAT_ATTITUDE):
        raise RuntimeError(f"satellite_pose attitude {attitude} differs from Eq. 5 {SAT_ATTITUDE}")
    return float(pos[0]), float(pos[1]), float(pos[2])


def relative_labels(uav: pd.DataFrame, sat: pd.DataFrame) -> pd.DataFrame:
    """R_uav^sat (Eq. 2) and T = UAV - satellite position (metres ENU) for aligned rows.

    ``uav`` and ``sat`` have the columns ``E, N, U, yaw, pitch, roll`` (radians), one row per
    pair; float64. ``R_uav^n`` is ``euler_to_rotmat_np``, bit for bit the rotation the renderer
    used for the UAV image, and ``R_sat^n`` the exact ``SAT_R_N`` of Eq. 5 (every satellite image
    of the plan has that attitude, checked in ``sat_position``). The rotation and the product go
    through ``detmath``, so the labels are the same on every CPU (torch's sin/cos and matmul
    kernels, used here before, depend on the ATen CPU capability). ``sat`` is used for positions.
    """
    R_uav = euler_to_rotmat_np(*(uav[k].to_numpy(np.float64) for k in ("yaw", "pitch", "roll")))
    R = detmath.matmul(R_uav, SAT_R_N.numpy().T).reshape(-1, 9)
    out = pd.DataFrame(R, columns=R_COLUMNS, index=uav.index)
    for k, c in zip(("dE", "dN", "dU"), ("E", "N", "U"), strict=True):
        out[k] = uav[c].to_numpy(np.float64) - sat[c].to_numpy(np.float64)
    return out


def _add_frame_split(by_group: dict[str, pd.DataFrame], seed: int, add: Any) -> None:
    """``frames/{train,val,test}``: the standard frames re-split at random (naive frame split)."""
    parts = ("train", "val", "test")
    rows = pd.concat([by_group[f"standard/{s}"] for s in parts])
    order = np.random.default_rng(
        np.random.SeedSequence(int(seed), spawn_key=(FRAME_SPLIT_STREAM,))
    ).permutation(len(rows))
    cuts = np.cumsum([len(by_group[f"standard/{s}"]) for s in parts])[:-1]
    for part, idx in zip(parts, np.split(order, cuts), strict=True):
        add(f"frames/{part}", rows.iloc[np.sort(idx)])


def make_plan(
    p: Any,
    cities: dict[tuple[str, str], Any],
    seed: int,
    *,
    train_styles: tuple[str, ...] = ("oxford", "cambridge"),
    generalized_style: str = "london",
    flight_style: str = "industrial",
) -> Plan:
    """Build the plan of profile ``p`` (``benchmark.data.profiles.Profile``) over ``cities``.

    ``cities`` maps ``(name, variant)`` -> City: ``(style, "now")`` for the four paper cities,
    ``(flight_style, "earlier")`` for the flight test's satellite images and ``(town.name, "now")``
    for every town of ``town_list(p.n_towns, seed)``. Deterministic in (p, cities, seed).
    """
    towns = town_list(
        tuple(p.n_towns),
        seed,
        train_styles=train_styles,
        london_style=generalized_style,
        confirm_draw=int(getattr(p, "confirm_draw", 0)),
    )
    style_of = {t.name: t.style for t in towns}
    now = {name: c for (name, variant), c in cities.items() if variant == "now"}
    groups = _groups(p, train_styles, generalized_style, flight_style, towns)
    leak = _LeakIndex()
    uav_rows: list[dict[str, Any]] = []
    flight_id = 0
    flights_of: dict[str, list[int]] = {}
    for g in groups:
        flights = _flights_for_group(g, now, seed, leak, flight_id)
        flight_id += len(flights)
        flights_of[g.name] = [f["flight"] for f in flights]
        for f in flights:
            d = f["data"]
            for i in range(f["take"]):
                uav_rows.append(
                    dict(
                        group=g.name, city=f["style"], style=style_of.get(f["style"], f["style"]),
                        centre=f["centre"], flight=f["flight"],
                        frame=int(d["frame"][i]), time_s=float(d["time_s"][i]),
                        **{k: float(d[k][i]) for k in POSE_COLUMNS},
                        camera_effects=g.camera_effects,
                    )
                )  # fmt: skip
    uav = pd.DataFrame(uav_rows)
    uav.insert(0, "uav_index", np.arange(len(uav), dtype=np.int64))
    # Odometry from the planned poses, one generator per flight (benchmark.sim.odometry): it
    # depends on the flight's own poses and number only, never on rendering or other flights.
    odometry = plan_odometry(uav.flight, uav.frame, uav, odometry_noise(p), seed)
    for k, col in enumerate(ODOMETRY_COLUMNS):
        uav[col] = odometry[:, k]

    # Satellite images, one per (city, variant, centre, height, footprint).
    sat_rows: list[dict[str, Any]] = []
    sat_key: dict[tuple, int] = {}

    def sat_index(style: str, variant: str, centre: int, height: float, fp: tuple) -> int:
        key = (style, variant, centre, float(height), tuple(float(x) for x in fp))
        if key not in sat_key:
            sat_key[key] = len(sat_rows)
            E, N, U = sat_position(now[style], now[style].flight_centres[centre], height)
            yaw, pitch, roll = SAT_ATTITUDE
            sat_rows.append(
                dict(
                    sat_index=len(sat_rows), city=style, style=style_of.get(style, style),
                    variant=variant, centre=centre,
                    height_m=float(height), footprint_E_m=float(fp[0]), footprint_N_m=float(fp[1]),
                    E=E, N=N, U=U, yaw=yaw, pitch=pitch, roll=roll,
                )
            )  # fmt: skip
        return sat_key[key]

    def footprint(height: float) -> tuple[float, float]:
        s = height / p.sat_height_m
        return (p.sat_footprint_m[0] * s, p.sat_footprint_m[1] * s)

    pair_parts: list[pd.DataFrame] = []

    def add_pairs(split: str, rows: pd.DataFrame, variant: str, height: float, fp: tuple) -> None:
        keys = zip(rows.city, rows.centre, strict=True)
        sat_idx = np.asarray([sat_index(c, variant, int(k), height, fp) for c, k in keys], np.int64)
        pair_parts.append(
            pd.DataFrame(
                {"split": split, "uav_index": rows.uav_index.to_numpy(), "sat_index": sat_idx}
            )
        )

    by_group = {name: uav[uav.group == name] for name in uav.group.unique()}
    h0, fp0 = p.sat_height_m, tuple(p.sat_footprint_m)
    for name in ("standard/train", "standard/val", "standard/test"):
        add_pairs(name, by_group[name], "now", h0, fp0)
    for name in ("train", "val"):
        add_pairs(f"generalized/{name}", by_group[f"standard/{name}"], "now", h0, fp0)
    if "generalized/test" in by_group:
        add_pairs("generalized/test", by_group["generalized/test"], "now", h0, fp0)
    for g in groups:
        if g.name.startswith("flight/"):
            add_pairs(g.name, by_group[g.name], "earlier", h0, tuple(p.flight_sat_footprint_m))
        elif g.name.startswith(("pitch", "towns/")):
            add_pairs(g.name, by_group[g.name], "now", h0, fp0)
    if p.frame_split:
        _add_frame_split(by_group, seed, lambda name, rows: add_pairs(name, rows, "now", h0, fp0))
    if p.n_height_train > 0 and p.n_height_test > 0:
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(0x48,)))
        subsets = {}
        for part, n in (("train", p.n_height_train), ("test", p.n_height_test)):
            rows = by_group[f"standard/{part}"]
            order = rng.permutation(flights_of[f"standard/{part}"])
            chosen = rows.set_index("flight").loc[order].reset_index()  # whole flights, shuffled
            subsets[part] = chosen.iloc[: min(n, len(chosen))].sort_values(
                "uav_index", kind="stable"
            )
        for h in p.sat_heights_m:
            for part in ("train", "test"):
                add_pairs(f"height{h:g}/{part}", subsets[part], "now", h, footprint(h))
    for name in (*CONFIRM_SPLITS, *LONG_SPLITS):  # last: the others keep their satellite indices
        if name in by_group:
            add_pairs(name, by_group[name], "now", h0, fp0)

    uav, sat = assign_illumination(uav, pd.DataFrame(sat_rows), cities, seed)
    pairs = pd.concat(pair_parts, ignore_index=True)
    u = uav.set_index("uav_index").loc[pairs.uav_index]
    s = sat.set_index("sat_index").loc[pairs.sat_index]
    for col in ("city", "style", "centre", "flight", "frame", "time_s", *POSE_COLUMNS):
        pairs[col] = u[col].to_numpy()
    for col in ODOMETRY_COLUMNS:
        pairs[col] = u[col].to_numpy()
    for col in ("light", "visibility_m", "sun_az", "sun_el"):
        pairs[col] = u[col].to_numpy()
    for col in (*POSE_COLUMNS, "light", "sun_az", "sun_el"):
        pairs[f"sat_{col}"] = s[col].to_numpy()
    pairs["sat_height_m"] = s["height_m"].to_numpy()
    labels = relative_labels(u.reset_index(drop=True), s.reset_index(drop=True))
    pairs = pd.concat([pairs, labels], axis=1)
    return Plan(uav=uav, sat=sat, pairs=pairs, splits=list(dict.fromkeys(pairs.split)))
