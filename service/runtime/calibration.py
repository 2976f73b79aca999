"""The calibration in force: the active calibration, its master correction, its axis and
run-out trackers and its master checks. One owner; the parts that need to know of a change
subscribe."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from calib_store.model import Calibration
from calib_store.store import CalibrationInfo, CalibrationStore
from service.calibrate.master import DiameterCorrection
from service.measure.axis_track import AxisTracker
from service.measure.diameter import axis_center
from service.measure.form import ConcentricityWatch
from service.measure.geometry import RigGeometry, geometry_of
from service.measure.runout_track import RunoutTracker, Settling, SpindleAngles
from service.runtime.listeners import Listeners

log = logging.getLogger("shaftgauge.calibration")


@dataclass(frozen=True)
class CalibrationInUse:
    """The calibration frames are measured with, and what belongs to it (its master
    correction, its axis tracker). A frame keeps the one it was taken under, even if another
    is activated while it is being measured."""

    info: CalibrationInfo
    calibration: Calibration
    geometry: RigGeometry
    correction: DiameterCorrection | None
    tracker: AxisTracker | None
    concentricity: ConcentricityWatch | None = None
    """Whether the surface is concentric with the spindle axis (from the free fits)."""
    runout: RunoutTracker | None = None
    """Where the surface's centre goes round the axis (when the spindle angle is known)."""
    settling: Settling = field(default_factory=Settling)
    """Whether the position was checked often enough that a frame may go without a free
    fit."""


@dataclass(frozen=True)
class MasterPolicy:
    """When master checks are due and what they must show (from ``[measurement]``)."""

    interval_h: float | None = None
    axis_sigma_mm: float = 0.001
    track_axis: bool = True


class CalibrationContext:
    """Owns the active calibration and everything that belongs to it.

    Parameters
    ----------
    store : CalibrationStore or None
        The calibration store (None: ``store_error`` says why it cannot be used).
    policy : MasterPolicy
        Master-check interval and axis tracking.
    store_error : str
        Why there is no store.
    spindle : SpindleAngles or None
        Each frame's spindle angle, when the camera is triggered by the spindle's encoder.
    """

    def __init__(self, store: CalibrationStore | None, policy: MasterPolicy,
                 store_error: str = "", spindle: SpindleAngles | None = None) -> None:
        self.store = store
        self.store_error = store_error
        self.policy = policy
        self.spindle = spindle
        self.in_use: CalibrationInUse | None = None
        self._last_master_check: dict[str, Any] | None = None
        self._changed: Listeners[int] = Listeners("calibration activated")

    def on_change(self, listener: Callable[[int], None]) -> None:
        """Call ``listener(calibration_id)`` whenever another calibration is activated."""
        self._changed.add(listener)

    def load_active(self) -> None:
        """Take the store's active calibration (a damaged one is reported, not raised)."""
        if self.store is None:
            return
        try:
            active = self.store.active()
        except Exception as err:  # a damaged stored document: report, keep running
            self.store_error = str(err)
            return
        if active is not None:
            self.set_calibration(*active)

    # ---- read-only views -----------------------------------------------------------------

    @property
    def calibration(self) -> tuple[CalibrationInfo, Calibration] | None:
        """The active calibration and its info."""
        u = self.in_use
        return None if u is None else (u.info, u.calibration)

    @property
    def calibration_id(self) -> int | None:
        """The active calibration's id."""
        return None if self.in_use is None else self.in_use.info.id

    @property
    def geometry(self) -> RigGeometry | None:
        """The active calibration's geometry."""
        return None if self.in_use is None else self.in_use.geometry

    @property
    def correction(self) -> DiameterCorrection | None:
        """The active calibration's master correction."""
        return None if self.in_use is None else self.in_use.correction

    @property
    def tracker(self) -> AxisTracker | None:
        """The active calibration's axis tracker."""
        return None if self.in_use is None else self.in_use.tracker

    # ---- changes -------------------------------------------------------------------------

    def set_calibration(self, info: CalibrationInfo, calibration: Calibration) -> None:
        """Measure with this calibration from the next frame on (its stored correction and
        master checks with it)."""
        geometry = geometry_of(calibration)
        corr = self.store.correction(info.id) if self.store is not None else None
        c0 = axis_center(geometry)
        tracker = (AxisTracker(c0, self.policy.axis_sigma_mm)
                   if c0 is not None and self.policy.track_axis else None)
        self.in_use = CalibrationInUse(info, calibration, geometry, None if corr is None else
                                       DiameterCorrection(corr["offset_mm"], corr["scale"],
                                                          corr["time"]), tracker,
                                       ConcentricityWatch() if tracker is not None else None,
                                       RunoutTracker() if tracker is not None and
                                       self.spindle is not None else None)
        self._last_master_check = (self.store.last_master_check(info.id)
                                   if self.store is not None else None)
        self._changed.tell(info.id)
        log.info("calibration %d in use (%s)", info.id, info.note or "no note")

    def set_correction(self, correction: DiameterCorrection) -> None:
        """The active calibration's master correction, from the next frame on."""
        if self.in_use is None:
            raise RuntimeError("no active calibration")
        self.in_use = replace(self.in_use, correction=correction)

    def record_master_check(self, certified_mm: float, measured_mm: float, error_mm: float,
                            limit_mm: float, passed: bool, by: str) -> None:
        """Store a master check of the active calibration and make it the one in force."""
        if self.store is None:
            raise RuntimeError(f"the calibration store cannot be used: {self.store_error}")
        cid = self.calibration_id
        self.store.add_master_check(cid, certified_mm, measured_mm, error_mm, limit_mm,
                                    passed, by)
        self._last_master_check = self.store.last_master_check(cid)

    def master_status(self) -> dict[str, Any]:
        """Correction in force, last master check, whether one is due, and whether offsets
        are blocked because of it."""
        last = self._last_master_check
        interval = self.policy.interval_h
        overdue = bool(interval is not None and (
            last is None or time.time() - last["time"] > interval * 3600.0))
        blocking = ""
        if last is not None and not last["passed"]:
            blocking = (f"the last master check failed ({last['error_mm'] * 1000:+.1f} um, "
                        f"limit {last['limit_mm'] * 1000:.1f} um)")
        elif overdue:
            blocking = f"a master check is overdue (every {interval:g} h)"
        corr = None if self.correction is None else asdict(self.correction)
        return {"correction": corr, "last_check": last, "overdue": overdue,
                "blocking": blocking or None}
