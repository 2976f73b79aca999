"""Measurements kept in the store for the quality export: the latest record at most
``hz`` times a second, with the feature it was judged against and the surface's run-out and
roundness where they were known."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from calib_store.compensation_log import CompensationLog
from service.measurement_record import Feature, MeasurementRecord


class MeasurementArchive:
    """A feed listener that hands every ``1/hz`` seconds' record to the store's writer.

    Parameters
    ----------
    log : CompensationLog
        The store's writer (its own thread; nothing here waits on the disk).
    hz : float
        Records kept a second, at most (by the records' wall-clock times).
    feature : callable
        What a record was compared with (``feature(record)``: nominal and tolerance, kept
        with each row).
    form : callable, optional
        The surface's form and position now (``HealthReport.form_position``: ``tir_mm`` and
        ``ront_mm``, None where not known); without it, none is kept.
    """

    def __init__(self, log: CompensationLog, hz: float,
                 feature: Callable[[MeasurementRecord], Feature],
                 form: Callable[[], dict[str, Any]] | None = None) -> None:
        self.log, self.period_s, self.feature = log, 1.0 / hz, feature
        self.form = form
        self._last_time = -float("inf")
        self.kept = 0

    def __call__(self, record: MeasurementRecord) -> None:
        if record.time - self._last_time < self.period_s:
            return
        self._last_time = record.time
        f = self.feature(record)
        form = self.form() if self.form is not None else {}
        self.log.submit_measurement({
            "seq": record.seq, "wall_time": record.time, "status": record.status,
            "diameter_mm": record.diameter_mm, "uncertainty_mm": record.uncertainty_mm,
            "fused_diameter_mm": record.fused_diameter_mm, "deviation_mm": record.deviation_mm,
            "in_tolerance": None if record.in_tolerance is None else int(record.in_tolerance),
            "calibration_id": record.calibration_id, "nominal_mm": f.nominal_mm,
            "tol_lower_mm": f.tol_lower_mm, "tol_upper_mm": f.tol_upper_mm,
            "tir_mm": form.get("tir_mm"), "ront_mm": form.get("ront_mm"),
            "feature": record.feature})
        self.kept += 1
