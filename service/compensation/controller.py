"""Tool-wear compensation's state machine, in the manner of CNC measuring cycles.

It turns measurements into tool-wear offsets and never does I/O: the service feeds it
measurements, the CNC's total as read and the outcome of each offset write, and carries out
the writes it asks for.

Per measurement, in this order (each step records a ``Decision`` with its reason; the bands
are ``service.compensation.bands``):

1. *Refuse* what is doubtful: status not ok, a non-finite diameter or uncertainty, an
   uncertainty above ``max_uncertainty_fraction`` of the tolerance width, a sequence number not
   above the last one (out of order or repeated), a measurement older than ``max_age_s``.
2. *Stop* when the deviation from nominal exceeds the safe area (``safe_area_mm``): a broken
   tool, a wrong part or a wrong nominal; nothing more is written until a person resets.
3. *Alarm* when it exceeds the plausibility limit: nothing is written and the measurement is
   not taken. The alarm ends by itself at the next plausible measurement (which resumes
   control) or when a person acknowledges it; no reset is needed.
4. *Hold* while stopped, while an offset waits for the CNC's acknowledgement or is
   uncertain, and while the law holds (``window``: the dead time after a correction and a
   window to fill; ``predictive``: a measurement set aside as a possible outlier, a process
   estimate starting from two measurements that agree).
5. *Flag* a part outside the workpiece tolerance in the decision's reason (the measurement
   itself is flagged by the service) and go on: a part out is a reason to correct.
6. *Hold* inside the null band (``deadband_mm``); otherwise correct, converted to the CNC's
   offset (diameter or radius programming, sign convention), clipped to ``max_step_mm``, and
   clipped so the cumulative offset stays within ``max_total_mm`` (refused when already
   there). In shadow mode the offset is *proposed* and nothing is written.

``law = "predictive"`` (``service.compensation.laws.Predictor``) sets the total offset to
cancel the forecast of the process without compensation; ``law = "window"`` corrects
``gain`` of the median or mean of a window.

The cumulative limit is checked against the CNC's own total wear offset (its ``total``
register), not against the gauge's bookkeeping: ``baseline_mm`` is the CNC's total when
compensation was enabled or reset by a person, and no offset is written that would take the
CNC's total further than ``max_total_mm`` from it (``check_before_write`` with a fresh reading
of the total, just before each write). Resets, restarts and settings changes cannot walk
around it.

A CNC total that someone else changed (the wear offset zeroed at an insert change) is seen
when it is read while no offset of the gauge's is in flight: logged, and from then on the
measurements of parts cut with it are judged with it (the law counts it as an offset in
flight for the dead time), so the change is not corrected back.

An offset whose fate is unknown (no acknowledgement in time, the PLC went silent, the service
was killed) stays UNCERTAIN and blocks everything until the CNC's registers settle it
(``settle_from_cnc``): its acknowledgement echoes the sequence (applied), its request
registers no longer hold the sequence (cleared or never received: not applied), or its total
moved by exactly the offset (applied). It is never sent again.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from service.compensation.bands import PartBand, part_band, tolerance_text
from service.compensation.dead_time import MeasuredDeadTime
from service.compensation.exchange import clip_step, effect_mm, same_total
from service.compensation.handshake import OffsetBook
from service.compensation.laws import Estimate, Law, law_of
from service.compensation.records import Decision, FeatureTerms, Kind, MeasurementIn, State
from service.compensation.settings import CompensationSettings

"""An offset that would reverse the gauge's last one must be this many null bands: noise
does not walk the tool back and forth."""


@dataclass
class CompensationController(OffsetBook):
    """The state machine. Call ``on_measurement`` for every measurement, then carry out any
    ``Kind.WRITE`` decision and report its outcome with ``on_write_outcome``; tell it the
    CNC's total whenever it is read (``observe_cnc_total``)."""

    writes_blocked: str = ""
    """Set by the service when offsets must not be written (a failed or overdue master check):
    offsets are then only proposed, with this reason."""

    calibration_id: int | None = None
    """The active calibration: measurements made with another one are refused."""

    def __post_init__(self) -> None:
        problems = self.settings.problems()
        if problems:
            raise ValueError("; ".join(problems))
        self._law: Law = law_of(self.settings)   # chosen once, anew when the law changes
        self.dead = MeasuredDeadTime()  # the dead time the gauge's own offsets show
        self._dead_used = (self.settings.dead_time_measurements, self.settings.dead_time_s)
        self._applied_mm = 0.0  # the effect of every offset applied since the start, mm
        self._last_offset_mm = 0.0  # the last applied offset's effect, mm
        # A write handed out but never reported (the service died) is uncertain on restart.
        if self.persisted.state == State.PENDING.value:
            self.persisted.state = State.UNCERTAIN.value

    def _enter(self, state: State, kind: Kind, code: str, reason: str, now: float,
               **kw: Any) -> Decision:
        """Move to ``state`` (the filter window starts afresh) and record why."""
        self.persisted.state = state.value
        self._law.clear()
        return self._decision(kind, code, reason, now, **kw)

    def _forget(self) -> None:
        self._law.clear()

    def _dead_in_use(self) -> None:
        """The law waits the dead time in use (the measured one once it differs)."""
        use = self.dead.in_use(self.settings.dead_time_measurements, self.settings.dead_time_s)
        if use != self._dead_used:
            self._dead_used = use
            self._law.use_dead_time(*use, drift_mm=self.dead.drift_mm())

    def _applied_now(self, effect: float, now: float) -> None:
        self._last_offset_mm = effect
        self._in_flight(effect, now)
        self.dead.applied(effect)


    def _in_flight(self, effect: float, now: float) -> None:
        """An offset's effect on the diameter (mm) applied now: the laws wait for it."""
        self._applied_mm += effect
        self._law.applied(effect, now)

    # ---- inputs --------------------------------------------------------------------------

    def check_settings(self, settings: CompensationSettings) -> None:
        """ValueError naming what ``update_settings`` would refuse now."""
        problems = settings.problems()
        if problems:
            raise ValueError("; ".join(problems))
        if self.settings.shadow and not settings.shadow and self.state in (State.PENDING,
                                                                           State.UNCERTAIN):
            raise ValueError(f"offset {self.persisted.pending_seq} is unsettled: enable "
                             "compensation once the CNC's registers settle it")

    def update_settings(self, settings: CompensationSettings, now: float,
                        who: str = "") -> Decision:
        """New settings (a new feature, tolerance or tuning); the window starts afresh.
        Switching shadow mode off enables compensation: the CNC's total at the next reading
        becomes the baseline of the cumulative limit."""
        self.check_settings(settings)
        old = self.settings
        self.settings = settings
        renewed = (old.nominal_mm, old.programming, old.offset_sign) != (
            settings.nominal_mm, settings.programming, settings.offset_sign)
        self._law = self._law.retuned(settings, renewed) if old.law == settings.law \
            else law_of(settings)
        self._dead_used = (settings.dead_time_measurements, settings.dead_time_s)
        self._dead_in_use()
        enabled = old.shadow and not settings.shadow
        if enabled:
            self.persisted.baseline_mm = None
        return self._decision(Kind.SETTINGS, "settings", f"settings changed "
                              f"({_changes(old, settings)}): filter window restarted"
                              + ("; compensation enabled: the CNC's total is the new baseline"
                                 if enabled else ""), now, who=who)

    def observe_cnc_total(self, total_mm: float, now: float) -> Decision | None:
        """The CNC's total wear offset as just read. Takes it as the baseline when there is
        none and compensation is enabled (a BASELINE decision); a total that someone else
        changed since the last reading (while no offset of the gauge's is in flight) is the
        reference of the measurements from now on (a BASELINE decision with the code
        ``cnc_total_changed``); else None."""
        p = self.persisted
        settled = self.state not in (State.PENDING, State.UNCERTAIN)
        before, p.cnc_total_mm = p.cnc_total_mm, total_mm
        changed = None if before is None or not settled or same_total(
            before, total_mm, self.settings) else self._changed_at_cnc(before, total_mm, now)
        if p.baseline_mm is None and not self.settings.shadow and settled:
            p.baseline_mm = total_mm
            return self._decision(Kind.BASELINE, "baseline", f"the CNC's total wear offset "
                                  f"{total_mm * 1000:+.1f} um is the reference of the "
                                  f"cumulative limit (+-{self.settings.max_total_mm * 1000:.0f}"
                                  " um)", now)
        return changed

    def _changed_at_cnc(self, before_mm: float, total_mm: float, now: float) -> Decision:
        """Someone else moved the CNC's total from ``before_mm`` to ``total_mm`` (offset
        units): an insert change when it zeroed the total or took back more than half of
        what stood since the baseline (the wear offset set back), else a hand change at the
        panel. Taken for an insert change when in doubt: read as a hand change, an insert
        change would be corrected back by all the wear the new insert does not have."""
        change = total_mm - before_mm
        effect = effect_mm(self.settings, change)
        base = self.persisted.baseline_mm or 0.0
        self._in_flight(effect, now)
        set_back = same_total(total_mm, 0.0, self.settings) or \
            abs(total_mm - base) < 0.5 * abs(before_mm - base)
        if not set_back:
            # A known step of known size: the process estimate takes it when it lands, a
            # dead time on, and the law corrects what it does to the parts like any other
            # offset in force; nothing is read as wear or a step of the process.
            self.dead.applied(effect)
            return self._decision(
                Kind.BASELINE, "hand_change", f"the CNC's total wear offset was changed "
                f"at the CNC by {change * 1000:+.1f} um (a hand change at the panel): taken "
                "as a known step, which shows a dead time on; the parts are still held to "
                "nominal; the cumulative limit counts it", now)
        self.dead.estimator.forget()  # not a step of the gauge's: the level jumps with it
        # An insert change, most likely: the process estimate starts again from the parts cut
        # after it, and nothing is corrected before they are seen.
        self._law.restart(now)
        return self._decision(
            Kind.BASELINE, "cnc_total_changed", f"the CNC's total wear offset was changed "
            f"at the CNC by {change * 1000:+.1f} um, back toward where it stood when "
            "compensation started (an insert change?): the process is estimated again from "
            "the parts cut with it, nothing is corrected before they are measured; the "
            "cumulative limit keeps its reference", now)

    def on_measurement(self, m: MeasurementIn, now: float,
                       feature: FeatureTerms | None = None) -> Decision:
        """Judge one measurement; see the module docstring for the order of the checks.
        With ``feature`` (a tool finishing several), the part is judged against that
        feature's nominal and bands, and its deviation less the feature's empirical value
        goes into the tool's law."""
        s = self.settings
        b = s if feature is None else feature.settings
        code, why = refusal(b, m, now, self.persisted.last_measurement_seq,
                            self.calibration_id)
        if why:
            return self._decision(Kind.REFUSED, code, why, now, measurement_seq=m.seq)
        self.persisted.last_measurement_seq = m.seq
        if b.nominal_mm is None:
            return self._decision(Kind.HELD, "no_nominal", "no nominal diameter set", now,
                                  measurement_seq=m.seq)
        raw = float(m.diameter_mm) - b.nominal_mm
        kw: dict[str, Any] = {"measurement_seq": m.seq, "deviation_mm": raw}
        band = part_band(b, raw)
        # What the tool's law sees: the deviation less what the feature always shows.
        deviation = raw - (0.0 if feature is None else feature.empirical_mm)
        if band is PartBand.BEYOND_SAFE_AREA:
            return self._enter(
                State.STOPPED, Kind.STOPPED, "safe_area",
                f"deviation {raw * 1000:+.1f} um is beyond the safe area of "
                f"{b.safe_area_mm * 1000:.0f} um (broken tool, wrong part or wrong "
                "nominal?): stopped; a person must check and reset", now, **kw)
        gate = _gate(self.state, self.persisted.pending_seq)
        if band is PartBand.IMPLAUSIBLE:
            return self._implausible(raw, b.plausibility(), gate, now, kw)
        if self.state is State.ALARM:
            return self._enter(
                State.ACTIVE, Kind.ACKNOWLEDGED, "plausible_again", f"deviation "
                f"{raw * 1000:+.1f} um is plausible again: the alarm is over and "
                "compensation resumes", now, who="gauge", **kw)
        said = self.dead.measured(deviation, m.time_s, s.dead_time_measurements,
                                  s.dead_time_s, float(m.uncertainty_mm))
        self._dead_in_use()
        if said:
            # Said once, in a row of its own (a quiet decision's reason gives way to the
            # next's): this measurement corrects nothing.
            return self._decision(Kind.SETTINGS, "dead_time_measured", self.dead.said(
                s.dead_time_measurements, s.dead_time_s), now, **kw)
        if gate:
            return self._decision(Kind.HELD, f"gate_{self.state.value}", gate, now, **kw)
        if feature is not None and feature.held:
            return self._decision(Kind.HELD, "features_disagree", feature.held, now, **kw)
        # The interval between measurements from when they were taken (``m.time_s``): a
        # queue judged in a burst (a busy host) must not read as measurements microseconds
        # apart.
        got = self._law.estimate(deviation, float(m.uncertainty_mm), now, m.time_s,
                                 self._applied_mm, self._last_offset_mm, b.deadband_mm)
        flag = "" if band is PartBand.IN_TOLERANCE else (
            f"part out of tolerance ({raw * 1000:+.1f} um, tolerance "
            f"{tolerance_text(b)}): flagged; ")
        if not isinstance(got, Estimate):
            return self._decision(Kind.HELD, got.code, flag + got.why, now, **kw)
        filtered, note = got.deviation_mm, flag + got.note
        kw["filtered_mm"] = filtered
        if abs(filtered) <= got.null_mm:
            return self._decision(Kind.HELD, "deadband", f"{note}filtered deviation "
                                  f"{filtered * 1000:+.1f} um inside the null band (deadband) of "
                                  f"{got.null_mm * 1000:.1f} um", now, **kw)
        return self._correct(-got.gain * filtered / effect_mm(s, 1.0), now, kw, note)

    def _implausible(self, deviation: float, limit_mm: float, gate: str, now: float,
                     kw: dict[str, Any]) -> Decision:
        """A deviation beyond the plausibility limit: an alarm (once), nothing taken."""
        why = (f"deviation {deviation * 1000:+.1f} um is beyond the plausibility limit of "
               f"{limit_mm * 1000:.0f} um (a broken tool, a wrong part or "
               "setpoint?): nothing written")
        if self.state is State.ACTIVE:
            return self._enter(State.ALARM, Kind.ALARM, "implausible", why + "; the alarm "
                               "ends at the next plausible measurement or when acknowledged",
                               now, **kw)
        return self._decision(Kind.HELD, "implausible", f"{why} ({gate or 'alarm'})", now,
                              **kw)

    def _correct(self, wanted: float, now: float, kw: dict[str, Any], note: str = ""
                 ) -> Decision:
        """Write (or propose) ``wanted`` (offset units), within the step and cumulative
        limits and the CNC's resolution."""
        s = self.settings
        writing = not (s.shadow or self.writes_blocked)
        # Writing, the limit is on the CNC's own total; proposing, on our bookkeeping.
        cnc = self.persisted.cnc_offset_mm()
        if writing and cnc is None:
            self._law.clear()
            return self._decision(Kind.HELD, "cnc_total_unknown", "the CNC's total wear offset "
                                  "has not been read yet: no offset until it is (the "
                                  "cumulative limit is checked against it)", now, **kw)
        cum = cnc if writing else self.persisted.cumulative_mm
        step, limited = clip_step(s, wanted, cum)
        self._law.clear()
        if step == 0.0:
            if limited:  # already at the cumulative limit in this direction
                return self._decision(
                    Kind.LIMIT, "limit", f"{note}the cumulative offset {cum * 1000:+.1f} um is at "
                    f"its limit of {s.max_total_mm * 1000:.0f} um: change or re-measure the "
                    "tool, then reset", now, **kw)
            return self._decision(Kind.HELD, "below_resolution", f"offset "
                                  f"{wanted * 1000:+.3f} um is below the CNC's resolution of "
                                  f"{s.offset_resolution_mm * 1000:g} um", now, **kw)
        clipped = "" if abs(step - wanted) < 1e-12 else \
            f" (clipped from {wanted * 1000:+.2f} um)"
        own = self.persisted.cumulative_mm
        if not writing:
            why = "shadow mode" if s.shadow else f"writes blocked ({self.writes_blocked})"
            return self._decision(Kind.PROPOSED, "proposed", f"{note}{why}: offset "
                                  f"{step * 1000:+.2f} um proposed, not written{clipped}",
                                  now, offset_mm=step, after_mm=own + step, **kw)
        p = self.persisted
        p.offset_seq += 1
        p.pending_seq, p.pending_offset_mm = p.offset_seq, step
        p.pending_total_before_mm, p.pending_measurement_seq = None, kw.get("measurement_seq")
        p.state = State.PENDING.value
        return self._decision(Kind.WRITE, "write", f"{note}write offset {step * 1000:+.2f} um"
                              f"{clipped}",
                              now, offset_mm=step, offset_seq=self.persisted.offset_seq,
                              after_mm=own + step, **kw)

    def acknowledge_alarm(self, now: float, who: str = "") -> Decision:
        """Leave the plausibility alarm (it also ends by itself at the next plausible
        measurement)."""
        if self.state is not State.ALARM:
            return self._decision(Kind.HELD, "no_alarm", f"no alarm to acknowledge "
                                  f"({self.state.value})", now, who=who)
        self.persisted.state = State.ACTIVE.value
        self._law.clear()
        return self._decision(Kind.ACKNOWLEDGED, "acknowledged", "alarm acknowledged", now,
                              who=who)

    def reset(self, now: float, who: str = "", insert: bool = False) -> Decision:
        """A reset (after a tool change): the gauge's cumulative offset back to 0, leave
        STOPPED or ALARM; the CNC's total at the next reading becomes the reference of the
        cumulative limit. Refused while an offset's fate is unknown. ``insert``: a person
        recorded an insert change (its wear offset zeroed at the CNC), logged as such."""
        if self.state in (State.PENDING, State.UNCERTAIN):
            return self._decision(Kind.HELD, "reset_unsettled",
                                  f"{_RESET[insert][0]} refused: offset "
                                  f"{self.persisted.pending_seq} is still unsettled", now,
                                  who=who)
        before = self.persisted.cumulative_mm
        self.persisted.cumulative_mm = 0.0
        self.persisted.state = State.ACTIVE.value
        self.persisted.baseline_mm = None
        self.dead.estimator.forget()  # a new insert's level: no step of the gauge's
        self._law.clear()
        # Parts cut before the reset (a new insert) say nothing of the process after it.
        self._law.restart(now)
        return self._decision(Kind.RESET, "insert_change" if insert else "reset",
                              _RESET[insert][1], now, before_mm=before, after_mm=0.0, who=who)

    def note_settings(self, what: str, now: float, who: str) -> Decision:
        """Record a change of a setting outside the controller (for the audit trail)."""
        return self._decision(Kind.SETTINGS, "other_settings", what, now, who=who)

    def refuse_reset(self, now: float, who: str, why: str) -> Decision:
        """Record a reset that was asked for and not carried out."""
        return self._decision(Kind.REFUSED, "reset_refused", f"reset refused: {why}", now,
                              who=who)


_RESET = {
    False: ("reset", "compensation reset: cumulative offset back to 0; the CNC's total at the "
            "next reading is the new baseline"),
    True: ("insert change", "insert change recorded: the process is estimated again from the "
           "new insert's parts, nothing corrected before they are measured; cumulative offset "
           "back to 0, the CNC's total at the next reading (its wear offset zeroed) is the new "
           "baseline")}
"""What a reset is called and its log's text, and those of an insert change a person
recorded."""


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
            State.ALARM: "plausibility alarm: waiting for a plausible measurement or an "
                         "acknowledgement",
            State.PENDING: f"waiting for the CNC to acknowledge offset {pending_seq}",
            State.UNCERTAIN: f"offset {pending_seq} was not acknowledged: holding until the "
                             "CNC's registers settle it"}.get(state, "")

