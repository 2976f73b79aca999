"""Offline measurement of image files: the engine behind ``shaftgauge measure``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calib_store.model import Calibration
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.fuse import fuse
from service.measure.geometry import geometry_of
from service.measure.result import Measurement, Method
from service.measure.thermal import diameter_at_reference


class ImageError(ValueError):
    """An image file that cannot be measured at all (unreadable, or of the wrong size)."""


def read_grey_image(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit image file as a single-channel array (colour is converted to grey).

    Raises
    ------
    ImageError
        When the file is missing or not an image OpenCV can decode.
    """
    p = Path(path)
    if not p.is_file():
        raise ImageError(f"{p}: no such file")
    image = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageError(f"{p}: not an image file this program can read")
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"{p}: pixel type {image.dtype} is not 8- or 16-bit grey")
    return image


def check_image_file(path: str | Path, calibration: Calibration) -> None:
    """Raise ImageError unless the file is a readable image of the calibrated size."""
    image = read_grey_image(path)
    w, h = calibration.image_size
    if image.shape != (h, w):
        raise ImageError(f"{path}: image is {image.shape[1]}x{image.shape[0]} px but the "
                         f"calibration is for {w}x{h} px")


def measurement_record(image: str, m: Measurement) -> dict[str, Any]:
    """The stable JSON record of one image's measurement (the ``measure`` contract)."""
    d = m.as_dict()

    def rnd(x: float | None, nd: int) -> float | None:
        return None if x is None else round(x, nd)

    return {
        "image": image,
        "method": d["method"],
        "status": d["status"],
        "diameter_mm": rnd(d["diameter_mm"], 6),
        "n_points": d["n_points"],
        "arc_deg": rnd(d["arc_deg"], 2),
        "rms_residual_mm": rnd(d["rms_residual_mm"], 6),
        "uncertainty_mm": rnd(d["uncertainty_mm"], 7),
        "reason": d["reason"],
        "note": d["note"],
    }


def measure_images(
    paths: list[str], calibration: Calibration, method: Method,
    params: MeasureParams | None = None,
) -> Iterator[tuple[str, Measurement]]:
    """Check every file first (so that a bad one stops the run before any output), then yield
    ``(path, measurement)`` per image, in order.

    Raises
    ------
    ImageError
        On the first unreadable or wrongly sized image, before anything is yielded.
    """
    for p in paths:
        check_image_file(p, calibration)
    geometry = geometry_of(calibration)
    for p in paths:
        yield p, measure_frame(read_grey_image(p), geometry, method, params)


def measure_files(
    paths: list[str], calibration: Calibration, method: Method,
    params: MeasureParams | None = None,
) -> Iterator[dict[str, Any]]:
    """One ``measure`` record per image (see ``measure_images``)."""
    for p, m in measure_images(paths, calibration, method, params):
        yield measurement_record(p, m)


def fused_record(paths: list[str], measurements: list[Measurement]) -> dict[str, Any]:
    """The one JSON record of ``measure --fuse``."""
    f = fuse(measurements)

    def rnd(x: float | None, nd: int) -> float | None:
        return None if x is None else round(x, nd)

    return {
        "images": len(paths), "method": f.method.value, "status": f.status.value,
        "diameter_mm": rnd(f.diameter_mm, 6), "uncertainty_mm": rnd(f.uncertainty_mm, 7),
        "n_frames": f.n_frames, "n_used": f.n_used, "n_rejected": f.n_rejected,
        "spread_mm": rnd(f.spread_mm, 7), "reason": f.reason,
    }


def add_temperature(record: dict[str, Any], part_temp_c: float, alpha_per_k: float) -> None:
    """Add the part temperature and the diameter at 20 C to a record (in place)."""
    d = record.get("diameter_mm")
    record["part_temp_c"] = part_temp_c
    record["diameter_20c_mm"] = None if d is None else round(
        diameter_at_reference(d, part_temp_c, alpha_per_k), 6)
