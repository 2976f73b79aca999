"""Offline measurement of image files: the engine behind ``shaftgauge measure``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calib_store.model import Calibration
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.result import Measurement, Method


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
        "reason": d["reason"],
    }


def measure_files(
    paths: list[str], calibration: Calibration, method: Method,
    params: MeasureParams | None = None,
) -> Iterator[dict[str, Any]]:
    """Check every file first (so that a bad one stops the run before any output), then yield
    one record per image, in order.

    Raises
    ------
    ImageError
        On the first unreadable or wrongly sized image, before anything is yielded.
    """
    for p in paths:
        check_image_file(p, calibration)
    geometry = calibration.to_geometry()
    for p in paths:
        yield measurement_record(p, measure_frame(read_grey_image(p), geometry, method, params))
