"""The per-frame measurement's settings (``diameter.measure_frame``): in a module of their own
so that the steps below the fit (``sheet_correction``) read them without importing the fit."""

from __future__ import annotations

from dataclasses import dataclass, field

from service.measure.reflection import ReflectionParams
from service.measure.result import MAX_UNCERTAINTY_MM
from service.measure.stripe import StripeParams


@dataclass(frozen=True)
class MeasureParams:
    """Settings of the per-frame measurement.

    Attributes
    ----------
    stripe : StripeParams
        Stripe extractor settings.
    min_points : int
        Fewest stripe points for a measurement.
    min_arc_deg : float
        Shortest arc (degrees around the fitted centre) for a measurement.
    max_diameter_mm : float
        Larger fitted diameters are refused as a failed fit.
    max_rms_mm : float
        Points scattered more than this (RMS, mm) about the fit are not a shaft's section.
    max_view_angle_deg : float
        Points the camera sees at a more grazing angle (between the surface normal and the
        line of sight) are dropped before fitting: there the stripe is squeezed into a sliver
        and its centre leaves the light plane by tens of micrometres.
    free_fit : bool
        With ``axis``, also fit a free circle and report its centre and covariance (for the
        service's axis tracker); off where nothing tracks the axis.
    axis_sigma_mm : float
        Standard deviation of the spindle axis position as a prior on the section centre
        (method ``axis``), mm: 1 um is the axis as known after mastering; a bare axis
        calibration is good to tens of micrometres, and the service widens this accordingly.
    sheet_correction : bool
        With ``axis`` and ``geometric``, take out the radial error that the light sheet's
        thickness leaves in the stripe centres on a curved surface (``service.measure.sheet``)
        and fit again.
    sheet_sigma_mm : float or None
        The sheet's thickness (Gaussian sigma, mm) for that correction; None estimates it from
        the stripe's width in each frame.
    max_uncertainty_mm : float
        A diameter whose standard uncertainty exceeds this is refused (``uncertain``): three
        of them must stay within 20 um, the most a frame may be off. A free circle on a short
        arc trades centre against radius and is often this uncertain; ``axis`` is not.
    max_side_balance : float
        A stripe whose centres' profiles are this lopsided (the median of
        ``StripePoints.balance``; about 0.02 alone, 0.03-0.04 at low contrast or with a thick
        sheet), beyond what the image noise makes of it, has a second line beside it, a
        reflection, which pulls the centres toward it by up to tenths of a pixel: the
        reflection is modelled and its pull taken out (``reflection``), or, when no
        reflection explains the profiles, the frame is refused as ``uncertain``.
    reflection : ReflectionParams
        Settings of that model (``service.measure.reflection``).
    reflection_check : bool
        Look for a reflection on every frame, not only on a lopsided one: a faint
        reflection close to the stripe (a tenth of its height, 2 px off) leaves the profile
        within the lopsidedness limit but pulls the centres by 10-20 um of diameter. It costs
        about 1.5 tracked frames more (a linear screen clears a frame without one; the fit
        runs where it does not); the service asks for it a few times a second and on every
        frame while a reflection is there (``service.runtime.pipeline``).
    reflection_shift_rel : float
        Relative standard uncertainty of the modelled pull: the diameter's uncertainty takes
        in how far it moves when the pull is this share larger.
    consensus_mm : float
        With ``axis`` and ``geometric``, section points farther than this from the circle that
        most points share (plus three sigmas of the axis prior, with ``axis``) are not the
        shaft's (``service.measure.consensus``): a ghost, an edge, a glint.
    consensus_sigmas : float
        With ``axis``, the ring widens to this many robust sigmas of its points' own radial
        scatter when that is wider (a thick sheet under speckle scatters them by tens of
        micrometres); not for a lopsided stripe, whose scatter is a second line's pull.
    arc_weighting : bool
        Weigh the points of ``axis`` and ``geometric`` fits by the inverse of their scatter's
        smooth profile along the arc, estimated from the first fit's residuals
        (``fit.arc_variance``), and fit again.
    """

    stripe: StripeParams = field(default_factory=StripeParams)
    min_points: int = 20
    min_arc_deg: float = 30.0
    max_diameter_mm: float = 1000.0
    max_rms_mm: float = 0.05
    max_view_angle_deg: float = 75.0
    axis_sigma_mm: float = 0.001
    free_fit: bool = False
    sheet_correction: bool = True
    sheet_sigma_mm: float | None = None
    max_uncertainty_mm: float = MAX_UNCERTAINTY_MM
    max_side_balance: float = 0.05
    reflection: ReflectionParams = field(default_factory=ReflectionParams)
    reflection_check: bool = True
    reflection_shift_rel: float = 0.1
    consensus_mm: float = 0.05
    consensus_sigmas: float = 4.0
    arc_weighting: bool = True
