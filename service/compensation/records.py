"""What the controller takes and gives: measurements in, decisions out, the state that
survives a restart, the CNC's registers as read."""

from __future__ import annotations

import enum
from dataclasses import asdict, dataclass
from typing import Any

from service.compensation.settings import CompensationSettings


class Kind(enum.StrEnum):
    """What a decision did."""

    REFUSED = "refused"          # the measurement does not count
    HELD = "held"                # counted or not, nothing to do now
    ALARM = "alarm"              # beyond the plausibility limit: nothing written until a
    #                              plausible measurement or an acknowledgement
    STOPPED = "stopped"          # beyond the safe area: a person must check and reset
    PROPOSED = "proposed"        # shadow mode: computed, shown, not written
    WRITE = "write"              # the service must write this offset now
    APPLIED = "applied"          # the CNC acknowledged it
    NOT_APPLIED = "not_applied"  # definitely not applied (never re-sent)
    UNCERTAIN = "uncertain"      # written, not acknowledged: holding until the CNC tells
    LIMIT = "limit"              # the cumulative limit forbids any further correction
    RESET = "reset"
    ACKNOWLEDGED = "acknowledged"  # the alarm ended (by a person, or plausible again)
    SETTINGS = "settings"
    BASELINE = "baseline"        # the CNC's total taken as the reference of the limit (also
    #                              when someone else changed it: an insert change)


QUIET_KINDS = frozenset({Kind.REFUSED, Kind.HELD, Kind.PROPOSED})
"""Kinds that repeat with every measurement in a steady state; the log keeps a run of them as
one row with a count (see ``calib_store.compensation_log``)."""


class State(enum.StrEnum):
    """Where the controller is."""

    ACTIVE = "active"
    PENDING = "pending"        # an offset was handed out for writing
    UNCERTAIN = "uncertain"    # its outcome is unknown
    ALARM = "alarm"
    STOPPED = "stopped"


@dataclass(frozen=True)
class MeasurementIn:
    """What the controller needs of a measurement."""

    seq: int
    time_s: float                 # monotonic seconds when it was taken
    status: str                   # "ok" or a failure status
    diameter_mm: float | None
    uncertainty_mm: float | None
    calibration_id: int | None = None  # the calibration it was measured with


@dataclass(frozen=True)
class FeatureTerms:
    """How a tool's controller takes a measurement of one of its features: judged against
    the feature's ``settings`` (nominal, tolerance, bands), its deviation less
    ``empirical_mm`` into the tool's law, or ``held`` (why) when its features disagree."""

    settings: CompensationSettings
    empirical_mm: float = 0.0
    held: str = ""


@dataclass(frozen=True)
class Decision:
    """One step of the controller, for the log (and, for WRITE, an order to write).

    ``offset_mm`` is in offset units as sent to the CNC; ``before_mm``/``after_mm`` are the
    cumulative offset around the decision.
    """

    kind: Kind
    reason: str
    time_s: float
    measurement_seq: int | None = None
    deviation_mm: float | None = None
    filtered_mm: float | None = None
    offset_mm: float | None = None
    offset_seq: int | None = None
    before_mm: float = 0.0
    after_mm: float = 0.0
    shadow: bool = False
    code: str = ""
    """A stable name of the reason (``no_nominal``, ``deadband``, ``stale``, ...): decisions
    of one kind and code are "the same" for the log's runs."""
    who: str = ""
    """Who asked, for a person's or the CNC's command (``api:technician``, ``modbus``)."""
    tool: int | None = None
    """The tool of the offset entry whose controller decided (None: not yet named, a
    controller on its own)."""
    entry: int | None = None
    """That entry's offset number (None: the tool's own)."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        d = asdict(self)
        d["kind"] = self.kind.value
        return d


@dataclass
class ControllerState:
    """What survives a restart (JSON-ready through ``asdict``)."""

    cumulative_mm: float = 0.0
    offset_seq: int = 0
    state: str = State.ACTIVE.value
    pending_seq: int | None = None
    pending_offset_mm: float | None = None
    last_measurement_seq: int = -1
    baseline_mm: float | None = None
    """The CNC's total wear offset when compensation was enabled or last reset by a person
    (None: taken at the next reading of the CNC's total)."""
    cnc_total_mm: float | None = None
    """The CNC's total wear offset as last read."""
    pending_total_before_mm: float | None = None
    """The CNC's total read just before the pending offset was written."""
    pending_measurement_seq: int | None = None
    """The measurement the pending offset answers (its outcome names it too)."""

    def cnc_offset_mm(self) -> float | None:
        """How far the CNC's total stands from the baseline (None while either is unknown):
        the figure the cumulative limit is checked against."""
        if self.cnc_total_mm is None or self.baseline_mm is None:
            return None
        return self.cnc_total_mm - self.baseline_mm

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> ControllerState:
        """From what was saved (fields added since are defaulted; None: a fresh state)."""
        known = cls.__dataclass_fields__
        return cls(**{k: v for k, v in (d or {}).items() if k in known})


@dataclass(frozen=True)
class CncReading:
    """The CNC's side of the offset exchange, as read from its registers (offset units).

    ``request_seq`` is the sequence in its request registers (0 once the CNC cleared a request
    it will not apply), ``ack_seq`` the sequence it last applied, ``total_mm`` its total wear
    offset.
    """

    ack_seq: int
    request_seq: int
    total_mm: float

