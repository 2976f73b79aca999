"""The offset in flight: the exchange with the CNC around one offset (checked against the
CNC's fresh total before it goes out, acknowledged, not applied, or uncertain until the CNC's
registers settle it), kept in ``ControllerState``. The base of ``CompensationController``,
which decides what to write. Pure: time passed in."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from service.compensation.exchange import cnc_verdict, effect_mm, limit_veto, same_total
from service.compensation.records import CncReading, ControllerState, Decision, Kind, State
from service.compensation.settings import CompensationSettings


@dataclass
class OffsetBook:
    """An offset's life from the order to write it to its settlement."""

    settings: CompensationSettings = field(default_factory=CompensationSettings)
    persisted: ControllerState = field(default_factory=ControllerState)

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

    # What the controller does when an offset is settled or the CNC's total moved.

    def _forget(self) -> None:
        """Start the filter afresh."""

    def _applied_now(self, effect: float, now: float) -> None:
        """An offset with this effect on the diameter (mm) was applied now."""

    def _changed_at_cnc(self, before_mm: float, total_mm: float, now: float) -> Decision:
        """Someone else moved the CNC's total from ``before_mm`` to ``total_mm`` (offset
        units)."""
        raise NotImplementedError

    def check_before_write(self, offset_seq: int, total_mm: float | None,
                           now: float) -> Decision | None:
        """Just before the pending offset goes out: the CNC's total as read now. None when it
        may be written; otherwise the offset is dropped (never written) and the decision says
        why: the total cannot be read, the offset would take it beyond the limit, or someone
        changed the total at the CNC since the offset was decided (``cnc_total_changed``:
        an insert change, most likely; the change is taken as the reference of the
        measurements from now on)."""
        p = self.persisted
        if p.pending_seq != offset_seq or self.state is not State.PENDING:
            return self._drop(offset_seq, "not_in_flight", "it is not the offset in flight",
                              now)
        seen = None
        if total_mm is not None:
            if p.cnc_total_mm is not None and not same_total(p.cnc_total_mm, total_mm,
                                                             self.settings):
                seen = self._changed_at_cnc(p.cnc_total_mm, total_mm, now)
            p.cnc_total_mm = total_mm
        code, why = limit_veto(self.settings, p, total_mm)
        if code:
            return self._drop(offset_seq, code, why, now,
                              kind=Kind.LIMIT if code == "limit" else Kind.NOT_APPLIED)
        if seen is not None:
            return self._drop(offset_seq, seen.code, f"decided before the change: {seen.reason}",
                              now)
        p.pending_total_before_mm = total_mm
        return None

    def _drop(self, offset_seq: int, code: str, why: str, now: float,
              kind: Kind = Kind.NOT_APPLIED) -> Decision:
        p = self.persisted
        seq = p.pending_measurement_seq if p.pending_seq == offset_seq else None
        if p.pending_seq == offset_seq and self.state is State.PENDING:
            self._settled()
        return self._decision(kind, code, f"offset {offset_seq} not written: {why}", now,
                              offset_seq=offset_seq, measurement_seq=seq)

    def _settled(self) -> None:
        """Nothing in flight any more."""
        p = self.persisted
        p.pending_seq, p.pending_offset_mm, p.pending_total_before_mm = None, None, None
        p.pending_measurement_seq = None
        p.state = State.ACTIVE.value
        self._forget()

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
        # The measurement it answers: the trend ties each offset to it, in either handshake.
        kw: dict[str, Any] = {"offset_mm": step, "offset_seq": offset_seq,
                              "measurement_seq": p.pending_measurement_seq}
        if applied is None:
            p.state = State.UNCERTAIN.value
            return self._decision(Kind.UNCERTAIN, "uncertain", f"{what} not acknowledged"
                                  f"{_colon(detail)}; holding until the CNC's registers settle "
                                  "it, it will not be sent again", now, **kw)
        before = p.cumulative_mm
        self._settled()
        if applied:
            p.cumulative_mm = before + step
            if p.cnc_total_mm is not None:  # until the next reading says otherwise
                p.cnc_total_mm += step
            self._applied_now(effect_mm(self.settings, step), now)
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



def _colon(detail: str) -> str:
    return f": {detail}" if detail else ""
