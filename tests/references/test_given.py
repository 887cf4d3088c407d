"""Each reference is given only what it declares (issue 38, item 4).

The declaration (``Reference.given_values``) drives the report's wording and the frames a
reference is served; a withheld true value is absent from the frame. Checked on the smoke
dataset's rendered pairs, through ``evaluate_reference`` (the path the report takes): changing any
UAV value of a pair row the reference is not given (its true pose, the labels derived from it, the
flight, time and illumination) leaves every estimate bit for bit the same, and changing each value
it is given changes some estimate (so the check is not vacuous).

Bit for bit: the attitude, the position and the failure flag. The match score is compared to
1e-8: the oracle's gradient channel (``cv2.magnitude``, OpenCV 5.1) rounds a few pixels' last bit
differently with the memory alignment of its input, so the same frame evaluated twice can score
1e-10 apart whatever it is given (measured on these frames: up to 1e-9; the estimate is the same).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from benchmark.data import PairDataset
from benchmark.data.dataset import R_COLUMNS
from benchmark.references import (
    TRUE_POSE_COLUMNS,
    Estimate,
    GivenValue,
    Reference,
    TrueValues,
    WithheldError,
    create_reference,
    evaluate_reference,
    get_reference_class,
    iter_frames,
    list_references,
)
from benchmark.runner.execute.reference_rows import reads_text

# What the protocol (issue 21) gives each reference, as pose-table columns and as the row label.
PROTOCOL = {
    "geometry_oracle": (
        ("E", "N", "U", "pitch", "roll"),
        "Geometry oracle (not learned; given true position, pitch, roll)",
    ),
    "gravity_template": (
        ("U", "pitch", "roll"),
        "Gravity-aided template matching (not learned; given true pitch, roll, altitude)",
    ),
    "feature_pnp": ((), "Feature matching + PnP (not learned; given no true pose values)"),
}

# Every value of a pair row, by who may see it. The UAV side: what a reference may be given (the
# true pose) or is never given (the labels, flight, time, illumination, odometry), with the change
# the test makes to it. The satellite side is the image's geo-reference, known to every method; the
# rest says which images and place the pair is.
UAV_ROW = {
    **dict(zip(TRUE_POSE_COLUMNS, (53.0, -41.0, 17.0, 1.1, 0.09, -0.07), strict=True)),
    **dict.fromkeys(R_COLUMNS, 0.25),
    "dE": 31.0,
    "dN": -23.0,
    "dU": 13.0,
    "time_s": 5.0,
    "flight": 1,
    "frame": 1,
    "light": 1,
    "visibility_m": 500.0,
    "sun_az": 0.5,
    "sun_el": -0.2,
    # The motion since the flight's previous sample (NaN on its first): flight fusion reads it, a
    # per-frame reference never does.
    "odo_dyaw": 0.03,
    "odo_dx": 1.5,
    "odo_dy": 9.0,
    "odo_dz": 0.4,
}
SATELLITE_ROW = ("sat_E", "sat_N", "sat_U", "sat_yaw", "sat_pitch", "sat_roll", "sat_light",
                 "sat_sun_az", "sat_sun_el", "sat_height_m")  # fmt: skip
WHICH_PAIR = ("split", "uav_index", "sat_index", "city", "style", "centre")
SPLITS = ("standard/test", "towns/test")
# Every reference as the report runs it, and the yaw sweeps made to fail on every frame (their
# failed estimate is checked too: feature_pnp fails on every 32 px smoke pair anyway).
CASES = [(name, {}) for name in list_references()] + [
    ("geometry_oracle", {"min_pixels": 10**6}),
    ("gravity_template", {"min_cells": 10**6}),
]


@pytest.fixture(scope="module")
def splits(smoke_dataset):
    return [PairDataset(smoke_dataset, split, verify="size") for split in SPLITS]


def _changed(dataset: PairDataset, column: str) -> PairDataset:
    """``dataset`` with ``column`` of every pair row changed by ``UAV_ROW[column]``."""
    out = copy.copy(dataset)
    out.poses = dataset.poses.copy()
    out.poses[column] = out.poses[column] + UAV_ROW[column]
    return out


def _bits(est: Estimate) -> tuple:
    return est.R_bn.tobytes(), np.asarray(est.position).tobytes(), bool(est.failed), est.score


def _same(a: list[tuple], b: list[tuple]) -> bool:
    """The same estimates: bit for bit but the score, to 1e-8 (module docstring)."""
    return len(a) == len(b) and all(
        x[:3] == y[:3] and bool(np.isclose(x[3], y[3], rtol=0.0, atol=1e-8, equal_nan=True))
        for x, y in zip(a, b, strict=True)
    )


def _estimates(reference: Reference, datasets: list[PairDataset]) -> list[tuple]:
    """Every estimate ``reference`` makes when ``evaluate_reference`` runs it on ``datasets``."""
    out: list[tuple] = []
    estimate = reference.estimate

    def recorded(frame):
        est = estimate(frame)
        out.append(_bits(est))
        return est

    reference.estimate = recorded  # the instance's: evaluate_reference calls it
    try:
        for dataset in datasets:
            evaluate_reference(reference, dataset)
    finally:
        del reference.estimate
    return out


class TestDeclaration:
    def test_each_reference_is_given_what_the_protocol_says(self):
        assert list(PROTOCOL) == list_references()
        for name, (columns, label) in PROTOCOL.items():
            cls = get_reference_class(name)
            assert cls.given_columns == columns and cls.label == label
            assert reads_text(name).startswith(
                f"reads the true {', '.join(cls.given)};" if columns else "reads no true pose"
            )

    def test_label_and_wording_come_from_the_declaration_only(self):
        class Altimeter(Reference):
            name, title = "altimeter", "Altimeter"
            given_values = (GivenValue(("U",), "altitude", "altitude"),)

            def estimate(self, frame):
                return Estimate(np.eye(3), np.zeros(3))

        assert Altimeter.label == "Altimeter (not learned; given true altitude)"
        assert Altimeter.given == ("altitude",) and Altimeter.given_columns == ("U",)
        with pytest.raises(TypeError, match="label"):

            class ByHand(Altimeter):
                label = "Altimeter (not learned; given nothing)"

    def test_only_true_pose_columns_can_be_given(self):
        with pytest.raises(ValueError, match="dE"):
            GivenValue(("dE",), "translation label", "translation")
        with pytest.raises(ValueError, match="R00"):
            TrueValues({"R00": 1.0})

    def test_a_withheld_value_is_absent(self):
        truth = TrueValues.select({"E": 1.0, "N": 2.0, "U": 3.0, "yaw": 0.5}, ("U",))
        assert dict(truth) == {"U": 3.0} and "yaw" not in truth
        with pytest.raises(WithheldError, match="'yaw' is withheld"):
            truth["yaw"]
        with pytest.raises(KeyError):
            truth.position()


class TestWithheldValuesAreAbsent:
    def test_the_pair_rows_hold_nothing_unaccounted_for(self, splits):
        known = set(UAV_ROW) | set(SATELLITE_ROW) | set(WHICH_PAIR)
        for dataset in splits:
            assert set(dataset.poses.columns) == known

    @pytest.mark.parametrize("name", list_references())
    def test_frames_hold_exactly_the_given_values(self, splits, name):
        cls = get_reference_class(name)
        for dataset in splits:
            for i, frame in iter_frames(dataset, given_columns=cls.given_columns):
                assert tuple(frame.truth) == cls.given_columns
                for column in cls.given_columns:
                    assert frame.truth[column] == dataset.poses[column][i]

    @pytest.mark.parametrize(("name", "options"), CASES, ids=lambda x: str(x or "defaults"))
    def test_withheld_values_change_nothing_and_given_ones_do(self, splits, name, options):
        reference = create_reference(name, **options)
        given = set(reference.given_columns)
        before = _estimates(reference, splits)
        assert len(before) == sum(len(d) for d in splits)
        if options:
            assert all(failed for _, _, failed, _ in before)
        for column in UAV_ROW:
            after = _estimates(reference, [_changed(d, column) for d in splits])
            if column in given:
                assert not _same(after, before), f"{name}: its given {column} changed nothing"
            else:
                assert _same(after, before), f"{name}: the withheld {column} changed it"
