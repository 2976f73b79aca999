"""The ``shaftgauge calibrate ...`` steps on image files: each step writes a JSON file with its
result and figures; ``build`` assembles a calibration document and its quality report."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from calib_store.model import SCHEMA, Calibration, parse_calibration
from service.calibrate import board
from service.calibrate.axis import AxisResult, calibrate_axis
from service.calibrate.board import Board, board_of
from service.calibrate.intrinsics import IntrinsicsResult, calibrate_intrinsics
from service.calibrate.kept_detections import detect_kept
from service.calibrate.laser_line import grey_of
from service.calibrate.master import correction_from_masters
from service.calibrate.plane import PlaneResult, calibrate_plane, calibrate_plane_laser_on
from service.calibrate.report import QualityReport, assess
from service.measure.diameter import measure_frame
from service.measure.fuse import fuse
from service.measure.geometry import geometry_of
from service.measure.result import Method
from service.offline import COLOUR_TO_GREY, read_image


class StepError(ValueError):
    """A step that cannot run (bad input files); the message says what to do."""


def parse_board(text: str) -> Board:
    """A board's description (``service.calibrate.board``), e.g. ``11x8x8``,
    ``circles:7x7x37.5``; StepError naming what to write instead."""
    try:
        return board.parse_board(text)
    except ValueError as err:
        raise StepError(str(err)) from None


def _read_raw(paths: list[str]) -> list[np.ndarray]:
    try:
        return [read_image(p) for p in paths]
    except ValueError as err:
        raise StepError(str(err)) from None


def _read_all(paths: list[str]) -> list[np.ndarray]:
    """The images, grey (colour converted, ``COLOUR_TO_GREY``)."""
    return [grey_of(im) for im in _read_raw(paths)]


def how_read(images: list[np.ndarray]) -> dict[str, Any]:
    """What a step did with its images' colour, for its record."""
    colour = sum(1 for im in images if im.ndim == 3)
    return {"images": len(images), "colour_images": colour,
            "conversion": COLOUR_TO_GREY if colour else "grey as read"}


def _load(path: str, what: str) -> dict[str, Any]:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise StepError(f"{path}: cannot read the {what} step's result ({err})") from None


def write_json(path: str, data: dict[str, Any]) -> None:
    """Write a step's result as indented JSON."""
    Path(path).write_text(json.dumps(data, indent=2) + "\n")


def intrinsics_step(images: list[str], board: Board, detections: Path | None = None
                    ) -> tuple[dict[str, Any], IntrinsicsResult]:
    """Camera matrix and distortion from images of the target (the board's detections kept
    in ``detections``, ``kept_detections``)."""
    raw = _read_raw(images)
    imgs = [grey_of(im) for im in raw]
    detect_kept(imgs, board, detections)
    res = calibrate_intrinsics(imgs, board)
    report = assess(res)
    out: dict[str, Any] = {"step": "intrinsics", "ok": bool(res), "reason": res.reason,
                           "board": board.describe(), "detector": res.detector,
                           "read": how_read(raw),
                           "image_size": [int(imgs[0].shape[1]), int(imgs[0].shape[0])]
                           if imgs else None, "images_used": len(res.used),
                           "rejected": {str(k): v for k, v in res.rejected.items()},
                           "report": report.as_dict()}
    if res:
        out["camera_matrix"] = res.camera_matrix.tolist()
        out["dist_coeffs"] = [float(x) for x in res.dist_coeffs]
    return out, res


def _intrinsics(path: str) -> tuple[np.ndarray, np.ndarray, Board, dict[str, Any]]:
    d = _load(path, "intrinsics")
    if not d.get("ok"):
        raise StepError(f"{path}: the intrinsics step failed ({d.get('reason')}): redo it")
    board_ = replace(board_of(d["board"]), detector=d.get("detector", "sb"))
    return np.array(d["camera_matrix"]), np.array(d["dist_coeffs"]), board_, d


def plane_step(intrinsics: str, pairs: list[str], laser_on_only: list[str] | None = None,
               detections: Path | None = None) -> tuple[dict[str, Any], PlaneResult]:
    """The light plane from laser-off / laser-on image pairs, or from laser-on images alone
    (``laser_on_only``; their colour is used); the board's detections kept in
    ``detections``."""
    if len(pairs) % 2:
        raise StepError("--pairs takes images two by two: laser off, then laser on")
    if pairs and laser_on_only:
        raise StepError("give laser-off / laser-on pairs or laser-on images alone, not both")
    K, dist, board, _ = _intrinsics(intrinsics)
    if laser_on_only:
        raw = _read_raw(laser_on_only)
        detect_kept([grey_of(im) for im in raw], board, detections)
        res = calibrate_plane_laser_on(raw, board, K, dist)
        read = {**how_read(raw), "conversion": "laser-on images alone: the line looked for "
                "in the channel it stands out in (see how)"}
    else:
        raw = _read_raw(pairs)
        imgs = [grey_of(im) for im in raw]
        detect_kept(imgs[::2], board, detections)
        res = calibrate_plane(list(zip(imgs[::2], imgs[1::2], strict=True)), board, K, dist)
        read = how_read(raw)
    out: dict[str, Any] = {"step": "plane", "ok": bool(res), "reason": res.reason,
                           "read": read, "how": {str(k): v for k, v in res.how.items()},
                           "rms_mm": res.rms_mm, "poses_used": len(res.per_pose_points),
                           "per_pose_points": res.per_pose_points,
                           "per_pose_rms_mm": res.per_pose_rms_mm, "points": res.points,
                           "worst_mm": res.worst_mm, "normal_u_deg": res.normal_u_deg,
                           "axis_u_mm": res.axis_u_mm,
                           "rejected": {str(k): v for k, v in res.rejected.items()}}
    if res:
        out["normal"] = [float(x) for x in res.normal]
        out["d"] = float(res.d)
    return out, res


def axis_step(intrinsics: str, plane: str | None, images: list[str],
              detections: Path | None = None) -> tuple[dict[str, Any], AxisResult]:
    """The spindle axis from the board clamped between the centres at several rotations (the
    board's detections kept in ``detections``)."""
    K, dist, board, _ = _intrinsics(intrinsics)
    light = None
    if plane:
        p = _load(plane, "plane")
        if not p.get("ok"):
            raise StepError(f"{plane}: the plane step failed ({p.get('reason')}): redo it")
        light = (np.array(p["normal"]), float(p["d"]))
    imgs = _read_all(images)
    detect_kept(imgs, board, detections)
    res = calibrate_axis(imgs, board, K, dist, light)
    out: dict[str, Any] = {"step": "axis", "ok": bool(res), "reason": res.reason,
                           "rotation_span_deg": res.rotation_span_deg,
                           "plane_residual_mm": res.plane_residual_mm,
                           "rejected": {str(k): v for k, v in res.rejected.items()}}
    if res:
        out["direction"] = [float(x) for x in res.direction]
        out["point"] = [float(x) for x in res.point]
    return out, res


def build_step(intrinsics: str, plane: str, axis: str) -> tuple[Calibration | None,
                                                                 QualityReport]:
    """Assemble the calibration document and grade it; no document when refused."""
    K, dist, _, intr = _intrinsics(intrinsics)
    p, a = _load(plane, "plane"), _load(axis, "axis")
    fig = intr.get("report", {}).get("figures", {}).get("intrinsics", {})
    ires = IntrinsicsResult(K, dist, fig.get("rms_px", float("nan")),
                            fig.get("per_image_rms_px", []), fig.get("worst_px", float("nan")),
                            fig.get("coverage", 0.0), fig.get("tilt_spread_deg", 0.0),
                            list(range(fig.get("images_used", 0))))
    pres = PlaneResult(np.array(p["normal"]) if p.get("ok") else None, p.get("d", float("nan")),
                       p.get("rms_mm", float("nan")), p.get("worst_mm", float("nan")),
                       p.get("points", 0),
                       p.get("per_pose_points", []), p.get("per_pose_rms_mm", []),
                       rejected={int(k): v for k, v in p.get("rejected", {}).items()},
                       reason=p.get("reason", ""),
                       how={int(k): v for k, v in p.get("how", {}).items()},
                       normal_u_deg=p.get("normal_u_deg", float("nan")),
                       axis_u_mm=p.get("axis_u_mm", float("nan")))
    ares = AxisResult(np.array(a["direction"]) if a.get("ok") else None,
                      np.array(a["point"]) if a.get("ok") else None,
                      a.get("rotation_span_deg", 0.0), a.get("plane_residual_mm", float("nan")),
                      reason=a.get("reason", ""))
    report = assess(ires, pres, ares)
    report.figures["target"] = {"board": intr.get("board"), "detector": intr.get("detector")}
    report.figures["images"] = {"intrinsics": intr.get("read"), "light_plane": p.get("read")}
    if report.verdict == "refused":
        return None, report
    n = np.array(p["normal"]) / np.linalg.norm(p["normal"])
    direction = np.array(a["direction"]) / np.linalg.norm(a["direction"])
    doc = {"schema": SCHEMA, "units": "mm", "image_size": intr["image_size"],
           "camera_matrix": K.tolist(), "dist_coeffs": [float(x) for x in dist],
           "light_plane": {"normal": [float(x) for x in n], "d": float(p["d"])},
           "axis": {"direction": [float(x) for x in direction],
                    "point": [float(x) for x in a["point"]]}}
    return parse_calibration(doc), report


def master_step(calibration: Calibration, masters: list[tuple[float, list[str]]],
                method: Method = Method.AXIS) -> dict[str, Any]:
    """Measure each master's images (fused) and derive the diameter correction."""
    geometry = geometry_of(calibration)
    pairs, measured = [], []
    for certified, paths in masters:
        f = fuse([measure_frame(im, geometry, method) for im in _read_all(paths)])
        if not f:
            raise StepError(f"master {certified} mm: {f.reason}")
        pairs.append((certified, f.diameter_mm))
        measured.append({"certified_mm": certified, "measured_mm": f.diameter_mm,
                         "uncertainty_mm": f.uncertainty_mm, "frames": f.n_used})
    try:
        corr = correction_from_masters(pairs)
    except ValueError as err:
        raise StepError(str(err)) from None
    return {"step": "master", "offset_mm": corr.offset_mm, "scale": corr.scale,
            "created": corr.created, "masters": measured}
