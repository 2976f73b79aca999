"""What the registers show the CNC: the latest measurement, the offsets of the job's entries,
the feature and the job in force, the results for the part program, and the status and fault
bits from a snapshot every ``REFRESH_S`` (the pure ``service.runtime.status_words``)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from drivers.plc.registers import (
    ENTRY_BLOCKS,
    FEATURE_BLOCKS,
    FaultBit,
    RegisterBank,
    mm_to_units,
)
from service.compensation import Decision
from service.measurement_record import Feature, MeasurementRecord
from service.quality.parts import FeatureResult
from service.quality.results import REFUSED, feature_verdict, part_verdict
from service.runtime.compensating import CompensationService
from service.runtime.job_service import JobService
from service.runtime.status_words import StatusSnapshot, form_words, status_words

log = logging.getLogger("shaftgauge.modbus")

REFRESH_S = 0.2


class RegisterView:
    """The only writer of what the gauge shows in the register bank (the CNC's own writes
    and the pull handshake's request block aside).

    Parameters
    ----------
    bank : RegisterBank
        The registers the Modbus server serves.
    compensation : CompensationService
        Whose channels in force each entry's block shows.
    """

    def __init__(self, bank: RegisterBank, compensation: CompensationService) -> None:
        self.bank, self.compensation = bank, compensation
        self.jobs: JobService | None = None
        self._proposed: dict[tuple[int | None, int | None], int] = {}  # (tool, entry): units
        self._offsets_shown: dict[str, int] = {}     # what the offsets' registers hold
        self._results_shown: dict[str, int] = {}     # ... and the results' (but the seqs)

    def publish(self, record: MeasurementRecord) -> None:
        """The latest measurement."""
        self.bank.set_many({"diameter": mm_to_units(record.diameter_mm),
                            "uncertainty": mm_to_units(record.uncertainty_mm),
                            "measurement_seq": record.seq & 0xFFFFFFFF,
                            "measurement_age": 0})

    def set_sequence(self, seq: int) -> None:
        """The sequence number before any measurement (it never goes back)."""
        self.bank.set("measurement_seq", seq & 0xFFFFFFFF)

    def decided(self, d: Decision) -> None:
        """A compensation decision: the offsets' registers."""
        if d.offset_mm is not None:
            self._proposed[d.tool, d.entry] = mm_to_units(d.offset_mm)
        self._show_offsets()

    def _show_offsets(self) -> None:
        """Each entry's block from the channels in force (map v5); the gauge-wide registers
        from the one entry's, or *no value* in a job of several entries."""
        in_force = self.compensation.in_force()
        none = mm_to_units(None)
        blocks = [(e, ch.controller, self._proposed.get((e.tool, e.number), none))
                  for e, ch in in_force]
        _, one, proposed = blocks[0] if len(blocks) == 1 else (None, None, none)
        update = {"cumulative_offset": mm_to_units(None if one is None else one.cumulative_mm),
                  "offset_seq": max(c.persisted.offset_seq for _, c, _ in blocks) & 0xFFFFFFFF,
                  "proposed_offset": proposed}
        for k in range(1, ENTRY_BLOCKS + 1):
            e, c, proposed = blocks[k - 1] if k <= len(blocks) else (None, None, none)
            update.update({
                f"entry{k}_tool": e.tool if e else 0,
                f"entry{k}_number": (e.number or 0) if e else 0,
                f"entry{k}_proposed": proposed,
                f"entry{k}_offset_seq": c.persisted.offset_seq & 0xFFFFFFFF if c else 0,
                f"entry{k}_cumulative": mm_to_units(c.cumulative_mm if c else None)})
        # Every measurement's decision comes here: write only what changed.
        changed = {k: v for k, v in update.items() if self._offsets_shown.get(k) != v}
        if changed:
            self.bank.set_many(changed)
            self._offsets_shown.update(changed)

    def set_feature(self, feature: Feature) -> None:
        """Nominal and tolerances of the feature in view (``JobService.feature_in_view``)."""
        self.bank.set_many({"nominal": mm_to_units(feature.nominal_mm),
                            "tol_upper": mm_to_units(feature.tol_upper_mm),
                            "tol_lower": mm_to_units(feature.tol_lower_mm)})

    def command_done(self, command: int) -> None:
        """A command carried out: ``command`` cleared, ``last_command`` it, ``command_seq``
        counted on."""
        seq = (self.bank.get("command_seq") + 1) & 0xFFFF
        self.bank.set_many({"command": 0, "last_command": int(command), "command_seq": seq})

    def show_jobs(self, jobs: JobService) -> None:
        """Show the job registers (map v4) from ``jobs`` (told of each change:
        ``job_changed``)."""
        self.jobs = jobs
        self.job_changed()

    def job_changed(self) -> None:
        """The job in force or the feature named or measured changed: its registers, the
        feature's nominal and tolerances, and the entry blocks."""
        self._show_offsets()  # the job's entries, each in its block
        jobs = self.jobs
        if jobs is not None:
            self.set_feature(jobs.feature_in_view())
            self.bank.set_many({"job": 0 if jobs.stored is None else jobs.stored.number & 0xFFFF,
                                "feature": jobs.selected or 0})

    def show_results(self) -> None:
        """The results for the part program (map v5) from ``JobService.results``: the part's
        verdict, each feature's block, the answer to the last "feature measured" request;
        each block's sequence number, and ``result_seq``, moved when what it shows moved."""
        if self.jobs is None:
            return
        r = self.jobs.results()
        features = r.job.features if r.job is not None else ()
        got = {f.feature: f for f in r.part.features} if r.part is not None else {}
        update = {"part_verdict": part_verdict(r.part, r.finished), "part": r.number & 0xFFFF,
                  "features": len(features)}
        moved_blocks = []
        # The blocks in use, and those in use before (cleared): the rest stand at 0.
        in_use = max(len(features), self._results_shown.get("features", FEATURE_BLOCKS))
        for k in range(1, in_use + 1):
            f = features[k - 1] if k <= len(features) else None
            res = got.get(f.number) if f is not None else None
            verdict = feature_verdict(res)
            reason = r.refused.get(f.number, 0) if f is not None and not verdict else 0
            block = {f"feature{k}_number": f.number if f else 0,
                     f"feature{k}_verdict": REFUSED if reason else verdict,
                     f"feature{k}_reason": reason,
                     f"feature{k}_part": r.number & 0xFFFF if res is not None else 0,
                     **_result_words(f"feature{k}_", res)}
            if any(self._results_shown.get(n) != v for n, v in block.items()):
                moved_blocks.append(k)
            update.update(block)
        if r.answer is not None:
            verdict = feature_verdict(r.answered) if not r.answer.reason else REFUSED
            update.update({"measured_feature": r.answer.feature, "measured_verdict": verdict,
                           "measured_reason": r.answer.reason,
                           **_result_words("measured_", None if r.answer.reason
                                           else r.answered)})
        changed = {k: v for k, v in update.items() if self._results_shown.get(k) != v}
        seq = r.answer.seq if r.answer is not None else 0  # 0: no answer (none asked)
        if self.bank.get("measured_seq") != seq:
            changed["measured_seq"] = seq  # in the same write as what it answers
        if not changed:
            return
        self._results_shown.update({k: v for k, v in changed.items() if k != "measured_seq"})
        for k in moved_blocks:
            changed[f"feature{k}_seq"] = (self.bank.get(f"feature{k}_seq") + 1) & 0xFFFF
        changed["result_seq"] = (self.bank.get("result_seq") + 1) & 0xFFFF
        self.bank.set_many(changed)

    async def refresh(self, snapshot: Callable[[], StatusSnapshot]) -> None:
        """Status, faults and form from ``snapshot()`` every ``REFRESH_S``, until cancelled;
        a "feature measured" request whose time ran out with no measurement to end it (the
        camera away) answered."""
        while True:
            await asyncio.sleep(REFRESH_S)
            if self.jobs is not None:
                self.jobs.tick(time.time())
            try:
                snap = snapshot()
                status, faults, age_ms = status_words(snap)
            except Exception:  # keep the loop: a bug here must not freeze the registers
                log.exception("status registers")
                continue
            update = {"status": int(status), "faults": int(faults), "measurement_age": age_ms,
                      **form_words(snap)}
            if faults & FaultBit.STALE_MEASUREMENT:  # a stale diameter is no diameter
                update["diameter"] = mm_to_units(None)
            self.bank.set_many(update)


def _result_words(prefix: str, res: FeatureResult | None) -> dict[str, int]:
    """A feature's result as ``<prefix>value``, ``deviation``, ``uncertainty`` (0.1 um) and,
    for a block, ``measurements``."""
    value = res.diameter_mm if res is not None else None
    words = {f"{prefix}value": mm_to_units(value),
             f"{prefix}deviation": mm_to_units(None if value is None or res is None
                                               else value - res.nominal_mm),
             f"{prefix}uncertainty": mm_to_units(res.uncertainty_mm if res else None)}
    if prefix.startswith("feature"):
        words[f"{prefix}measurements"] = res.n if res is not None else 0
    return words
