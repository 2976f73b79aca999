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


@dataclass
class QualityReport:
    """Figures of every step and the overall verdict."""

    verdict: Verdict = "good"
    reasons: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)

    def judge(self, value: float, good: float, marginal: float, what: str, advice: str,
              higher_is_better: bool = False) -> None:
        """Grade one figure against the limits of good and marginal."""
        v = -value if higher_is_better else value
        g, m = (-good, -marginal) if higher_is_better else (good, marginal)
        if not math.isfinite(v) or v > m:
            self._worse("refused", f"{what}: {advice}")
        elif v > g:
            self._worse("marginal", f"{what}: {advice}")

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
    r.judge(intr.rms_px, 0.3, 0.7, f"reprojection RMS {intr.rms_px:.2f} px",
            "refocus, light the board evenly, keep it still")
    r.judge(intr.worst_px, 1.5, 3.0, f"worst corner error {intr.worst_px:.2f} px",
            "drop blurred or moved images")
    r.judge(intr.coverage, 0.5, 0.3, f"the corners covered {intr.coverage:.0%} of the image",
            "hold the board near the image corners and edges too", higher_is_better=True)
    r.judge(len(intr.used), 10, 6, f"{len(intr.used)} images with the board found",
            "capture 10-20 views", higher_is_better=True)
    if plane is not None:
        if not plane:
            r.refuse(f"light plane: {plane.reason}")
        else:
            r.figures["light_plane"] = {"rms_mm": plane.rms_mm, "worst_mm": plane.worst_mm,
                                        "points": plane.points,
                                        "per_pose_points": plane.per_pose_points,
                                        "per_pose_rms_mm": plane.per_pose_rms_mm,
                                        "how": {str(k): v for k, v in plane.how.items()}}
            r.judge(plane.rms_mm, 0.03, 0.08, f"light-plane residual {plane.rms_mm * 1000:.0f}"
                    " um RMS", "check the laser line is sharp and the board flat")
            r.judge(len(plane.per_pose_points), 4, 3, f"{len(plane.per_pose_points)} poses "
                    "with the laser line", "add poses at other distances and tilts",
                    higher_is_better=True)
    if axis is not None:
        if not axis:
            r.refuse(f"spindle axis: {axis.reason}")
        else:
            r.figures["axis"] = {"rotation_span_deg": axis.rotation_span_deg,
                                 "plane_residual_mm": axis.plane_residual_mm,
                                 "poses": axis.poses}
            r.judge(axis.rotation_span_deg, 60, 30, f"the board turned through "
                    f"{axis.rotation_span_deg:.0f} degrees", "turn it through 60-90",
                    higher_is_better=True)
            r.judge(axis.plane_residual_mm, 0.02, 0.05, "axis-to-board-planes residual "
                    f"{axis.plane_residual_mm * 1000:.0f} um", "clamp the board firmly")
    if plane is not None and plane and axis is not None and axis:
        cos = abs(float(np.dot(plane.normal, axis.direction)))
        angle = math.degrees(math.asin(min(1.0, cos)))  # between the plane and the axis
        r.figures["plane_axis_angle_deg"] = angle
        r.judge(angle, 45, 15, f"the light plane meets the axis at {angle:.0f} degrees",
                "turn the laser so its sheet crosses the shaft more squarely",
                higher_is_better=True)
    return r
