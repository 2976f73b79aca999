"""Tool-wear compensation: a pure state machine in the manner of CNC measuring cycles.

It turns measurements into tool-wear offsets and never does I/O: the service feeds it
measurements and the outcome of each offset write, and carries out the writes it asks for.

Per measurement, in this order (each step records a ``Decision`` with its reason):

1. *Refuse* what is doubtful: status not ok, a non-finite diameter or uncertainty, an
   uncertainty above ``max_uncertainty_fraction`` of the tolerance width, a sequence number not
   above the last one (out of order or repeated), a measurement older than ``max_age_s``.
2. *Stop* when the deviation from nominal exceeds the safe area (``safe_area_mm``): a broken
   tool, a wrong part or a wrong nominal; nothing more is written until a person resets.
3. *Hold* while stopped, while an alarm waits for acknowledgement, while an offset waits for
   the CNC's acknowledgement, during the dead time after a correction, and until the filter
   window holds ``window`` good measurements.
4. *Alarm* when the filtered deviation (median or mean of the window) is outside the
   tolerance: the part is already out; nothing is written; acknowledge to go on.
5. *Hold* inside the deadband.
6. Otherwise correct ``gain`` of the filtered deviation, converted to the CNC's offset
   (diameter or radius programming, sign convention), clipped to ``max_step_mm``, and clipped
   so the cumulative offset stays within ``max_total_mm`` (refused when already there). In
   shadow mode the offset is *proposed* and nothing is written.

With ``law = "predictive"`` steps 3-6 use every measurement that counts instead: the process
without compensation is estimated from it and the offsets in force when it was cut
(``service.control_law``), an alarm is raised when the measured part is out of tolerance, and
the correction sets the total offset to cancel the forecast (within the deadband, the step and
the cumulative limit as above).

The cumulative limit is checked against the CNC's own total wear offset (its ``total``
register), not against the gauge's bookkeeping: ``baseline_mm`` is the CNC's total when
compensation was enabled or reset by a person, and no offset is written that would take the
CNC's total further than ``max_total_mm`` from it (``check_before_write`` with a fresh reading
of the total, just before each write). Resets, restarts and settings changes cannot walk
around it.

An offset whose fate is unknown (no acknowledgement in time, the PLC went silent, the service
was killed) stays UNCERTAIN and blocks everything until the CNC's registers settle it
(``settle_from_cnc``): its acknowledgement echoes the sequence (applied), its request
registers no longer hold the sequence (cleared or never received: not applied), or its total
moved by exactly the offset (applied). It is never sent again.
"""

from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from service.control_law import Predictor, WindowLaw


class Kind(enum.StrEnum):
    """What a decision did."""

    REFUSED = "refused"          # the measurement does not count
    HELD = "held"                # counted or not, nothing to do now
    ALARM = "alarm"              # out of tolerance: nothing written, acknowledge needed
    STOPPED = "stopped"          # beyond the safe area: a person must check and reset
    PROPOSED = "proposed"        # shadow mode: computed, shown, not written
    WRITE = "write"              # the service must write this offset now
    APPLIED = "applied"          # the CNC acknowledged it
    NOT_APPLIED = "not_applied"  # definitely not applied (never re-sent)
    UNCERTAIN = "uncertain"      # written, not acknowledged: holding until the CNC tells
    LIMIT = "limit"              # the cumulative limit forbids any further correction
    RESET = "reset"
    ACKNOWLEDGED = "acknowledged"
    SETTINGS = "settings"
    BASELINE = "baseline"        # the CNC's total taken as the reference of the limit


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
class CompensationSettings:
    """Tuning of the controller. Lengths in mm of diameter unless named otherwise.

    Attributes
    ----------
    nominal_mm : float or None
        Nominal diameter of the current feature; None holds everything.
    tol_upper_mm, tol_lower_mm : float
        Tolerance as deviations from nominal (upper >= 0 >= lower).
    window : int
        Good measurements in the filter.
    filter : {'median', 'mean'}
        How the window is combined: the median, or the mean weighted by 1 / uncertainty^2.
    deadband_mm : float
        No correction while the filtered deviation (``predictive``: the correction wanted)
        is within +-deadband.
    gain : float
        Fraction (0-1] of the filtered deviation corrected at once: the feedback
        percentage of a measuring cycle (``predictive``: the share of each measurement in
        the process estimate, an EWMA's lambda).
    law : {'window', 'predictive'}
        ``window``: wait out the dead time after a correction, fill the window, correct
        ``gain`` of its median or mean. ``predictive`` (``service.control_law``): every
        measurement counts, tagged with the offsets in force when its surface was cut; the
        process without compensation is followed by a double EWMA and the total offset set
        to cancel its forecast where the next correction will show. The dead time then says
        when an applied offset becomes visible, not how long to wait.
    trend_gain : float
        ``predictive``: the share of each change of the process estimate taken into its
        trend (0: a single EWMA, which lags behind linear wear).
    max_step_mm : float
        Largest single offset, in offset units as sent (see ``programming``).
    max_total_mm : float
        Largest cumulative offset, in offset units.
    dead_time_measurements, dead_time_s : int, float
        After a correction, the next measurements within both limits were cut before it
        (the cut has to pass under the gauge first): ``window`` ignores them, ``predictive``
        counts the correction as in flight for them.
    safe_area_mm : float
        A deviation beyond this stops the controller.
    max_uncertainty_fraction : float
        Measurements with a larger uncertainty than this fraction of the tolerance width do
        not count.
    max_age_s : float
        Older measurements do not count.
    programming : {'diameter', 'radius'}
        Whether the CNC's X offsets are diameter or radius values.
    offset_sign : {+1, -1}
        +1 when a positive wear offset makes the part larger, -1 when it makes it smaller.
    shadow : bool
        Compute and show offsets, write none.
    offset_resolution_mm : float
        The CNC's offset resolution (the register's unit, 0.1 um): offsets are whole
        multiples of it, so the log adds up to the CNC's total exactly.
    """

    nominal_mm: float | None = None
    tol_upper_mm: float = 0.02
    tol_lower_mm: float = -0.02
    window: int = 5
    filter: Literal["median", "mean"] = "median"
    deadband_mm: float = 0.003
    gain: float = 0.7
    max_step_mm: float = 0.010
    max_total_mm: float = 0.200
    dead_time_measurements: int = 5
    dead_time_s: float = 2.0
    safe_area_mm: float = 0.5
    max_uncertainty_fraction: float = 0.25
    max_age_s: float = 10.0
    programming: Literal["diameter", "radius"] = "diameter"
    offset_sign: int = 1
    shadow: bool = True
    offset_resolution_mm: float = 0.0001
    law: Literal["window", "predictive"] = "window"
    trend_gain: float = 0.2

    def problems(self) -> list[str]:
        """What is inconsistent, each naming the setting (empty when fine)."""
        p = []
        finite = all(math.isfinite(v) for v in (
            self.tol_upper_mm, self.tol_lower_mm, self.deadband_mm, self.gain,
            self.max_step_mm, self.max_total_mm, self.dead_time_s, self.safe_area_mm,
            self.max_uncertainty_fraction, self.max_age_s, self.offset_resolution_mm))
        if not finite:
            return ["settings: every number must be finite"]
        if self.nominal_mm is not None and not (math.isfinite(self.nominal_mm)
                                                and self.nominal_mm > 0):
            p.append("nominal_mm must be a positive diameter")
        if not self.tol_lower_mm <= 0 <= self.tol_upper_mm or \
                self.tol_upper_mm == self.tol_lower_mm:
            p.append("tolerance must satisfy tol_lower_mm <= 0 <= tol_upper_mm, not both 0")
        if not 0 < self.gain <= 1:
            p.append("gain must be within (0, 1]")
        if self.window < 1:
            p.append("window must be at least 1")
        if self.filter not in ("median", "mean"):
            p.append("filter must be 'median' or 'mean'")
        if not 0 <= self.deadband_mm < max(self.tol_upper_mm, -self.tol_lower_mm):
            p.append("deadband_mm must be >= 0 and inside the tolerance")
        if not 0 < self.max_step_mm <= self.max_total_mm:
            p.append("max_step_mm must be > 0 and <= max_total_mm")
        if self.safe_area_mm <= max(self.tol_upper_mm, -self.tol_lower_mm):
            p.append("safe_area_mm must be larger than the tolerance")
        if self.dead_time_measurements < 0 or self.dead_time_s < 0:
            p.append("dead time must be >= 0")
        if not 0 < self.max_uncertainty_fraction <= 1:
            p.append("max_uncertainty_fraction must be within (0, 1]")
        if self.max_age_s <= 0:
            p.append("max_age_s must be > 0")
        if self.programming not in ("diameter", "radius"):
            p.append("programming must be 'diameter' or 'radius'")
        if not 0 < self.offset_resolution_mm <= self.max_step_mm:
            p.append("offset_resolution_mm must be > 0 and <= max_step_mm")
        if self.offset_sign not in (1, -1):
            p.append("offset_sign must be +1 or -1")
        if self.law not in ("window", "predictive"):
            p.append("law must be 'window' or 'predictive'")
        if not 0 <= self.trend_gain < 1:
            p.append("trend_gain must be within [0, 1)")
        return p


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


@dataclass
class CompensationController:
    """The state machine. Call ``on_measurement`` for every measurement, then carry out any
    ``Kind.WRITE`` decision and report its outcome with ``on_write_outcome``."""

    settings: CompensationSettings = field(default_factory=CompensationSettings)
    persisted: ControllerState = field(default_factory=ControllerState)

    writes_blocked: str = ""
    """Set by the service when offsets must not be written (a failed or overdue master check):
    offsets are then only proposed, with this reason."""

    calibration_id: int | None = None
    """The active calibration: measurements made with another one are refused."""

    def __post_init__(self) -> None:
        problems = self.settings.problems()
        if problems:
            raise ValueError("; ".join(problems))
        self._window = WindowLaw.of(self.settings)
        self._predictor = Predictor.of(self.settings)
        # A write handed out but never reported (the service died) is uncertain on restart.
        if self.persisted.state == State.PENDING.value:
            self.persisted.state = State.UNCERTAIN.value

    # ---- read-only views ---------------------------------------------------------------

    @property
    def state(self) -> State:
        """Current state."""
        return State(self.persisted.state)

    @property
    def cumulative_mm(self) -> float:
        """Sum of the acknowledged offsets since the last reset, offset units."""
        return self.persisted.cumulative_mm

    def _decision(self, kind: Kind, code: str, reason: str, now: float,
                  **kw: Any) -> Decision:
        cum = self.persisted.cumulative_mm
        kw.setdefault("before_mm", cum)
        kw.setdefault("after_mm", cum)
        return Decision(kind, reason, now, shadow=self.settings.shadow, code=code, **kw)

    def _enter(self, state: State, kind: Kind, code: str, reason: str, now: float,
               **kw: Any) -> Decision:
        """Move to ``state`` (the filter window starts afresh) and record why."""
        self.persisted.state = state.value
        self._window.clear()
        return self._decision(kind, code, reason, now, **kw)

    # ---- inputs --------------------------------------------------------------------------

    def update_settings(self, settings: CompensationSettings, now: float,
                        who: str = "") -> Decision:
        """New settings (a new feature, tolerance or tuning); the window starts afresh.
        Switching shadow mode off enables compensation: the CNC's total at the next reading
        becomes the baseline of the cumulative limit."""
        problems = settings.problems()
        if problems:
            raise ValueError("; ".join(problems))
        old = self.settings
        if old.shadow and not settings.shadow and self.state in (State.PENDING,
                                                                 State.UNCERTAIN):
            raise ValueError(f"offset {self.persisted.pending_seq} is unsettled: enable "
                             "compensation once the CNC's registers settle it")
        self.settings = settings
        self._window = self._window.retuned(settings)
        keep = (old.law, old.nominal_mm, old.programming, old.offset_sign) == (
            settings.law, settings.nominal_mm, settings.programming, settings.offset_sign)
        self._predictor = self._predictor.retuned(settings) if keep else Predictor.of(settings)
        enabled = old.shadow and not settings.shadow
        if enabled:
            self.persisted.baseline_mm = None
        return self._decision(Kind.SETTINGS, "settings", f"settings changed "
                              f"({_changes(old, settings)}): filter window restarted"
                              + ("; compensation enabled: the CNC's total is the new baseline"
                                 if enabled else ""), now, who=who)

    def observe_cnc_total(self, total_mm: float, now: float) -> Decision | None:
        """The CNC's total wear offset as just read. Takes it as the baseline when there is
        none and compensation is enabled (a BASELINE decision), else None."""
        p = self.persisted
        p.cnc_total_mm = total_mm
        if p.baseline_mm is None and not self.settings.shadow and self.state not in (
                State.PENDING, State.UNCERTAIN):
            p.baseline_mm = total_mm
            return self._decision(Kind.BASELINE, "baseline", f"the CNC's total wear offset "
                                  f"{total_mm * 1000:+.1f} um is the reference of the "
                                  f"cumulative limit (+-{self.settings.max_total_mm * 1000:.0f}"
                                  " um)", now)
        return None

    def on_measurement(self, m: MeasurementIn, now: float) -> Decision:
        """Judge one measurement; see the module docstring for the order of the checks."""
        s = self.settings
        code, why = refusal(s, m, now, self.persisted.last_measurement_seq,
                            self.calibration_id)
        if why:
            return self._decision(Kind.REFUSED, code, why, now, measurement_seq=m.seq)
        self.persisted.last_measurement_seq = m.seq
        if s.nominal_mm is None:
            return self._decision(Kind.HELD, "no_nominal", "no nominal diameter set", now,
                                  measurement_seq=m.seq)
        deviation = float(m.diameter_mm) - s.nominal_mm
        kw: dict[str, Any] = {"measurement_seq": m.seq, "deviation_mm": deviation}
        if abs(deviation) > s.safe_area_mm:
            return self._enter(
                State.STOPPED, Kind.STOPPED, "safe_area",
                f"deviation {deviation * 1000:+.1f} um is beyond the safe area of "
                f"{s.safe_area_mm * 1000:.0f} um (broken tool, wrong part or wrong "
                "nominal?): stopped; a person must check and reset", now, **kw)
        gate = _gate(self.state, self.persisted.pending_seq)
        if gate:
            return self._decision(Kind.HELD, f"gate_{self.state.value}", gate, now, **kw)
        if s.law == "predictive":
            applied = effect_mm(s, self.persisted.cumulative_mm)
            # Where the coming parts will stand with the offsets applied (in flight too).
            filtered = self._predictor.observe(deviation, applied, now) + applied
            judged, label, gain = deviation, "deviation", 1.0
        else:
            got = self._window.observe(deviation, float(m.uncertainty_mm), now)
            if isinstance(got, tuple):
                return self._decision(Kind.HELD, *got, now, **kw)
            judged = filtered = got
            label, gain = "filtered deviation", s.gain
        kw["filtered_mm"] = filtered
        if not s.tol_lower_mm <= judged <= s.tol_upper_mm:
            return self._enter(
                State.ALARM, Kind.ALARM, "out_of_tolerance",
                f"{label} {judged * 1000:+.1f} um is outside the tolerance "
                f"{s.tol_lower_mm * 1000:+.1f}/{s.tol_upper_mm * 1000:+.1f} um: "
                "out of tolerance, nothing written; acknowledge to go on", now, **kw)
        if abs(filtered) <= s.deadband_mm:
            return self._decision(Kind.HELD, "deadband", f"filtered deviation "
                                  f"{filtered * 1000:+.1f} um inside the deadband of "
                                  f"{s.deadband_mm * 1000:.1f} um", now, **kw)
        return self._correct(-gain * filtered / effect_mm(s, 1.0), now, kw)

    def _correct(self, wanted: float, now: float, kw: dict[str, Any]) -> Decision:
        """Write (or propose) ``wanted`` (offset units), within the step and cumulative
        limits and the CNC's resolution."""
        s = self.settings
        writing = not (s.shadow or self.writes_blocked)
        # Writing, the limit is on the CNC's own total; proposing, on our bookkeeping.
        cnc = self.persisted.cnc_offset_mm()
        if writing and cnc is None:
            self._window.clear()
            return self._decision(Kind.HELD, "cnc_total_unknown", "the CNC's total wear offset "
                                  "has not been read yet: no offset until it is (the "
                                  "cumulative limit is checked against it)", now, **kw)
        cum = cnc if writing else self.persisted.cumulative_mm
        step, limited = clip_step(s, wanted, cum)
        self._window.clear()
        if step == 0.0:
            if limited:  # already at the cumulative limit in this direction
                return self._decision(
                    Kind.LIMIT, "limit", f"the cumulative offset {cum * 1000:+.1f} um is at "
                    f"its limit of {s.max_total_mm * 1000:.0f} um: change or re-measure the "
                    "tool, then reset", now, **kw)
            return self._decision(Kind.HELD, "below_resolution", f"offset "
                                  f"{wanted * 1000:+.3f} um is below the CNC's resolution of "
                                  f"{s.offset_resolution_mm * 1000:g} um", now, **kw)
        note = "" if abs(step - wanted) < 1e-12 else \
            f" (clipped from {wanted * 1000:+.2f} um)"
        own = self.persisted.cumulative_mm
        if not writing:
            why = "shadow mode" if s.shadow else f"writes blocked ({self.writes_blocked})"
            return self._decision(Kind.PROPOSED, "proposed", f"{why}: offset "
                                  f"{step * 1000:+.2f} um proposed, not written{note}", now,
                                  offset_mm=step, after_mm=own + step, **kw)
        self.persisted.offset_seq += 1
        self.persisted.pending_seq = self.persisted.offset_seq
        self.persisted.pending_offset_mm = step
        self.persisted.pending_total_before_mm = None
        self.persisted.state = State.PENDING.value
        return self._decision(Kind.WRITE, "write", f"write offset {step * 1000:+.2f} um{note}",
                              now, offset_mm=step, offset_seq=self.persisted.offset_seq,
                              after_mm=own + step, **kw)

    def check_before_write(self, offset_seq: int, total_mm: float | None,
                           now: float) -> Decision | None:
        """Just before the pending offset goes out: the CNC's total as read now. None when it
        may be written; otherwise the offset is dropped (never written) and the decision says
        why: the total cannot be read, or the offset would take it beyond the limit."""
        p = self.persisted
        if p.pending_seq != offset_seq or self.state is not State.PENDING:
            return self._drop(offset_seq, "not_in_flight", "it is not the offset in flight",
                              now)
        if total_mm is not None:
            p.cnc_total_mm = total_mm
        code, why = limit_veto(self.settings, p, total_mm)
        if code:
            return self._drop(offset_seq, code, why, now,
                              kind=Kind.LIMIT if code == "limit" else Kind.NOT_APPLIED)
        p.pending_total_before_mm = total_mm
        return None

    def _drop(self, offset_seq: int, code: str, why: str, now: float,
              kind: Kind = Kind.NOT_APPLIED) -> Decision:
        p = self.persisted
        if p.pending_seq == offset_seq and self.state is State.PENDING:
            p.pending_seq, p.pending_offset_mm, p.pending_total_before_mm = None, None, None
            p.state = State.ACTIVE.value
            self._window.clear()
        return self._decision(kind, code, f"offset {offset_seq} not written: {why}", now,
                              offset_seq=offset_seq)

    def on_write_outcome(self, offset_seq: int, applied: bool | None, now: float,
                         detail: str = "") -> Decision:
        """The outcome of a WRITE: True acknowledged, False definitely not applied, None
        unknown (written, then no acknowledgement in time, or silence)."""
        p = self.persisted
        if p.pending_seq != offset_seq or self.state not in (State.PENDING, State.UNCERTAIN):
            return self._decision(Kind.HELD, "not_in_flight", f"outcome of offset "
                                  f"{offset_seq} ignored: it is not the offset in flight", now,
                                  offset_seq=offset_seq)
        step = p.pending_offset_mm or 0.0
        what = f"offset {offset_seq} ({step * 1000:+.2f} um)"
        kw: dict[str, Any] = {"offset_mm": step, "offset_seq": offset_seq}
        if applied is None:
            p.state = State.UNCERTAIN.value
            return self._decision(Kind.UNCERTAIN, "uncertain", f"{what} not acknowledged"
                                  f"{_colon(detail)}; holding until the CNC's registers settle "
                                  "it, it will not be sent again", now, **kw)
        before = p.cumulative_mm
        p.pending_seq, p.pending_offset_mm, p.pending_total_before_mm = None, None, None
        p.state = State.ACTIVE.value
        self._window.clear()
        if applied:
            p.cumulative_mm = before + step
            if p.cnc_total_mm is not None:  # until the next reading says otherwise
                p.cnc_total_mm += step
            self._window.corrected(now)
            self._predictor.applied(effect_mm(self.settings, step),
                                    self.settings.dead_time_measurements,
                                    now + self.settings.dead_time_s)
            return self._decision(Kind.APPLIED, "applied", f"{what} acknowledged by the "
                                  f"CNC{_colon(detail)}", now, before_mm=before,
                                  after_mm=p.cumulative_mm, **kw)
        return self._decision(Kind.NOT_APPLIED, "not_applied", f"{what} was not applied"
                              f"{_colon(detail)}; it will not be sent again", now, **kw)

    def settle_from_cnc(self, cnc: CncReading, now: float) -> Decision | None:
        """Settle an UNCERTAIN offset from the CNC's registers, or None while they cannot
        tell (the request is still there, unacknowledged: nothing else is sent meanwhile).

        Applied when the CNC echoes its sequence, or when its total moved from the total read
        before the write by exactly the offset; not applied when its request registers no
        longer hold the sequence (the CNC cleared a request it will not apply, or never
        received it).
        """
        p = self.persisted
        seq = p.pending_seq
        if self.state is not State.UNCERTAIN or seq is None:
            return None
        applied, how = cnc_verdict(p, cnc)
        if applied is None:
            return None
        d = self.on_write_outcome(seq, applied, now, how)
        self.persisted.cnc_total_mm = cnc.total_mm
        return d

    def acknowledge_alarm(self, now: float, who: str = "") -> Decision:
        """Leave the out-of-tolerance alarm."""
        if self.state is not State.ALARM:
            return self._decision(Kind.HELD, "no_alarm", f"no alarm to acknowledge "
                                  f"({self.state.value})", now, who=who)
        self.persisted.state = State.ACTIVE.value
        self._window.clear()
        return self._decision(Kind.ACKNOWLEDGED, "acknowledged", "alarm acknowledged", now,
                              who=who)

    def reset(self, now: float, who: str = "") -> Decision:
        """A reset (after a tool change): the gauge's cumulative offset back to 0, leave
        STOPPED or ALARM; the CNC's total at the next reading becomes the reference of the
        cumulative limit. Refused while an offset's fate is unknown."""
        if self.state in (State.PENDING, State.UNCERTAIN):
            return self._decision(Kind.HELD, "reset_unsettled", f"reset refused: offset "
                                  f"{self.persisted.pending_seq} is still unsettled", now,
                                  who=who)
        before = self.persisted.cumulative_mm
        self.persisted.cumulative_mm = 0.0
        self.persisted.state = State.ACTIVE.value
        self.persisted.baseline_mm = None
        self._window.clear()
        self._predictor.reset()
        return self._decision(Kind.RESET, "reset", "compensation reset: cumulative offset "
                              "back to 0; the CNC's total at the next reading is the new "
                              "baseline", now, before_mm=before, after_mm=0.0, who=who)

    def note_settings(self, what: str, now: float, who: str) -> Decision:
        """Record a change of a setting outside the controller (for the audit trail)."""
        return self._decision(Kind.SETTINGS, "other_settings", what, now, who=who)

    def refuse_reset(self, now: float, who: str, why: str) -> Decision:
        """Record a reset that was asked for and not carried out."""
        return self._decision(Kind.REFUSED, "reset_refused", f"reset refused: {why}", now,
                              who=who)


def refusal(s: CompensationSettings, m: MeasurementIn, now: float, last_seq: int,
            calibration_id: int | None) -> tuple[str, str]:
    """(code, reason) why a measurement does not count, or ("", "")."""
    if m.status != "ok":
        return f"status_{m.status}", f"measurement status {m.status!r}"
    if m.diameter_mm is None or not math.isfinite(m.diameter_mm) or m.diameter_mm <= 0:
        return "bad_diameter", f"diameter {m.diameter_mm!r} is not a positive finite number"
    if m.uncertainty_mm is None or not math.isfinite(m.uncertainty_mm) \
            or m.uncertainty_mm < 0:
        return "bad_uncertainty", (f"uncertainty {m.uncertainty_mm!r} is not a finite "
                                   "number >= 0")
    limit = s.max_uncertainty_fraction * (s.tol_upper_mm - s.tol_lower_mm)
    if m.uncertainty_mm > limit:
        return "uncertain_measurement", (
            f"uncertainty {m.uncertainty_mm * 1000:.1f} um is above {limit * 1000:.1f} um "
            f"({s.max_uncertainty_fraction:.0%} of the tolerance width)")
    if m.calibration_id != calibration_id:
        return "other_calibration", (f"measured with calibration {m.calibration_id}, "
                                     f"calibration {calibration_id} is active")
    if m.seq <= last_seq:
        return "out_of_order", (f"measurement {m.seq} is not newer than "
                                f"{last_seq} (out of order or "
                                "repeated)")
    if not math.isfinite(m.time_s) or now - m.time_s > s.max_age_s:
        return "stale", f"measurement is stale (older than {s.max_age_s:g} s)"
    if m.time_s - now > 1.0:
        return "future", "measurement is from the future (clock jump?)"
    return "", ""


def _changes(old: CompensationSettings, new: CompensationSettings) -> str:
    """``name=value`` of each setting that changed."""
    before = asdict(old)
    return ", ".join(f"{k}={v!r}" for k, v in asdict(new).items() if before[k] != v) \
        or "nothing changed"


def _gate(state: State, pending_seq: int | None) -> str:
    """Why nothing is judged in this state ("" when it is)."""
    return {State.STOPPED: "stopped: waiting for a reset",
            State.ALARM: "out-of-tolerance alarm: waiting for acknowledgement",
            State.PENDING: f"waiting for the CNC to acknowledge offset {pending_seq}",
            State.UNCERTAIN: f"offset {pending_seq} was not acknowledged: holding until the "
                             "CNC's registers settle it"}.get(state, "")


def limit_veto(s: CompensationSettings, p: ControllerState, total_mm: float | None
               ) -> tuple[str, str]:
    """(code, why) the pending offset must not be written with the CNC's total as read now,
    or ("", "")."""
    if total_mm is None:
        return "cnc_total_unreadable", ("the CNC's total wear offset cannot be read, so the "
                                        "cumulative limit cannot be checked")
    if p.baseline_mm is None:  # a reset or enabling came between the decision and now
        return "no_baseline", "the reference of the cumulative limit is being taken again"
    after = total_mm + (p.pending_offset_mm or 0.0) - p.baseline_mm
    if abs(after) > s.max_total_mm + 1e-9:
        return "limit", (f"the CNC's total would stand {after * 1000:+.1f} um from the "
                         f"baseline, beyond the limit of {s.max_total_mm * 1000:.0f} um")
    return "", ""


def effect_mm(s: CompensationSettings, offset_mm: float) -> float:
    """What an offset (offset units) does to the diameter, mm."""
    return offset_mm * s.offset_sign * (2.0 if s.programming == "radius" else 1.0)


def clip_step(s: CompensationSettings, wanted: float, cum_mm: float) -> tuple[float, bool]:
    """(step, limited): the offset ``wanted`` (offset units) clipped to ``max_step_mm``, and
    to ``max_total_mm`` around ``cum_mm``, in the CNC's resolution rounded toward zero; and
    whether the cumulative limit clipped it."""
    step = max(-s.max_step_mm, min(s.max_step_mm, wanted))
    target = max(-s.max_total_mm, min(s.max_total_mm, cum_mm + step))
    limited = abs(target - (cum_mm + step)) > 1e-12
    # In the CNC's resolution, rounded toward zero: what is logged is what is applied, and
    # rounding never takes the total past the limit.
    return _toward_zero(target - cum_mm, s.offset_resolution_mm), limited


def cnc_verdict(p: ControllerState, cnc: CncReading) -> tuple[bool | None, str]:
    """Whether the CNC's registers say the pending offset was applied (True, False, or None
    while they cannot tell), and how they say it."""
    seq, step = p.pending_seq, p.pending_offset_mm or 0.0
    if cnc.ack_seq == seq:
        return True, "the CNC's acknowledgement register echoes its sequence"
    if p.pending_total_before_mm is not None and abs(step) > 0 and \
            abs(cnc.total_mm - (p.pending_total_before_mm + step)) < 0.5e-4:
        return True, "the CNC's total moved by the offset"
    if cnc.request_seq != seq:
        return False, (f"the CNC's request registers no longer hold it (they hold "
                       f"{cnc.request_seq}): cleared by the CNC or never received")
    return None, ""


def _toward_zero(value_mm: float, resolution_mm: float) -> float:
    """``value_mm`` as a whole number of ``resolution_mm``, rounded toward zero (a hair of
    float error is forgiven: 0.30000000000000004 units is 0.3)."""
    units = value_mm / resolution_mm
    whole = math.floor(abs(units) + 1e-6)
    return math.copysign(whole * resolution_mm, units) if whole else 0.0


def _colon(detail: str) -> str:
    return f": {detail}" if detail else ""
