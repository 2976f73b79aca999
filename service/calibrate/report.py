"""The quality report of a calibration: figures, and a verdict (good / marginal / refused)
with reasons that say what to do."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from service.calibrate.axis import AxisResult
from service.calibrate.intrinsics import IntrinsicsResult
from service.calibrate.plane import PlaneResult

Verdict = Literal["good", "marginal", "refused"]
_ORDER = {"good": 0, "marginal": 1, "refused": 2}


@dataclass(frozen=True)
class Limit:
    """One figure's limits: good within ``good``, marginal within ``marginal``, refused
    beyond (or the other way round where ``higher_is_better``), and what to do."""

    figure: str
    unit: str
    good: float
    marginal: float
    advice: str
    higher_is_better: bool = False


LIMITS = {
    "rms_px": Limit("reprojection RMS", "px", 0.3, 0.7,
                    "refocus, light the board evenly, keep it still"),
    "worst_px": Limit("worst corner error", "px", 1.5, 3.0, "drop blurred or moved images"),
    "coverage": Limit("share of the image the corners cover", "", 0.5, 0.3,
                      "hold the board near the image corners and edges too", True),
    "images": Limit("images with the board found", "", 10, 6, "capture 10-20 views", True),
    "plane_rms_mm": Limit("light-plane residual (RMS)", "mm", 0.03, 0.08,
                          "check the laser line is sharp and the board flat"),
    "plane_poses": Limit("poses with the laser line", "", 4, 3,
                         "add poses at other distances and tilts", True),
    "rotation_deg": Limit("the board's turn on the spindle", "degrees", 60, 30,
                          "turn it through 60-90", True),
    "axis_residual_mm": Limit("axis-to-board-planes residual", "mm", 0.02, 0.05,
                              "clamp the board firmly"),
    "plane_axis_deg": Limit("angle of the light plane to the axis", "degrees", 45, 15,
                            "turn the laser so its sheet crosses the shaft more squarely",
                            True),
}
"""Every figure the report grades (the technician's runbook prints them: ``markdown_table``)."""


def markdown_table() -> str:
    """The verdict's limits as a Markdown table (what ``docs/runbooks.md`` must contain)."""
    lines = ["| figure | good | marginal | refused | what to do |", "|---|---|---|---|---|"]
    for lim in LIMITS.values():
        unit = f" {lim.unit}" if lim.unit else ""
        better, worse = (">=", "<") if lim.higher_is_better else ("<=", ">")
        lines.append(f"| {lim.figure} | {better} {lim.good:g}{unit} | {better} "
                     f"{lim.marginal:g}{unit} | {worse} {lim.marginal:g}{unit} | "
                     f"{lim.advice} |")
    return "\n".join(lines) + "\n"


@dataclass
class QualityReport:
    """Figures of every step and the overall verdict."""

    verdict: Verdict = "good"
    reasons: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)

    def judge(self, value: float, limit: Limit, what: str) -> None:
        """Grade one figure against its limits of good and marginal."""
        v = -value if limit.higher_is_better else value
        g, m = (-limit.good, -limit.marginal) if limit.higher_is_better \
            else (limit.good, limit.marginal)
        if not math.isfinite(v) or v > m:
            self._worse("refused", f"{what}: {limit.advice}")
        elif v > g:
            self._worse("marginal", f"{what}: {limit.advice}")

    def _worse(self, verdict: Verdict, reason: str) -> None:
        self.reasons.append(f"{verdict}: {reason}")
        if _ORDER[verdict] > _ORDER[self.verdict]:
            self.verdict = verdict

    def refuse(self, reason: str) -> None:
        """A step failed outright."""
        self._worse("refused", reason)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"verdict": self.verdict, "reasons": self.reasons, "figures": self.figures}


def assess(intr: IntrinsicsResult, plane: PlaneResult | None = None,
           axis: AxisResult | None = None) -> QualityReport:
    """Grade a calibration's steps (the plane and axis when given)."""
    r = QualityReport()
    if not intr:
        r.refuse(f"intrinsics: {intr.reason}")
        return r
    r.figures["intrinsics"] = {
        "rms_px": intr.rms_px, "worst_px": intr.worst_px,
        "per_image_rms_px": intr.per_image_rms_px, "coverage": intr.coverage,
        "tilt_spread_deg": intr.tilt_spread_deg, "images_used": len(intr.used),
        "rejected": {str(k): v for k, v in intr.rejected.items()}}
    r.judge(intr.rms_px, LIMITS["rms_px"], f"reprojection RMS {intr.rms_px:.2f} px")
    r.judge(intr.worst_px, LIMITS["worst_px"], f"worst corner error {intr.worst_px:.2f} px")
    r.judge(intr.coverage, LIMITS["coverage"],
            f"the corners covered {intr.coverage:.0%} of the image")
    r.judge(len(intr.used), LIMITS["images"], f"{len(intr.used)} images with the board found")
    if plane is not None:
        # Refused or not: how many poses it rests on, and what became of the rest.
        r.figures["light_plane"] = {
            "rms_mm": _finite(plane.rms_mm), "worst_mm": _finite(plane.worst_mm),
            "points": plane.points, "poses_used": len(plane.per_pose_points),
            "normal_u_deg": _finite(plane.normal_u_deg), "axis_u_mm": _finite(plane.axis_u_mm),
            "per_pose_points": plane.per_pose_points,
            "per_pose_rms_mm": plane.per_pose_rms_mm,
            "how": {str(k): v for k, v in plane.how.items()},
            "rejected": {str(k): v for k, v in plane.rejected.items()}}
        if not plane:
            r.refuse(f"light plane: {plane.reason}")
        else:
            r.judge(plane.rms_mm, LIMITS["plane_rms_mm"],
                    f"light-plane residual {plane.rms_mm * 1000:.0f} um RMS")
            r.judge(len(plane.per_pose_points), LIMITS["plane_poses"],
                    f"{len(plane.per_pose_points)} poses with the laser line")
    if axis is not None:
        if not axis:
            r.refuse(f"spindle axis: {axis.reason}")
        else:
            r.figures["axis"] = {"rotation_span_deg": axis.rotation_span_deg,
                                 "plane_residual_mm": axis.plane_residual_mm,
                                 "poses": axis.poses}
            r.judge(axis.rotation_span_deg, LIMITS["rotation_deg"],
                    f"the board turned through {axis.rotation_span_deg:.0f} degrees")
            r.judge(axis.plane_residual_mm, LIMITS["axis_residual_mm"],
                    f"axis-to-board-planes residual {axis.plane_residual_mm * 1000:.0f} um")
    if plane is not None and plane and axis is not None and axis:
        cos = abs(float(np.dot(plane.normal, axis.direction)))
        angle = math.degrees(math.asin(min(1.0, cos)))  # between the plane and the axis
        r.figures["plane_axis_angle_deg"] = angle
        r.judge(angle, LIMITS["plane_axis_deg"],
                f"the light plane meets the axis at {angle:.0f} degrees")
    return r


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
