"""The calibration interchange format ``shaftgauge.calibration/1`` (see
``shared/calibration-format.md``): load, validate, save.

Validation refuses, each with a message that names the field: a wrong schema or unit, non-finite
numbers, a normal or direction whose length differs from 1 by more than 1e-6 (never silently
normalised), a plane through the camera centre, a light plane within 5 degrees of parallel to
the axis, and a camera matrix that is not upper triangular with positive focal lengths.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PositiveInt,
    ValidationError,
    field_validator,
    model_validator,
)

SCHEMA = "shaftgauge.calibration/1"
UNIT_TOLERANCE = 1e-6
MIN_PLANE_OFFSET_MM = 1e-3
MIN_PLANE_AXIS_ANGLE_DEG = 5.0
DIST_COEFF_COUNTS = (4, 5, 8, 12, 14)
MIN_IMAGE_SIDE_PX, MAX_IMAGE_SIDE_PX = 16, 65536
MIN_WORKING_DISTANCE_MM, MAX_WORKING_DISTANCE_MM = 20.0, 10_000.0
"""The axis is in front of the camera, farther than the least and nearer than the most (a
gauge at a lathe works 100 mm to a metre or two from the shaft; an axis 4 um from the camera
is a board described a thousand times too small)."""
EDGE_DISTORTION = (0.25, 4.0)
"""At the image's farthest corner the radial model may scale the radius within this (a
lens's barrel or pincushion is tens of per cent; a factor of 0 or 1e300 is a typing error)."""

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class CalibrationError(ValueError):
    """A calibration document that cannot be used; the message names the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, frozen=True)


def _unit(v: list[float], what: str) -> list[float]:
    length = math.sqrt(sum(x * x for x in v))
    if abs(length - 1.0) > UNIT_TOLERANCE:
        raise ValueError(f"{what} must be a unit vector: its length is {length:.9g}")
    return v


class LightPlane(_Strict):
    """The laser plane ``normal . X = d`` in the camera frame (mm)."""

    normal: Vec3
    d: float

    @field_validator("normal")
    @classmethod
    def _normal_is_unit(cls, v: list[float]) -> list[float]:
        return _unit(v, "normal")

    @field_validator("d")
    @classmethod
    def _not_through_camera(cls, v: float) -> float:
        if abs(v) < MIN_PLANE_OFFSET_MM:
            raise ValueError(
                f"|d| is {abs(v):.3g} mm: a light plane through the camera centre cannot "
                f"triangulate (need |d| >= {MIN_PLANE_OFFSET_MM} mm)")
        return v


class Axis(_Strict):
    """The spindle axis in the camera frame: unit direction, optionally a point on it (mm)."""

    direction: Vec3
    point: Vec3 | None = None

    @field_validator("direction")
    @classmethod
    def _direction_is_unit(cls, v: list[float]) -> list[float]:
        return _unit(v, "direction")


class Calibration(_Strict):
    """One ``shaftgauge.calibration/1`` document."""

    schema_: Literal["shaftgauge.calibration/1"] = Field(alias="schema")
    units: Literal["mm"]
    image_size: Annotated[list[PositiveInt], Field(min_length=2, max_length=2)]
    camera_matrix: Annotated[list[Vec3], Field(min_length=3, max_length=3)]
    dist_coeffs: list[float]
    light_plane: LightPlane
    axis: Axis

    model_config = ConfigDict(populate_by_name=True)

    @field_validator("camera_matrix")
    @classmethod
    def _intrinsics(cls, k: list[list[float]]) -> list[list[float]]:
        if k[1][0] != 0 or k[2][0] != 0 or k[2][1] != 0:
            raise ValueError("must be upper triangular (K[1][0], K[2][0], K[2][1] all 0)")
        if not (k[0][0] > 0 and k[1][1] > 0):
            raise ValueError(f"focal lengths must be positive, got fx={k[0][0]}, fy={k[1][1]}")
        if k[2][2] != 1:
            raise ValueError(f"K[2][2] must be 1 (OpenCV convention), got {k[2][2]}")
        return k

    @field_validator("dist_coeffs")
    @classmethod
    def _dist_count(cls, v: list[float]) -> list[float]:
        if len(v) not in DIST_COEFF_COUNTS:
            raise ValueError(f"has {len(v)} values; OpenCV takes 4, 5, 8, 12 or 14")
        return v

    @model_validator(mode="after")
    def _plausible(self) -> Calibration:
        """What a camera at a lathe can be: the principal point on the sensor, a focal
        length of at most 100 image widths, the radial distortion at the farthest corner
        within ``EDGE_DISTORTION``, the light plane and the axis in front of the camera and
        within ``MAX_WORKING_DISTANCE_MM``."""
        (fx, _, cx), (_, fy, cy), _ = self.camera_matrix
        w, h = self.image_size
        if not (min(w, h) >= MIN_IMAGE_SIDE_PX and max(w, h) <= MAX_IMAGE_SIDE_PX):
            raise ValueError(f"image_size: {w} x {h} px is no camera's (each side "
                             f"{MIN_IMAGE_SIDE_PX}-{MAX_IMAGE_SIDE_PX} px)")
        if not (0 <= cx <= w and 0 <= cy <= h):
            raise ValueError(f"camera_matrix: the principal point ({cx:g}, {cy:g}) px is off "
                             f"the {w} x {h} image")
        if max(fx, fy) > 100 * max(w, h):
            raise ValueError(f"camera_matrix: focal lengths of {max(fx, fy):g} px are over "
                             f"100 image widths")
        factor = _edge_distortion(self.dist_coeffs, max(
            math.hypot((x - cx) / fx, (y - cy) / fy) for x in (0, w) for y in (0, h)))
        low, high = EDGE_DISTORTION
        if not low <= factor <= high:
            raise ValueError(f"dist_coeffs: at the image's farthest corner they scale the "
                             f"radius by {factor:.3g} (a lens does {low:g} to {high:g})")
        if abs(self.light_plane.d) > MAX_WORKING_DISTANCE_MM:
            raise ValueError(f"light_plane: d = {self.light_plane.d:g} mm puts the plane "
                             f"beyond {MAX_WORKING_DISTANCE_MM:g} mm of the camera")
        point = self.axis.point
        if point is not None and not (
                MIN_WORKING_DISTANCE_MM <= point[2] <= MAX_WORKING_DISTANCE_MM
                and max(abs(point[0]), abs(point[1])) <= MAX_WORKING_DISTANCE_MM):
            raise ValueError(f"axis.point: {point} mm is not in front of the camera "
                             f"{MIN_WORKING_DISTANCE_MM:g} to {MAX_WORKING_DISTANCE_MM:g} mm "
                             "away (is the board's square size right?)")
        return self

    @model_validator(mode="after")
    def _plane_crosses_axis(self) -> Calibration:
        cos = abs(float(np.dot(self.light_plane.normal, self.axis.direction)))
        angle = math.degrees(math.asin(min(1.0, cos)))  # angle between plane and axis
        if angle < MIN_PLANE_AXIS_ANGLE_DEG:
            raise ValueError(
                f"light_plane: the plane is {angle:.2f} degrees from parallel to the axis "
                f"(need at least {MIN_PLANE_AXIS_ANGLE_DEG:.0f}); it would not cut a section")
        return self

    # ---- conversions -----------------------------------------------------------------------

    def to_document(self) -> dict[str, Any]:
        """The interchange document as a JSON-ready dict (round-trips unchanged)."""
        return self.model_dump(by_alias=True, exclude_none=True)

    def to_json(self, indent: int | None = 2) -> str:
        """The interchange document as JSON text."""
        return json.dumps(self.to_document(), indent=indent)


def _edge_distortion(k: list[float], r: float) -> float:
    """OpenCV's radial factor at normalised radius ``r`` (k1 k2 p1 p2 [k3 [k4 k5 k6]])."""
    r2 = r * r
    k1, k2 = k[0], k[1]
    k3 = k[4] if len(k) > 4 else 0.0
    num = 1.0 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    den = 1.0 + (k[5] * r2 + k[6] * r2 ** 2 + k[7] * r2 ** 3 if len(k) >= 8 else 0.0)
    with np.errstate(all="ignore"):
        factor = float(np.float64(num) / np.float64(den)) if den else math.inf
    return factor if math.isfinite(factor) else math.inf


def format_validation_error(err: ValidationError,
                            rename: Callable[[tuple], tuple] | None = None) -> str:
    """One line per problem, each starting with the dotted field name (``rename`` may change
    a field's path first: one that holds a secret)."""
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in (rename(e["loc"]) if rename else e["loc"]))
        msg = e["msg"].removeprefix("Value error, ")
        # Whole-document checks name their fields in the message itself.
        lines.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(lines)


def parse_calibration(document: Any) -> Calibration:
    """Validate a decoded JSON document.

    Raises
    ------
    CalibrationError
        With a message naming each bad field.
    """
    if not isinstance(document, dict):
        raise CalibrationError(f"document: expected a JSON object, got {type(document).__name__}")
    schema = document.get("schema")
    if schema != SCHEMA:
        raise CalibrationError(f"schema: expected {SCHEMA!r}, got {schema!r}")
    try:
        return Calibration.model_validate(document)
    except ValidationError as err:
        raise CalibrationError(format_validation_error(err)) from None


def loads_calibration(text: str | bytes) -> Calibration:
    """Parse and validate calibration JSON text."""
    try:
        document = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise CalibrationError(f"document: not valid JSON ({err})") from None
    return parse_calibration(document)


def load_calibration(path: str | Path) -> Calibration:
    """Read and validate a calibration file; errors name the file and the field."""
    p = Path(path)
    try:
        text = p.read_bytes()
    except OSError as err:
        raise CalibrationError(f"{p}: cannot read ({err.strerror})") from None
    try:
        return loads_calibration(text)
    except CalibrationError as err:
        raise CalibrationError(f"{p}: {err}") from None


def save_calibration(calibration: Calibration, path: str | Path) -> None:
    """Write a calibration file (atomically: a temporary file renamed into place)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(calibration.to_json() + "\n")
    tmp.replace(p)
