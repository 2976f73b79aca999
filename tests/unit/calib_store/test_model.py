"""The calibration interchange format: round trip, and every refusal names its field."""

from __future__ import annotations

import copy
import json
import math

import pytest

from calib_store.model import (
    CalibrationError,
    load_calibration,
    loads_calibration,
    parse_calibration,
    save_calibration,
)
from service.measure.geometry import geometry_of

# The example of shared/calibration-format.md, made exactly unit-length.
_n = [0.93, -0.05, -0.36]
_a = [0.999, 0.004, 0.03]
EXAMPLE = {
    "schema": "shaftgauge.calibration/1",
    "units": "mm",
    "image_size": [1376, 1024],
    "camera_matrix": [[3875.97, 0.0, 694.0], [0.0, 3876.75, 508.0], [0.0, 0.0, 1.0]],
    "dist_coeffs": [-0.12, 0.25, 0.0004, -0.0003, 0.0],
    "light_plane": {"normal": [v / math.hypot(*_n) for v in _n], "d": -41.8},
    "axis": {"direction": [v / math.hypot(*_a) for v in _a], "point": [-2.1, 1.3, 297.4]},
}


def with_change(path: str, value: object) -> dict:
    doc = copy.deepcopy(EXAMPLE)
    *parents, last = path.split(".")
    node = doc
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node[p]
    if isinstance(node, list):
        node[int(last)] = value
    elif value is ...:
        del node[last]
    else:
        node[last] = value
    return doc


def test_round_trip_is_unchanged(tmp_path) -> None:
    cal = parse_calibration(EXAMPLE)
    assert cal.to_document() == EXAMPLE
    path = tmp_path / "cal.json"
    save_calibration(cal, path)
    assert json.loads(path.read_text()) == EXAMPLE
    assert load_calibration(path) == cal


def test_axis_point_is_optional_and_stays_absent() -> None:
    doc = with_change("axis.point", ...)
    cal = parse_calibration(doc)
    assert cal.to_document() == doc
    assert geometry_of(cal).axis_point is None


def test_integers_are_accepted_where_numbers_are_expected() -> None:
    doc = with_change("camera_matrix", [[3875, 0, 694], [0, 3876, 508], [0, 0, 1]])
    assert geometry_of(parse_calibration(doc)).camera_matrix[0, 0] == 3875.0


def test_geometry_conversion() -> None:
    geo = geometry_of(parse_calibration(EXAMPLE))
    assert geo.image_size == (1376, 1024)
    assert geo.camera_matrix.shape == (3, 3)
    assert geo.plane_d == -41.8


@pytest.mark.parametrize(
    ("path", "value", "field", "words"),
    [
        ("schema", "shaftgauge.calibration/2", "schema", "expected"),
        ("schema", ..., "schema", "expected"),
        ("units", "inch", "units", "mm"),
        ("image_size", [1376], "image_size", "at least 2"),
        ("image_size", [0, 1024], "image_size.0", "greater than 0"),
        ("camera_matrix.1", [0.1, 3876.75, 508.0], "camera_matrix", "upper triangular"),
        ("camera_matrix.0", [-3875.97, 0.0, 694.0], "camera_matrix", "positive"),
        ("camera_matrix.2", [0.0, 0.0, 2.0], "camera_matrix", "K[2][2]"),
        ("dist_coeffs", [0.1, 0.2, 0.3], "dist_coeffs", "4, 5, 8, 12 or 14"),
        ("dist_coeffs", [0.1, "x", 0.0, 0.0], "dist_coeffs.1", "number"),
        ("light_plane.normal", [0.93, -0.05, -0.36], "light_plane.normal", "unit vector"),
        ("light_plane.normal", [1.0, 0.0], "light_plane.normal", "at least 3"),
        ("light_plane.d", 0.0005, "light_plane.d", "camera centre"),
        ("axis.direction", [2.0, 0.0, 0.0], "axis.direction", "unit vector"),
        ("axis.point", [1.0, 2.0], "axis.point", "at least 3"),
        # A board described 80000 times too small (the second outside probe): the axis
        # 0.0037 mm from the camera, its diameters 0.0004 mm, graded good.
        ("axis.point", [0.0, 0.0, 0.0037], "axis.point", "is the board's square size right"),
        ("axis.direction", [0.05 / math.hypot(0.05, 0.93), 0.93 / math.hypot(0.05, 0.93), 0.0],
         "light_plane", "parallel"),
        ("extra", 1, "extra", "not permitted"),
        ("light_plane", ..., "light_plane", "required"),
        ("units", True, "units", "mm"),
        ("light_plane.d", "41.8", "light_plane.d", "number"),
    ],
)
def test_bad_field_is_refused_with_its_name(path, value, field, words) -> None:
    with pytest.raises(CalibrationError) as err:
        parse_calibration(with_change(path, value))
    msg = str(err.value)
    assert msg.startswith(field), msg
    assert words in msg, msg


def test_parallel_plane_check_uses_the_5_degree_limit() -> None:
    # Normal perpendicular to the axis but for 4 and 6 degrees.
    for deg, ok in ((4.0, False), (6.0, True)):
        t = math.radians(deg)
        doc = with_change("light_plane.normal", [math.sin(t), 0.0, math.cos(t)])
        doc["axis"]["direction"] = [1.0, 0.0, 0.0]
        if ok:
            parse_calibration(doc)
        else:
            with pytest.raises(CalibrationError, match="parallel"):
                parse_calibration(doc)


@pytest.mark.parametrize("text", ['{"schema": NaN}', "[1, 2]", "not json", b"\xff\xfe"])
def test_non_documents_are_refused(text) -> None:
    with pytest.raises(CalibrationError):
        loads_calibration(text)


def test_non_finite_number_is_refused_with_field() -> None:
    text = json.dumps(EXAMPLE).replace("-41.8", "NaN")
    with pytest.raises(CalibrationError, match=r"^light_plane\.d"):
        loads_calibration(text)


def test_missing_file_names_the_file(tmp_path) -> None:
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "nope.json")
