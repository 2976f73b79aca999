"""The running service, in parts with one job each (ARCHITECTURE.md): ``FramePipeline``
(frames to measurements), ``Publisher`` and ``make_record`` (measurements to records, fanned
out), ``MeasurementFeed`` (latest, history, subscribers), ``CalibrationContext`` (the
calibration in force), ``CompensationService`` (the controller and its settings),
``RegisterView`` (what the registers show), ``CncWriteRules`` and ``CncCommands`` (what
the CNC writes), ``ModbusService`` (their server), ``HealthReport`` (a read-only view),
and ``Gauge`` (starts and stops them)."""

from service.measurement_record import MeasurementRecord
from service.runtime.gauge import Gauge

__all__ = ["Gauge", "MeasurementRecord"]
