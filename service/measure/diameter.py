"""One frame to one diameter: stripe -> points -> section -> fit, with a status for every way
it can fail (no stripe, too few points, arc too short, fit failed, wrong image)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from service.measure import circle_kernels, consensus
from service.measure import fit as fits
from service.measure.geometry import RigGeometry
from service.measure.params import MeasureParams
from service.measure.reflection import Reflection, fit_reflection
from service.measure.result import DEFAULT_METHOD, Measurement, Method, Status
from service.measure.robust import median
from service.measure.section import (
    SectionPoints,
    light_plane_basis,
    light_plane_coordinates,
    orthonormal_basis,
    project_to_section,
)
from service.measure.sheet_correction import correct_sheet_bias
from service.measure.shoulder import MIN_SHARE, second_diameter
from service.measure.stripe import (
    StripePoints,
    extract_stripe,
    matched_scale,
    with_scale,
)
from service.measure.triangulate import triangulate


def check_image(image: np.ndarray, geometry: RigGeometry,
                origin: tuple[int, int] | None = None) -> str:
    """Why ``image`` cannot be measured with ``geometry`` ('' when it can): a whole frame of
    the calibrated sensor, or with ``origin`` (x, y, px) a region of it (the camera's region
    of interest) that lies within the sensor."""
    if not isinstance(image, np.ndarray) or image.ndim != 2:
        shape = getattr(image, "shape", None)
        return f"expected a single-channel (grey) image, got shape {shape}"
    w, h = geometry.image_size
    if origin is None and image.shape != (h, w):
        return (f"image is {image.shape[1]}x{image.shape[0]} px but the calibration is for "
                f"{w}x{h} px")
    if origin is not None:
        x0, y0 = origin
        if x0 < 0 or y0 < 0 or x0 + image.shape[1] > w or y0 + image.shape[0] > h:
            return (f"region {image.shape[1]}x{image.shape[0]} px at ({x0}, {y0}) is not "
                    f"within the calibrated {w}x{h} px sensor")
    if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
        return f"image has unsupported pixel type {image.dtype}"
    return ""


def section_points(stripe: StripePoints, geometry: RigGeometry) -> SectionPoints:
    """Triangulate stripe centres on the light plane and project them onto the section."""
    pts3 = triangulate(stripe.xy, geometry.camera_matrix, geometry.dist_coeffs,
                       geometry.plane_normal, geometry.plane_d)
    finite = np.isfinite(pts3).all(axis=1)
    stripe, pts3 = stripe.subset(finite), pts3[finite]
    return SectionPoints(stripe, pts3, project_to_section(pts3, geometry.axis_direction))


def view_angles_deg(points: SectionPoints, center: np.ndarray) -> np.ndarray:
    """Angle between the surface normal and the line of sight at each point, degrees.

    The normal of a cylinder is radial: in the section it points from ``center`` to the point,
    in 3-D ``(dx e1 + dy e2) / |d|``; the camera sits at the origin of the camera frame, so the
    line of sight is ``-X / |X|``, and ``X . e1``, ``X . e2`` are the point's own section
    coordinates: the cosine is ``-(d . section) / (|d| |X|)``.
    """
    cos = circle_kernels.view_cosines(np.ascontiguousarray(points.section, np.float64),
                                      np.ascontiguousarray(points.points3d, np.float64),
                                      float(center[0]), float(center[1]))
    return np.degrees(np.arccos(cos))


def drop_grazing(points: SectionPoints, geometry: RigGeometry, params: MeasureParams,
                 center: np.ndarray | None = None) -> SectionPoints:
    """Drop points seen at a grazing angle, judged about ``center`` (section mm: the axis,
    when it is known) or else about a preliminary (Hyper) circle's centre."""
    if len(points.section) == 0:
        return points
    if center is None:
        prelim = fits.fit_hyper(points.section, uncertainty=False)
        if not prelim:
            return points
        center = prelim.center
    keep = view_angles_deg(points, center) <= params.max_view_angle_deg
    if keep.mean() < 0.5:
        # A preliminary circle that calls most points grazing is itself wrong (a short or
        # broken stripe): leave the judgement to the fit and its checks.
        return points
    return points.subset(keep)


def on_the_shaft(points: SectionPoints, params: MeasureParams,
                 known: tuple[np.ndarray, float] | None) -> SectionPoints:
    """The points of the circle that most points share, by whole chains: about the ``known``
    centre (section mm, its sigma mm) when there is one (a ring as wide as the stripe's own
    scatter, unless the stripe is lopsided: ``consensus.ring_consensus``), else by RANSAC
    (``service.measure.consensus``) unless one algebraic circle through all of them already
    holds nine in ten within ``consensus_mm`` (a clean frame: nothing to choose between)."""
    keep = _on_the_shaft_mask(points, params, known)
    return points if keep.all() else points.subset(keep)


def _on_the_shaft_mask(points: SectionPoints, params: MeasureParams,
                       known: tuple[np.ndarray, float] | None) -> np.ndarray:
    """Which of the points ``on_the_shaft`` keeps."""
    if len(points.section) < 3:
        return np.ones(len(points.section), bool)
    if known is not None:
        window = params.consensus_mm + 3.0 * known[1]
        # A lopsided stripe's scatter is a second line's pull, not the stripe's own: the ring
        # does not widen to it.
        lopsided = side_balance(points) > side_balance_limit(points, params)
        inside = consensus.ring_consensus(points.section, known[0], window,
                                          0.0 if lopsided else params.consensus_sigmas)
    else:
        pre = fits.fit_hyper(points.section, uncertainty=False)
        inside = np.zeros(len(points.section), bool)
        if pre:
            dist = np.hypot(*(points.section - pre.center).T) - pre.radius
            inside = np.abs(dist) <= params.consensus_mm
        if not inside.mean() >= 0.9:
            inside = consensus.circle_consensus(points.section, params.consensus_mm,
                                                params.max_diameter_mm / 2.0)
    return consensus.by_chain(inside, points.stripe.chain)


def axis_center(geometry: RigGeometry) -> np.ndarray | None:
    """The calibrated spindle axis in section coordinates, mm (None when not calibrated)."""
    if geometry.axis_point is None:
        return None
    return project_to_section(geometry.axis_point[None, :], geometry.axis_direction)[0]


def _fit_circle(sec: np.ndarray, method: Method,
                center_prior: tuple[np.ndarray, float] | None, weights: np.ndarray,
                start: fits.CircleFit | None = None, uncertainty: bool = True
                ) -> fits.CircleFit:
    """The circle of ``axis`` (with the centre prior) or ``geometric``, from ``start`` when
    given (a fit of the same points before a sub-micrometre correction). Outliers are judged
    again: corrected, a point at the stripe's faded end may rejoin or leave. Without
    ``uncertainty`` the fit only starts another and has no ``radius_std``."""
    if method is Method.AXIS and center_prior is not None:
        return fits.fit_axis_prior(sec, center_prior[0], center_prior[1], weights=weights,
                                   start=start, uncertainty=uncertainty)
    return fits.fit_geometric(sec, weights=weights, start=start, uncertainty=uncertainty)


def fit_section(
    points: SectionPoints, geometry: RigGeometry, method: Method, params: MeasureParams,
    center_prior: tuple[np.ndarray, float] | None = None,
) -> Measurement:
    """Fit the section points by ``method`` and judge the result.

    ``center_prior`` (centre in section mm, sigma mm) overrides the calibrated axis for
    ``axis`` (a tracked centre).
    """
    sec = points.section
    note = ""
    free_extra: dict = {}
    if method is Method.AXIS:
        if center_prior is None:
            c0 = axis_center(geometry)
            center_prior = None if c0 is None else (c0, params.axis_sigma_mm)
        if center_prior is None:
            method = Method.GEOMETRIC
            note = "the calibration has no axis point: measured with geometric instead of axis"
    if method is Method.ELLIPSE:
        plane_xy = light_plane_coordinates(points.points3d, geometry.plane_normal,
                                           geometry.axis_direction)
        ell = fits.fit_ellipse(plane_xy)
        if not ell:
            return Measurement.failed(Status.FIT_FAILED, method, ell.reason,
                                      n_points=len(sec), points_px=points.stripe.xy)
        # The ellipse centre lies on the light plane (and on the axis): show it on the section.
        u1, u2 = light_plane_basis(geometry.plane_normal, geometry.axis_direction)
        c3 = ell.center[0] * u1 + ell.center[1] * u2 + geometry.plane_d * geometry.plane_normal
        e1, e2 = orthonormal_basis(geometry.axis_direction)
        center = np.array([c3 @ e1, c3 @ e2])
        diameter, rms, used = ell.minor_diameter, ell.rms, np.ones(len(sec), bool)
        std = 2.0 * ell.minor_std
    else:
        weights = fits.point_weights(points.stripe.strength, len(sec))
        if method in (Method.AXIS, Method.GEOMETRIC):
            # A first fit that another follows needs no uncertainty of its own (only if the
            # second fails, below).
            refit = params.arc_weighting or params.sheet_correction
            first = circ = _fit_circle(sec, method, center_prior, weights,
                                       uncertainty=not refit)
            first_weights = weights
            if circ and params.arc_weighting:
                # Weigh each point by how much the points about it scatter (fits.arc_variance).
                res = (np.hypot(*(sec - circ.center).T) - circ.radius) * np.sqrt(weights)
                weights = weights / fits.arc_variance(sec, circ.center, circ.inliers, res)
            if circ and params.sheet_correction:
                # Take out the sheet's error modelled on this fit, and fit again from it.
                moved = correct_sheet_bias(points, circ.center, circ.radius, geometry, params)
                again = _fit_circle(moved, method, center_prior, weights, start=circ)
                if again:
                    sec, circ = moved, again
            elif circ and refit:
                circ = _fit_circle(sec, method, center_prior, weights, start=circ)
            if refit and first and (circ is first or not circ):
                # The second fit failed: the first stands, with its uncertainty.
                axis = method is Method.AXIS and center_prior is not None
                circ = fits.with_radius_std(first, sec, first_weights,
                                            center_prior[1] if axis else None)
        else:  # the paper's algorithms, as the paper has them: unweighted
            circ = (fits.fit_kasa if method is Method.CIRCLE else fits.fit_paper)(sec)
        # The free circle starts from this frame's own (a few micrometres off it, on the same
        # points): the same centre as from scratch in a quarter of the time, so that the
        # service can afford one every frame for the run-out.
        free = fits.fit_geometric(sec, weights=weights, start=circ if circ else None,
                                  uncertainty=False) \
            if method is Method.AXIS and params.free_fit else None
        if free:  # for the axis tracker
            cov = fits.circle_covariance(sec, free.center, free.radius, weights=weights,
                                         inliers=free.inliers)
            free_extra = {"free_center_mm": (float(free.center[0]), float(free.center[1])),
                          "free_center_cov": (float(cov[0, 0]), float(cov[0, 1]),
                                              float(cov[1, 1]))}
        if not circ:
            return Measurement.failed(Status.FIT_FAILED, method, circ.reason,
                                      n_points=len(sec), points_px=points.stripe.xy)
        center, diameter, rms, used = circ.center, circ.diameter, circ.rms, circ.inliers
        std = 2.0 * circ.radius_std
    n_used = int(used.sum())
    arc = fits.arc_span_deg(sec[used], center)
    common = dict(center_mm=(float(center[0]), float(center[1])), n_points=n_used, arc_deg=arc,
                  rms_residual_mm=float(rms), points_px=points.stripe.xy[used],
                  section_mm=sec[used], filter_px=points.stripe.filter_px,
                  uncertainty_mm=float(std) if np.isfinite(std) else None, note=note,
                  **free_extra)
    if n_used < params.min_points:
        return Measurement.failed(Status.TOO_FEW_POINTS, method,
                                  f"{n_used} points after outlier rejection, need "
                                  f"{params.min_points}", **common)
    if not arc >= params.min_arc_deg:
        return Measurement.failed(Status.ARC_TOO_SHORT, method,
                                  f"stripe covers {arc:.1f} degrees of the section, need "
                                  f"{params.min_arc_deg:.0f}", **common)
    if not (np.isfinite(diameter) and 0 < diameter <= params.max_diameter_mm):
        return Measurement.failed(Status.FIT_FAILED, method,
                                  f"fitted diameter {diameter:.4g} mm is implausible", **common)
    if not rms <= params.max_rms_mm:
        return Measurement.failed(Status.FIT_FAILED, method,
                                  f"points scatter {rms * 1000:.0f} um RMS about the fit (limit "
                                  f"{params.max_rms_mm * 1000:.0f} um): not a clean section",
                                  **common)
    if not (np.isfinite(std) and std <= params.max_uncertainty_mm):
        return Measurement.failed(Status.UNCERTAIN, method,
                                  f"diameter uncertain by {std * 1000:.1f} um (limit "
                                  f"{params.max_uncertainty_mm * 1000:.1f} um): a short arc or "
                                  f"scattered points", **common)
    return Measurement(status=Status.OK, method=method, diameter_mm=float(diameter), **common)


def measure_frame(
    image: np.ndarray, geometry: RigGeometry, method: Method = DEFAULT_METHOD,
    params: MeasureParams | None = None,
    center_prior: tuple[np.ndarray, float] | None = None,
    near: np.ndarray | None = None,
    origin: tuple[int, int] | None = None,
    scale_px: float | None = None,
) -> Measurement:
    """Measure the shaft diameter in one stripe image.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey stripe image (uint8, uint16 or float) of the size the calibration is for.
    geometry : RigGeometry
        Calibration.
    method : Method
        Fitting method.
    params : MeasureParams, optional
        Settings.
    center_prior : (ndarray, float), optional
        Section centre (mm) and its standard deviation (mm) for ``axis``, replacing the
        calibrated axis (the service passes its tracked centre).
    near : ndarray, shape (N, 2), optional
        The previous frame's stripe centres, px (its ``points_px``): the stripe is looked for
        near them first (``extract_stripe``).
    origin : (int, int), optional
        Where ``image`` lies on the calibrated sensor (x, y of its top-left pixel, px) when
        it is a region of it (the camera's region of interest); every position in and out
        (``near``, ``points_px``) is in the whole sensor's pixels.
    scale_px : float, optional
        The derivative filters' scale the previous frame's stripe was found with (its
        ``filter_px``): a wide stripe is extracted once, at that scale, while its width still
        suits it within a quarter pixel (the scale's rounding) and it is not lopsided
        there; otherwise, and on a frame checked for a reflection, the frame is measured from
        the default scale as without it.

    Returns
    -------
    Measurement
        ``status`` OK with ``diameter_mm`` in mm, or a failure status with its reason; this
        function does not raise for bad frames.
    """
    params = params or MeasureParams()
    method = Method(method)
    problem = check_image(image, geometry, origin)
    if problem:
        return Measurement.failed(Status.BAD_IMAGE, method, problem)
    shift = np.zeros(2) if origin is None else np.asarray(origin, np.float64)
    hinted = scale_px is not None and scale_px > params.stripe.sigma_px \
        and not params.reflection_check
    stripe_params = with_scale(params.stripe, float(scale_px)) if hinted else params.stripe
    stripe = extract_stripe(image, stripe_params, None if near is None else near - shift)
    if hinted and not _still_suits(stripe, float(scale_px), params):
        return measure_frame(image, geometry, method, params, center_prior, near, origin)
    if not stripe:
        return Measurement.failed(Status.NO_STRIPE, method, stripe.reason or "no stripe found")
    if origin is not None:
        stripe = replace(stripe, xy=stripe.xy + shift)
    # With ``axis`` the section's centre is known beforehand: the shaft's circle is sought
    # and grazing judged about it.
    known = None
    if method is Method.AXIS:
        known = center_prior if center_prior is not None else (
            None if (c0 := axis_center(geometry)) is None else (c0, params.axis_sigma_mm))
    points, found, on_circle, shoulder = _shaft_points(stripe, geometry, method, params, known)
    if shoulder:
        return Measurement.failed(Status.UNCERTAIN, method, shoulder,
                                  n_points=len(points.section), points_px=points.stripe.xy)
    if len(points.section) < params.min_points:
        why = "" if on_circle == found else \
            f" ({on_circle} of the {found} found lie on one circle, the shaft's)"
        return Measurement.failed(
            Status.TOO_FEW_POINTS, method,
            f"{len(points.section)} stripe points, need {params.min_points}{why}",
            n_points=len(points.section), points_px=points.stripe.xy)
    lopsided, limit = side_balance(points), side_balance_limit(points, params)
    if hinted and lopsided > limit:  # a second line beside it: judged at the default scale
        return measure_frame(image, geometry, method, params, center_prior, near, origin)
    if not hinted and not lopsided > limit:
        points = _with_matched_filters(image, points, geometry, method, params, known, shift)
    if lopsided > limit or params.reflection_check:
        st = points.stripe
        found = fit_reflection(image, st.xy - shift, st.normal,
                               median(st.width_px), params.reflection,
                               lopsided=lopsided > limit)
        if found:
            return _without_reflection(found, points, geometry, method, params, known)
        if lopsided > limit:
            return Measurement.failed(
                Status.UNCERTAIN, method,
                f"the stripe's profile is lopsided (side balance {lopsided:.3f}, limit "
                f"{limit:.3f}): a second line runs beside it and pulls its centres, and "
                f"{found.reason}", n_points=len(points.section), points_px=st.xy)
    return fit_section(points, geometry, method, params, known)


def _still_suits(stripe: StripePoints, scale_px: float, params: MeasureParams) -> bool:
    """Whether a stripe found at the previous frame's wider scale still suits it: found, and
    its width asks for that scale within a quarter pixel, the scale's rounding (a stripe
    grown narrower or wider is measured afresh)."""
    if not stripe:
        return False
    want = matched_scale(stripe.width_px, params.stripe)
    return want > params.stripe.sigma_px and abs(want - scale_px) <= 0.25 + 1e-9


def _shaft_points(stripe: StripePoints, geometry: RigGeometry, method: Method,
                  params: MeasureParams, known: tuple[np.ndarray, float] | None
                  ) -> tuple[SectionPoints, int, int, str]:
    """The stripe's section points on the shaft's circle (``axis``, ``geometric``) and not
    grazing; with the number found, the number on the circle, and why the points set aside
    are a second diameter ("" when they are not: ``shoulder.second_diameter``)."""
    points = section_points(stripe, geometry)
    found = len(points.section)
    shoulder = ""
    if method in (Method.AXIS, Method.GEOMETRIC):
        keep = _on_the_shaft_mask(points, params, known)
        # A second diameter a step beyond the consensus's ring is set aside by it; only then
        # (a clean frame pays nothing), about the surface's own centre (the kept points'),
        # not the axis: a run-out would read as a step.
        aside = len(keep) - int(keep.sum())
        kept = fits.fit_hyper(points.section[keep], uncertainty=False) \
            if aside >= MIN_SHARE * len(keep) and keep.sum() >= 3 else None
        if kept:
            shoulder = second_diameter(points.section, kept.center)
        if not keep.all():
            points = points.subset(keep)
    on_circle = len(points.section)
    points = drop_grazing(points, geometry, params, None if known is None else known[0])
    return points, found, on_circle, shoulder


def _with_matched_filters(image: np.ndarray, points: SectionPoints, geometry: RigGeometry,
                          method: Method, params: MeasureParams,
                          known: tuple[np.ndarray, float] | None,
                          shift: np.ndarray) -> SectionPoints:
    """The stripe found again with derivative filters that suit its width, when it is wider
    than ``params.stripe.sigma_px`` suits (``stripe.matched_scale``: a thick light sheet).

    Speckle moves each centre by about the sheet's width squared times the speckle's slope
    across it; filters narrow against the stripe follow the grains inside its core and add
    to that (a sheet sigma of 0.10 mm: 4.1 um of scatter from frame to frame with 1.5 px
    filters, 3.3 um with the 2.5 px ones chosen). Only for a stripe that is not lopsided (the
    caller's check): wider filters would merge a second line beside it into the stripe. The
    first points stay when the second search finds fewer than half as many.
    """
    scale = matched_scale(points.stripe.width_px, params.stripe)
    if not scale > params.stripe.sigma_px:
        return points
    again = extract_stripe(image, with_scale(params.stripe, scale), points.stripe.xy - shift)
    if not again:
        return points
    wide = _shaft_points(replace(again, xy=again.xy + shift), geometry, method, params,
                         known)[0]
    if len(wide.section) < max(params.min_points, 0.5 * len(points.section)):
        return points
    return wide


def _without_reflection(found: Reflection, points: SectionPoints, geometry: RigGeometry,
                        method: Method, params: MeasureParams,
                        known: tuple[np.ndarray, float] | None) -> Measurement:
    """The fit with the stripe's centres moved back by a reflection's modelled pull.

    The correction's own uncertainty is added to the diameter's: the diameter moves by
    ``params.reflection_shift_rel`` of the correction's effect when the pull is that much
    larger, and that is taken as one standard uncertainty (both fits with the same weights:
    weights from each fit's own scatter along the arc would add their difference to it)."""
    st = points.stripe

    def moved(scale: float, p: MeasureParams = params) -> Measurement:
        xy = st.xy + (scale * found.shift_px)[:, None] * st.normal
        again = section_points(replace(st, xy=xy, balance=None), geometry)
        again = drop_grazing(again, geometry, p, None if known is None else known[0])
        return fit_section(again, geometry, method, p, known)

    m = moved(1.0)
    if m.status is not Status.OK:
        return replace(m, reflection_px=found.offset_px)
    same = replace(params, arc_weighting=False)
    ref = moved(1.0, same) if params.arc_weighting else m
    more = moved(1.0 + params.reflection_shift_rel, same)
    extra = abs(more.diameter_mm - ref.diameter_mm) \
        if more.status is Status.OK and ref.status is Status.OK else math.inf
    std = math.hypot(m.uncertainty_mm or 0.0, extra)
    if not std <= params.max_uncertainty_mm:
        return Measurement.failed(
            Status.UNCERTAIN, method,
            f"{found.describe()}, but the diameter is then uncertain by {std * 1000:.1f} um "
            f"(limit {params.max_uncertainty_mm * 1000:.1f} um)",
            n_points=m.n_points, points_px=m.points_px, reflection_px=found.offset_px)
    note = "; ".join(x for x in (m.note, found.describe()) if x)
    return replace(m, uncertainty_mm=std, note=note, reflection_px=found.offset_px)


def side_balance(points: SectionPoints) -> float:
    """The median lopsidedness of the points' profiles (0 when it was not measured)."""
    b = points.stripe.balance
    return median(np.abs(b)) if b is not None and len(b) else 0.0


def side_balance_limit(points: SectionPoints, params: MeasureParams) -> float:
    """``params.max_side_balance`` plus what the image noise alone makes of the median: each
    balance is a mean of four differences of two bilinear samples, about 0.7 noise / height
    in standard deviation, and the median of its magnitude 0.67 of that."""
    st = points.stripe
    height = median(st.peak) if st.peak is not None and len(st.peak) else 0.0
    return params.max_side_balance + (0.47 * st.noise / height if height > 0 else 0.0)
