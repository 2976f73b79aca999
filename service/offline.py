"""Offline measurement of image files: the engine behind ``shaftgauge measure``."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calib_store.model import Calibration
from service.calibrate.master import DiameterCorrection, corrected
from service.measure.cadence import ReflectionWatch
from service.measure.diameter import MeasureParams, measure_frame
from service.measure.fuse import fuse
from service.measure.geometry import geometry_of
from service.measure.result import Measurement, Method
from service.measure.thermal import diameter_at_reference
from service.measure.turning import TurningFrames, measure_turning


class ImageError(ValueError):
    """An image file that cannot be measured at all (unreadable, or of the wrong size)."""


class CorrectionError(ValueError):
    """A master correction file that cannot be used."""


def load_correction(path: str | Path) -> DiameterCorrection:
    """The diameter correction written by ``shaftgauge calibrate master --output FILE``.

    Raises
    ------
    CorrectionError
        Naming what is wrong: a missing or unreadable file, not JSON, a missing or
        non-numeric ``offset_mm`` or ``scale``, or a scale more than 1 % from 1.
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as err:
        raise CorrectionError(f"{p}: cannot read it ({err.strerror})") from None
    except json.JSONDecodeError as err:
        raise CorrectionError(f"{p}: not JSON ({err.msg} at line {err.lineno})") from None
    if not isinstance(doc, dict):
        raise CorrectionError(f"{p}: expected the JSON object `calibrate master` writes")
    values = {}
    for key in ("offset_mm", "scale"):
        v = doc.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise CorrectionError(f"{p}: {key} must be a finite number, got {v!r} (the "
                                  "output of `shaftgauge calibrate master --output FILE`)")
        values[key] = float(v)
    if not 0.99 < values["scale"] < 1.01:
        raise CorrectionError(f"{p}: scale {values['scale']} is more than 1% from 1")
    if abs(values["offset_mm"]) > 1.0:
        raise CorrectionError(f"{p}: offset_mm {values['offset_mm']} is more than 1 mm")
    return DiameterCorrection(values["offset_mm"], values["scale"],
                              float(doc.get("created", 0.0) or 0.0))


def read_image(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit image file (PNG, JPEG, TIFF, ...) as it is: grey (H, W) or colour
    (H, W, 3), OpenCV's BGR order (an alpha channel is dropped).

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
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"{p}: pixel type {image.dtype} is not 8- or 16-bit")
    return np.ascontiguousarray(image)


COLOUR_TO_GREY = "colour converted to grey (0.299 R + 0.587 G + 0.114 B, OpenCV's weights)"


def read_grey_image(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit image file as a single-channel array (colour is converted to
    grey, ``COLOUR_TO_GREY``).

    Raises
    ------
    ImageError
        When the file is missing or not an image OpenCV can decode.
    """
    image = read_image(path)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


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
    params: MeasureParams | None = None, correction: DiameterCorrection | None = None,
    fps: float = 10.0, reflection_check_hz: float = 5.0,
) -> Iterator[tuple[str, Measurement]]:
    """Check every file first (so that a bad one stops the run before any output), then yield
    ``(path, measurement)`` per image, in order, with the master ``correction`` applied as the
    service applies it.

    Images are looked at for a reflection beside the stripe as the service looks at its
    frames (``ReflectionWatch``): ``reflection_check_hz`` times a second of images taken at
    ``fps`` (``inf``: every image), every image while one is seen, every lopsided stripe.

    Raises
    ------
    ImageError
        On the first unreadable or wrongly sized image, before anything is yielded.
    """
    for p in paths:
        check_image_file(p, calibration)
    geometry = geometry_of(calibration)
    params = params or MeasureParams()
    variants = {check: replace(params, reflection_check=check) for check in (False, True)}
    watch = ReflectionWatch(reflection_check_hz)
    for i, p in enumerate(paths):
        checked = watch.due(i / fps)
        m = measure_frame(read_grey_image(p), geometry, method, variants[checked])
        watch.seen(checked, m.reflection_px is not None)
        yield p, corrected(m, correction)


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


def parse_spindle_angles(text: str, count: int) -> list[float]:
    """``--spindle-deg A1,A2,...``: one finite angle (degrees) per image.

    Raises
    ------
    ValueError
        Naming what is wrong: a value that is not a number, or as many angles as images not
        given.
    """
    out = []
    for k, part in enumerate(text.split(","), 1):
        try:
            value = float(part)
        except ValueError:
            raise ValueError(f"--spindle-deg: angle {k} ({part.strip()!r}) is not a number "
                             "of degrees") from None
        if not math.isfinite(value):
            raise ValueError(f"--spindle-deg: angle {k} is {value}, need a finite angle")
        out.append(value)
    if len(out) != count:
        raise ValueError(f"--spindle-deg gives {len(out)} angles for {count} images: one "
                         "each, in the images' order")
    return out


def measure_turning_files(paths: list[str], calibration: Calibration,
                          spindle_deg: list[float] | None,
                          params: MeasureParams | None = None, form: bool = False,
                          upr: int = 50) -> TurningFrames:
    """``measure_turning`` over image files (each checked first, as ``measure_images``)."""
    for p in paths:
        check_image_file(p, calibration)
    return measure_turning([read_grey_image(p) for p in paths], geometry_of(calibration),
                           spindle_deg, params, form, upr)


def form_record(paths: list[str], turning: TurningFrames) -> dict[str, Any]:
    """The one JSON record of ``measure --form``: the diameter of the frames measured about
    the surface's own centre, the run-out and the roundness, each with its uncertainty."""

    def rnd(x: float | None, nd: int = 7) -> float | None:
        return None if x is None or not math.isfinite(x) else round(x, nd)

    r, f, shape = turning.runout, turning.fused, turning.roundness
    reasons = [x.reason for x in (r, shape) if x is not None and not x.ok]
    record: dict[str, Any] = {
        "images": len(paths), "status": f.status.value if r.ok else "uncertain",
        "diameter_mm": rnd(f.diameter_mm, 6), "diameter_uncertainty_mm": rnd(f.uncertainty_mm),
        "n_used": f.n_used,
        "eccentricity_mm": rnd(r.eccentricity_mm),
        "eccentricity_uncertainty_mm": rnd(r.eccentricity_uncertainty_mm),
        "eccentricity_deg": rnd(r.eccentricity_deg, 2),
        "eccentricity_deg_uncertainty": rnd(r.eccentricity_deg_uncertainty, 2),
        "tir_mm": rnd(r.tir_mm), "tir_uncertainty_mm": rnd(r.tir_uncertainty_mm),
        "axis_check_shift_mm": None if turning.axis_check is None or not
        turning.axis_check.ok else [rnd(v) for v in turning.axis_check.axis_shift_mm],
        "ront_mm": None, "ront_uncertainty_mm": None, "harmonics": [],
        "dominant_lobes": None, "odd_lobing": None,
        "spindle_angle_source": "given (--spindle-deg)" if turning.spindle is None else
        "estimated from the frames" if turning.spindle.ok else "none (not told by the frames)",
        "spindle_deg_per_frame": None if turning.spindle is None or not turning.spindle.ok
        else rnd(turning.spindle.deg_per_frame, 4),
        "reason": "; ".join(reasons) or f.reason,
    }
    if shape is not None and shape.ok:
        record.update(
            ront_mm=rnd(shape.ront_mm), ront_uncertainty_mm=rnd(shape.ront_uncertainty_mm),
            harmonics=[{"order": h.order, "amplitude_mm": rnd(h.amplitude_mm),
                        "phase_deg": rnd(h.phase_deg, 2),
                        "amplitude_uncertainty_mm": rnd(h.amplitude_uncertainty_mm)}
                       for h in shape.harmonics],
            dominant_lobes=shape.dominant_order or None, odd_lobing=shape.odd_lobing)
    return record
