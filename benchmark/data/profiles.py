"""Dataset profiles for ``uavbench simulate``: frozen configs, degrees and metres at this edge.

``smoke`` is for tests and the CI smoke reproduction (seconds), ``quick`` the default (minutes on
2 cores), ``paper`` the full-size reproduction (224 px, tens of thousands of pairs, paper Sec. 3.1).
``--size N`` rescales every set of a profile so that the standard split holds N pairs.

Each profile also states the noise of the odometry every UAV sample carries (``odometry_*``,
degrees at this edge; ``benchmark.sim.odometry_noise`` turns them into radians) and how many long
test flights (``long/{standard,towns,london}``, issue 39) it renders.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

# Fixed style roles (issue 3): two training cities, one held-out city, one flight-test city.
TRAIN_STYLES: tuple[str, ...] = ("oxford", "cambridge")
GENERALIZED_STYLE = "london"
FLIGHT_STYLE = "industrial"
# Roles of the towns family, split names towns/<role>; the order of DataProfile.n_towns and
# n_town_pairs. Same as benchmark.sim.towns.TOWN_ROLES (tested; data does not import sim here).
TOWN_ROLES: tuple[str, ...] = ("train", "val", "test", "london")
# DataProfile's odometry noise fields, as benchmark.sim.odometry.PROFILE_FIELDS reads them (tested).
ODOMETRY_FIELDS: tuple[str, ...] = (
    "odometry_gyro_bias_dps",
    "odometry_yaw_walk_deg",
    "odometry_scale_sigma",
    "odometry_step_sigma_m",
)


@dataclass(frozen=True)
class DataProfile:
    """Everything that determines a dataset besides the seed. Stored in the manifest.

    Pair counts per set, image and flight geometry, the towns family, the confirmation draw, the
    odometry noise figures (``odometry_*``: deg/s, deg, fraction, m; the UAV rows' ``odo_*``
    columns are measured with them) and the long test flights (``n_long_flights``,
    ``long_samples_per_flight``, ``long_frame_stride``: splits ``long/{standard,towns,london}``).
    Degrees and metres here, the config edge."""

    name: str
    image_size: int  # UAV and satellite images are image_size x image_size (paper: 224)
    n_standard: int  # pairs in standard/{train,val,test} together
    standard_fractions: tuple[float, float, float] = (0.8, 0.1, 0.1)  # train, val, test
    n_generalized_test: int = 0  # london pairs
    n_flight_per_pitch: int = 0  # industrial pairs for each fixed pitch
    flight_pitches_deg: tuple[float, ...] = (0.0, -10.0, -50.0)  # paper Sec. 3.5
    flight_altitude_m: tuple[float, float] = (70.0, 90.0)  # paper Sec. 3.5
    n_pitch_per_bin: int = 0  # pitch-sweep test pairs per bin (paper Fig. 6)
    pitch_bin_edges_deg: tuple[float, ...] = (0.0, -10.0, -20.0, -30.0, -40.0, -50.0)
    sat_heights_m: tuple[float, ...] = (600.0, 800.0, 1000.0, 1200.0, 1400.0)  # paper Fig. 5
    n_height_train: int = 0  # per height, taken from standard/train (whole flights)
    n_height_test: int = 0  # per height, taken from standard/test (whole flights)
    sat_height_m: float = 1000.0  # paper Sec. 3.1
    sat_footprint_m: tuple[float, float] = (2000.0, 1000.0)  # E x N at sat_height_m
    flight_sat_footprint_m: tuple[float, float] = (2500.0, 1200.0)  # paper Sec. 3.5
    samples_per_flight: int = 16
    # Samples per flight of the held-out groups (every val and test split, generalized/test, the
    # pitch bins, towns val/test/london; the height test sets are whole flights of standard/test):
    # None = samples_per_flight. Intervals resample whole flights, and frames of one flight are
    # correlated (the oracle's yaw errors on quick standard/val: intra-flight correlation 0.55), so
    # at the same number of pairs more, shorter flights give narrower intervals; the training
    # splits and the flight-test analogue (flight/*, continuous flights) keep samples_per_flight.
    # Flights are numbered across the groups and a flight's illumination follows its number, so
    # groups planned after the held-out ones (towns/train) keep their poses but draw other
    # illumination states; standard/train is unchanged in every column.
    eval_samples_per_flight: int | None = None
    frame_stride: int = 15  # 30 fps video, one sample every 0.5 s
    fov_deg: float = 60.0  # horizontal field of view of the UAV camera
    supersample: int = 1  # rays per pixel per axis; textures are mip-mapped, 2 costs 4x
    shard_size: int = 256  # UAV images per .npy shard
    sat_shard_size: int = 8  # satellite images per shard (each costs ~16 UAV frames to render)
    city_size_m: tuple[float, float] | None = None  # build_city size_m; None: its default tile
    city_metres_per_px: float = 1.0
    # Leakage audit (issue 9): frames/{train,val,test} re-split the standard flights' frames at
    # random, as a naive split of video frames would; same sizes as standard/{train,val,test}.
    frame_split: bool = True
    # Many towns (issue 9): procedurally distinct small tiles, one flight centre each (the tile
    # centre). Towns per role (train, val, test: training styles; london: the held-out style) and
    # pairs of towns/{train,val,test,london}.
    n_towns: tuple[int, int, int, int] = (0, 0, 0, 0)
    n_town_pairs: tuple[int, int, int, int] = (0, 0, 0, 0)
    town_size_m: tuple[float, float] = (2048.0, 1280.0)  # holds the 2 km x 1 km footprint
    town_metres_per_px: float = 2.0
    # Confirmation draw (issue 38): ``confirm/{standard,towns,generalized}``, a second set of test
    # flights as large as standard/test, towns/test and generalized/test, drawn from seed streams
    # of their own (draw k), with n_towns[test] new towns of the training styles. Nothing may be
    # chosen on them; a draw once used for a choice is replaced by the next one (k + 1). 0: none.
    confirm_draw: int = 0
    # Odometry noise (issue 39): what a consumer MEMS IMU plus visual odometry (VIO) gives per
    # sample (model: benchmark.sim.odometry). Gyro bias 0.2 deg/s per flight: a consumer MEMS
    # gyro's turn-on bias is of order 1 deg/s (BMI088: +-1 deg/s), and in-flight bias estimation
    # leaves a residual of order 0.1-0.2 deg/s; we take the top. 0.2 deg per step: the gyro's
    # angle random walk (0.3-0.9 deg/sqrt(h) for MPU-6000/BMI088-class parts: 0.01-0.02 deg over a
    # 2 s step) is small beside the VIO's own rotation noise between keyframes, which this covers.
    # Scale 3 %: a VIO's translation scale error is a few percent. 0.5 m per step and axis: VIO
    # over 0.5-2 s steps at 6-15 m/s. Each figure is at least the yardstick (0.2 deg/s,
    # 0.2 deg per step, 3 %), so a fusion shown to work here works on odometry no better.
    odometry_gyro_bias_dps: float = 0.2  # deg/s, std of the per-flight gyro bias
    odometry_yaw_walk_deg: float = 0.2  # deg, std of the heading noise per step
    odometry_scale_sigma: float = 0.03  # fraction, std of the per-flight translation scale error
    odometry_step_sigma_m: float = 0.5  # metres, std of the displacement noise per step and axis
    # Long test flights (issue 39): flights of 16 samples at 2 Hz (8 s) are too short to show what
    # fusing along a flight gains. ``long/{standard,towns,london}`` hold n_long_flights flights
    # each (0: none) of long_samples_per_flight samples every long_frame_stride video frames: the
    # default 32 samples every 60 frames (2 s at 30 fps) span 62 s. Test-only; cheap to render.
    n_long_flights: int = 0
    long_samples_per_flight: int = 32
    long_frame_stride: int = 60

    def __post_init__(self) -> None:
        if self.image_size < 8:
            raise ValueError(f"DataProfile.image_size must be >= 8, got {self.image_size}")
        if self.n_standard < 3:
            raise ValueError(
                f"DataProfile.n_standard must be >= 3 (train/val/test), got {self.n_standard}"
            )
        if abs(sum(self.standard_fractions) - 1.0) > 1e-9 or min(self.standard_fractions) <= 0:
            raise ValueError(
                "DataProfile.standard_fractions must be positive and sum to 1, got "
                f"{self.standard_fractions}"
            )
        edges = self.pitch_bin_edges_deg
        if any(b >= a for a, b in itertools.pairwise(edges)):
            raise ValueError(f"DataProfile.pitch_bin_edges_deg must decrease strictly, got {edges}")
        if min(self.samples_per_flight, self.shard_size, self.sat_shard_size) < 1:
            raise ValueError(
                "DataProfile.samples_per_flight, shard_size, sat_shard_size must be >= 1"
            )
        if self.eval_samples_per_flight is not None and (
            int(self.eval_samples_per_flight) != self.eval_samples_per_flight
            or self.eval_samples_per_flight < 1
        ):
            raise ValueError(
                "DataProfile.eval_samples_per_flight must be None or an integer >= 1, got "
                f"{self.eval_samples_per_flight!r}"
            )
        for name in ("n_towns", "n_town_pairs"):
            v = getattr(self, name)
            if len(v) != 4 or any(int(x) != x or x < 0 for x in v):
                raise ValueError(
                    f"DataProfile.{name} must be 4 non-negative integers "
                    f"(train, val, test, london), got {v}"
                )
        if int(self.confirm_draw) != self.confirm_draw or self.confirm_draw < 0:
            raise ValueError(
                f"DataProfile.confirm_draw must be an integer >= 0, got {self.confirm_draw!r}"
            )
        for name in ODOMETRY_FIELDS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"DataProfile.{name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"DataProfile.{name} must be finite and >= 0, got {value!r}")
        # a long flight needs two samples for one odometry step
        for name, least in (("n_long_flights", 0), ("long_samples_per_flight", 2),
                            ("long_frame_stride", 1)):  # fmt: skip
            value = getattr(self, name)
            whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
            if isinstance(value, bool) or not whole or value < least:
                raise ValueError(f"DataProfile.{name} must be an integer >= {least}, got {value!r}")
        for role, towns, pairs in zip(TOWN_ROLES, self.n_towns, self.n_town_pairs, strict=True):
            if pairs > 0 and towns == 0:
                raise ValueError(
                    f"DataProfile: {pairs} towns/{role} pairs need n_towns[{role}] > 0, got 0"
                )

    def with_size(self, n_standard: int) -> DataProfile:
        """This profile rescaled so that the standard split holds ``n_standard`` pairs.

        Every set scales by its number of pairs; the long test splits by their number of flights
        (``n_long_flights``, at least 1 if any), never by their length: a long flight stays as
        long as the profile says, since its length is what those splits are for. The length of
        the other flights does not change either."""
        if n_standard < 3:
            raise ValueError(f"size must be >= 3 pairs (train, val, test), got {n_standard}")
        f = n_standard / self.n_standard

        def scale(n: int) -> int:
            return 0 if n == 0 else max(1, math.ceil(n * f))

        return dataclasses.replace(
            self,
            n_standard=n_standard,
            n_generalized_test=scale(self.n_generalized_test),
            n_flight_per_pitch=scale(self.n_flight_per_pitch),
            n_pitch_per_bin=scale(self.n_pitch_per_bin),
            n_height_train=scale(self.n_height_train),
            n_height_test=scale(self.n_height_test),
            n_town_pairs=tuple(scale(n) for n in self.n_town_pairs),
            n_long_flights=scale(self.n_long_flights),
        )

    def standard_only(self) -> DataProfile:
        """This profile with only the standard splits (train, val, test): what the heading-cue
        audit renders for its extra dataset seeds. Named ``<name>-standard``."""
        return dataclasses.replace(
            self,
            name=f"{self.name}-standard",
            n_generalized_test=0,
            n_flight_per_pitch=0,
            n_pitch_per_bin=0,
            n_height_train=0,
            n_height_test=0,
            frame_split=False,
            n_towns=(0, 0, 0, 0),
            n_town_pairs=(0, 0, 0, 0),
            confirm_draw=0,
            n_long_flights=0,
        )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> DataProfile:
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - set(fields))
        if unknown:
            raise ValueError(f"DataProfile: unknown fields {unknown}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


DATA_PROFILES: dict[str, DataProfile] = {
    "smoke": DataProfile(
        name="smoke",
        image_size=32,
        n_standard=24,
        n_generalized_test=6,
        n_flight_per_pitch=4,
        n_pitch_per_bin=2,
        n_height_train=8,
        n_height_test=4,
        samples_per_flight=4,
        frame_stride=30,
        shard_size=16,
        city_size_m=(1024.0, 768.0),
        city_metres_per_px=2.0,
        n_towns=(3, 1, 1, 1),
        n_town_pairs=(16, 4, 4, 4),
        town_size_m=(1024.0, 768.0),
        confirm_draw=1,
        # 2 flights of 6 samples per long split (10 s): the splits exist, tests stay fast.
        n_long_flights=2,
        long_samples_per_flight=6,
        long_frame_stride=60,
    ),
    "quick": DataProfile(
        name="quick",
        image_size=96,
        # Held-out sets are large enough for flight-bootstrap intervals (issue 10): standard
        # 2400/600/600 pairs (150 training flights of 16 samples; 150/150 held-out flights of 4),
        # london 1200 (300 flights); training sets as before, the height training sets cut to
        # 800 pairs to fit the seeds into the time budget.
        n_standard=3600,
        standard_fractions=(2 / 3, 1 / 6, 1 / 6),
        n_generalized_test=1200,
        n_flight_per_pitch=200,
        n_pitch_per_bin=160,
        n_height_train=800,
        n_height_test=300,
        n_towns=(40, 4, 8, 6),
        n_town_pairs=(1600, 160, 480, 1200),
        samples_per_flight=16,
        eval_samples_per_flight=4,
        shard_size=256,
        confirm_draw=1,
        # 24 flights of 32 samples (62 s) per long split: 768 pairs each, 2304 in all, about 20 s
        # of one core to render at 96 px (6-8 ms a frame).
        n_long_flights=24,
    ),
    "paper": DataProfile(
        name="paper",
        image_size=224,
        n_standard=24000,
        n_generalized_test=2400,
        n_flight_per_pitch=600,
        n_pitch_per_bin=400,
        n_height_train=8000,
        n_height_test=2400,
        n_towns=(200, 20, 40, 30),
        n_town_pairs=(16000, 1600, 2400, 2400),
        town_metres_per_px=1.0,
        samples_per_flight=24,
        eval_samples_per_flight=6,
        shard_size=256,
        confirm_draw=1,
        n_long_flights=40,  # 1280 pairs per long split
    ),
}


def get_data_profile(name: str, size: int | None = None) -> DataProfile:
    """The named profile, optionally rescaled to ``size`` standard pairs; ValueError if bad."""
    if name not in DATA_PROFILES:
        raise ValueError(f"unknown profile {name!r}; expected one of {sorted(DATA_PROFILES)}")
    profile = DATA_PROFILES[name]
    return profile if size is None else profile.with_size(size)
