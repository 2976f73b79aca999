"""Result types of the measurement core: a status, never an exception, for a failed frame."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


class Status(enum.StrEnum):
    """Outcome of measuring one frame (or one fused window)."""

    OK = "ok"
    NO_STRIPE = "no_stripe"
    TOO_FEW_POINTS = "too_few_points"
    ARC_TOO_SHORT = "arc_too_short"
    FIT_FAILED = "fit_failed"
    UNCERTAIN = "uncertain"
    BAD_IMAGE = "bad_image"
    NOT_CONCENTRIC = "not_concentric"
    """The surface is not concentric with the spindle axis (``form.ConcentricityWatch``):
    the ``axis`` method's diameter cannot be trusted on it."""


class Method(enum.StrEnum):
    """Fitting method; the first three are the reference paper's comparison."""

    ELLIPSE = "ellipse"
    CIRCLE = "circle"
    PAPER = "paper"
    GEOMETRIC = "geometric"
    AXIS = "axis"


DEFAULT_METHOD = Method.AXIS
"""The most accurate method (see the manual's accuracy table)."""

MAX_UNCERTAINTY_MM = 0.0065
"""A diameter more uncertain than this (standard uncertainty) is refused as ``uncertain``
(``MeasureParams.max_uncertainty_mm``): three of them must stay within 20 um."""


@dataclass(frozen=True)
class Measurement:
    """One diameter measurement, or the reason there is none.

    Attributes
    ----------
    status : Status
        ``Status.OK`` when ``diameter_mm`` is a real measurement.
    method : Method
        The fit that produced it.
    diameter_mm : float or None
        Shaft diameter in mm; None unless ``status`` is OK.
    center_mm : tuple of float or None
        Fitted section centre in the section basis (mm).
    n_points : int
        Stripe points that entered the fit (after rejection).
    arc_deg : float
        Angular span of those points around the centre, degrees (0 when unknown).
    rms_residual_mm : float or None
        RMS distance of the points to the fitted curve, mm.
    reason : str
        Human-readable explanation, empty when OK.
    uncertainty_mm : float or None
        Standard uncertainty of ``diameter_mm``, mm.
    note : str
        Something worth knowing about a good result (e.g. a fallback), empty otherwise.
    free_center_mm, free_center_cov : tuple or None
        For ``axis``: the free (geometric) fit's centre and its covariance ``(xx, xy, yy)`` in
        mm^2, for the axis tracker.
    points_px : ndarray, shape (N, 2)
        Sub-pixel stripe centres (x, y) in pixels that were used, for display.
    section_mm : ndarray, shape (N, 2)
        The same points in the section as the fit took them (mm; the light sheet's bias taken
        out): for the form over many frames (``turning``).
    reflection_px : tuple of float or None
        The image offset (dx, dy, px) of a reflection beside the stripe whose pull was
        modelled and taken out (``service.measure.reflection``), None when there was none.
    filter_px : float or None
        The derivative filters' scale the stripe was found with, px (wider than the default
        for a wide stripe): where the next frame's extraction starts.
    spindle_deg : float or None
        The frame's spindle angle, when known.
    about_runout : bool
        Measured about the surface's own centre at that angle (its run-out known), not the
        spindle axis.
    """

    status: Status
    method: Method
    diameter_mm: float | None = None
    center_mm: tuple[float, float] | None = None
    n_points: int = 0
    arc_deg: float = 0.0
    rms_residual_mm: float | None = None
    reason: str = ""
    uncertainty_mm: float | None = None
    note: str = ""
    free_center_mm: tuple[float, float] | None = None
    free_center_cov: tuple[float, float, float] | None = None
    points_px: np.ndarray = field(default_factory=lambda: np.empty((0, 2)), repr=False)
    section_mm: np.ndarray = field(default_factory=lambda: np.empty((0, 2)), repr=False)
    reflection_px: tuple[float, float] | None = None
    filter_px: float | None = None
    spindle_deg: float | None = None
    about_runout: bool = False

    def __bool__(self) -> bool:
        return self.status is Status.OK

    @classmethod
    def failed(cls, status: Status, method: Method, reason: str, **kw: Any) -> Measurement:
        """A measurement that carries only a failure status and its reason."""
        return cls(status=status, method=method, reason=reason, **kw)

    @property
    def stripe_px(self) -> np.ndarray | None:
        """Where the stripe is, for the next frame to look near (and the camera's region to
        follow): the centres of a fit that was made (``ok``, or refused only as
        ``uncertain``), None when there was none."""
        return self.points_px if self.status in (Status.OK, Status.UNCERTAIN) else None

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (no arrays); non-finite numbers become None."""

        def num(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "status": self.status.value,
            "method": self.method.value,
            "diameter_mm": num(self.diameter_mm) if self.status is Status.OK else None,
            "center_mm": None if self.center_mm is None else [num(c) for c in self.center_mm],
            "n_points": int(self.n_points),
            "arc_deg": num(self.arc_deg),
            "rms_residual_mm": num(self.rms_residual_mm),
            "uncertainty_mm": num(self.uncertainty_mm) if self.status is Status.OK else None,
            "reason": self.reason,
            "note": self.note,
        }
