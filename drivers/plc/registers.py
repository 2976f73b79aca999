"""The Modbus register map the CNC polls, and a thread-safe bank of its values.

One table (``REGISTERS``) defines every register; ``docs/modbus-register-map.md`` is checked
against it by a test. Addresses are 0-based. 32-bit values take two registers; their word
order is configurable (big-endian words, high word first, by default). Diameters and offsets
are signed 32-bit integers in 0.1 um; ``NO_VALUE`` (0x80000000) means "no value".

Version 2 adds the pull handshake (``drivers.plc.pull``) for a CNC that can only poll: the
offset request the gauge posts and the report the CNC writes back, every entry one unsigned
16-bit register (what mb2hal and many PLCs' Modbus clients can read and write).

Version 3 adds form and position: the run-out (TIR and its phase) and roundness (RONt, the
dominant lobing) of the surface under the laser, with the spindle's angle known.

Version 4 adds the whole part: the job in force, the feature under the laser and the CNC's
part counter, each written by the CNC, and the tool in the pull handshake (``request_tool``,
``cnc_tool``; each adds into its block's check word, so a CNC written for version 3, leaving
them 0, computes the same checks). A CNC written for version 3 reads and writes what it did,
and the gauge behaves as it did for a job with one tool.

Version 5 makes the offset entry the unit of correction (a tool and the offset number the
correction goes to: Fanuc's offset number, Siemens' D, LinuxCNC's wear entry). The pull
request names its entry (``request_entry``, 0 the tool's own) and the report the entry it
was called for (``cnc_entry``); both add into their block's check word, so a CNC written for
version 4 computes the same checks for a tool's own entry and refuses (a torn request to it)
one for another entry. A version 5 CNC says so in ``cnc_version``; the gauge posts a request
for another entry only to one that does. A block for each offset entry of the job in force
(``ENTRY_BLOCKS``, in the job's order of entries) gives its tool, its offset number, the offset
its controller proposed last, that offset's sequence number and its cumulative offset. In a
job of several entries the gauge-wide ``proposed_offset`` and ``cumulative_offset`` read *no
value*: each entry's are in its block.
"""

from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass

NO_VALUE = -0x80000000  # 0x80000000 as a signed 32-bit integer
TEST_PATTERN = 0x12345678
MAP_VERSION = 5
UM_PER_UNIT = 0.1  # 0.1 um per count


class WordOrder(enum.StrEnum):
    """Order of the two 16-bit words of a 32-bit value."""

    BIG = "big"        # high word at the lower address (Modbus convention, the default)
    LITTLE = "little"  # low word first (some PLCs)


class RegisterType(enum.StrEnum):
    """Data type of a register entry."""

    U16 = "uint16"
    I32 = "int32"
    U32 = "uint32"

    @property
    def words(self) -> int:
        """Registers it takes."""
        return 1 if self is RegisterType.U16 else 2


@dataclass(frozen=True)
class Register:
    """One entry of the map."""

    name: str
    address: int
    kind: RegisterType
    unit: str
    writable: bool
    description: str


def _r(name: str, address: int, kind: RegisterType, unit: str, description: str,
       writable: bool = False) -> Register:
    return Register(name, address, kind, unit, writable, description)


U16, I32, U32 = RegisterType.U16, RegisterType.I32, RegisterType.U32

ENTRY_BLOCKS = 16
"""Offset entries with a block of their own: as many as a job may have (``MAX_ENTRIES``)."""
ENTRY_BLOCK_BASE = 54
ENTRY_BLOCK_WORDS = 8
CNC_VERSION = 5
"""What a CNC whose subroutine applies offset entries writes into ``cnc_version``."""


FEATURE_BLOCKS = 32
"""Features with a result block of their own: as many as a job may have (``MAX_FEATURES``)."""
RESULTS_BASE = ENTRY_BLOCK_BASE + ENTRY_BLOCKS * ENTRY_BLOCK_WORDS
FEATURE_BLOCK_BASE = RESULTS_BASE + 16
FEATURE_BLOCK_WORDS = 12


def _feature_block(k: int) -> tuple[Register, ...]:
    """The result block of the job's ``k``-th feature (in its order of features)."""
    a = FEATURE_BLOCK_BASE + FEATURE_BLOCK_WORDS * (k - 1)
    return (
        _r(f"feature{k}_number", a, U16, "number", f"the job's feature {k} (in its order), as "
           "the job numbers it; 0 none"),
        _r(f"feature{k}_verdict", a + 1, U16, "code", f"its verdict in the part `feature{k}_part`"
           f": 0 not measured yet, 1 in tolerance, 2 out, 3 refused (`feature{k}_reason`)"),
        _r(f"feature{k}_reason", a + 2, U16, "code", "why refused (the reason codes below); 0 "
           "none"),
        _r(f"feature{k}_part", a + 3, U16, "number", "the part the result belongs to (as "
           "`part`)"),
        _r(f"feature{k}_value", a + 4, I32, "0.1 um", "its diameter in that part, fused from "
           "its measurements; no value none yet"),
        _r(f"feature{k}_deviation", a + 6, I32, "0.1 um", "that diameter less the feature's "
           "nominal"),
        _r(f"feature{k}_uncertainty", a + 8, I32, "0.1 um", "the standard uncertainty of that "
           "diameter"),
        _r(f"feature{k}_measurements", a + 10, U16, "count", "the measurements fused"),
        _r(f"feature{k}_seq", a + 11, U16, "count", "moves when its result moves (wraps)"),
    )


def _entry_block(k: int) -> tuple[Register, ...]:
    """The block of the job's ``k``-th offset entry."""
    a = ENTRY_BLOCK_BASE + ENTRY_BLOCK_WORDS * (k - 1)
    return (
        _r(f"entry{k}_tool", a, U16, "T number", f"the tool of the job's offset entry {k} (in "
           "its order of entries); 0 none"),
        _r(f"entry{k}_number", a + 1, U16, "offset number", "the offset number its "
           "corrections go to (Fanuc's offset, Siemens' D, LinuxCNC's wear entry); 0 the "
           "tool's own"),
        _r(f"entry{k}_proposed", a + 2, I32, "0.1 um", "the offset its controller proposed "
           "last (also in shadow mode); no value none yet"),
        _r(f"entry{k}_offset_seq", a + 4, U32, "count", "sequence number of that offset"),
        _r(f"entry{k}_cumulative", a + 6, I32, "0.1 um", "its cumulative offset since its "
           "last reset"),
    )


REGISTERS: tuple[Register, ...] = (
    _r("test_pattern", 0, U32, "-", "always 0x12345678: reads 0x1234, 0x5678 with "
       "big-endian words; check your word order with it"),
    _r("map_version", 2, U16, "-", "version of this map (5)"),
    _r("heartbeat", 3, U16, "count", "counts up once a second while the service is "
       "healthy (wraps at 65535); stands still when it is not"),
    _r("status", 4, U16, "bits", "status bits, see below"),
    _r("faults", 5, U16, "bits", "fault bits, see below"),
    _r("diameter", 6, I32, "0.1 um", "latest measured diameter"),
    _r("uncertainty", 8, I32, "0.1 um", "standard uncertainty of the latest diameter"),
    _r("measurement_seq", 10, U32, "count", "sequence number of the latest measurement"),
    _r("measurement_age", 12, U16, "ms", "age of the latest measurement (65535: older)"),
    _r("command_seq", 13, U16, "count", "counts commands carried out (wraps)"),
    _r("nominal", 14, I32, "0.1 um", "nominal diameter of the current feature",
       writable=True),
    _r("tol_upper", 16, I32, "0.1 um", "upper tolerance, deviation above nominal "
       "(>= 0)", writable=True),
    _r("tol_lower", 18, I32, "0.1 um", "lower tolerance, deviation below nominal "
       "(<= 0)", writable=True),
    _r("command", 20, U16, "code", "write 1 measure now, 2 reset compensation, "
       "3 acknowledge alarm; reads 0 once carried out", writable=True),
    _r("last_command", 21, U16, "code", "code of the last command carried out"),
    _r("proposed_offset", 22, I32, "0.1 um", "latest tool-wear offset the controller "
       "proposed (also in shadow mode)"),
    _r("offset_seq", 24, U32, "count", "sequence number of the latest offset sent"),
    _r("offset_ack", 26, U32, "count", "acknowledgement the CNC echoed for it"),
    _r("cumulative_offset", 28, I32, "0.1 um", "sum of the offsets the CNC "
       "acknowledged since the last reset"),
    # The pull handshake (drivers/plc/pull.py): the gauge posts, the CNC polls and reports.
    _r("request_seq", 30, U16, "count", "pull: sequence of the offset request posted "
       "(1-65535, wrapping past 0); 0 none"),
    _r("request_offset", 31, U16, "0.1 um + 32768", "pull: the offset to the diameter, "
       "biased: 32768 is 0, 32868 is +10 um"),
    _r("request_base_hi", 32, U16, "see below", "pull: the CNC total the offset applies "
       "to, high word (as the CNC reported it)"),
    _r("request_base_lo", 33, U16, "see below", "pull: ... low word"),
    _r("request_check", 34, U16, "-", "pull: (request_seq + request_offset + "
       "request_base_hi + request_base_lo + request_tool + request_entry + 0x5A5A) mod "
       "65536"),
    _r("cnc_ack", 35, U16, "count", "pull, written by the CNC: the request sequence it "
       "settled last; 0 none", writable=True),
    _r("cnc_result", 36, U16, "code", "pull, written by the CNC: 1 applied, 2 not "
       "applied (its total was not the request's base)", writable=True),
    _r("cnc_total_hi", 37, U16, "see below", "pull, written by the CNC: its total, high "
       "word", writable=True),
    _r("cnc_total_lo", 38, U16, "see below", "pull, written by the CNC: ... low word",
       writable=True),
    _r("cnc_check", 39, U16, "-", "pull, written by the CNC last: (cnc_ack + cnc_result + "
       "cnc_total_hi + cnc_total_lo + cnc_tool + cnc_entry + 0xA5A5) mod 65536",
       writable=True),
    # Form and position, with the spindle's angle (spindle.source = "encoder").
    _r("runout_tir", 40, I32, "0.1 um", "run-out of the surface under the laser: TIR, "
       "twice its eccentricity (what a dial indicator reads); no value while not known"),
    _r("runout_phase", 42, U16, "0.01 deg", "direction of the eccentricity at spindle angle "
       "0 (0-35999); 65535 while not known"),
    _r("ront", 43, I32, "0.1 um", "roundness RONt of the last revolutions (ISO 12181, 50 "
       "undulations per revolution); no value while not known"),
    _r("lobes", 45, U16, "count", "the form's dominant lobing (3: three lobes); 0 none above "
       "its noise, or not known"),
    # The whole part (version 4): written by the CNC.
    _r("job", 46, U16, "number", "the job to put in force by its number (the same for every "
       "version of a part number: its newest version goes in force); reads the number of the "
       "job in force, 0 none (the single feature of the settings; writing `nominal` ends the "
       "job too)", writable=True),
    _r("feature", 47, U16, "number", "the feature under the laser, as the job numbers it "
       "(1-99); 0: recognised from the diameter", writable=True),
    _r("part_counter", 48, U16, "count", "the CNC's part counter: a new value starts the next "
       "part record (wraps); 0: the gauge counts parts itself", writable=True),
    _r("request_tool", 49, U16, "T number", "pull: the tool the request is for; 0 for the "
       "one tool of a job with one (the tool the CNC compensates, as in version 3)"),
    _r("cnc_tool", 50, U16, "T number", "pull, written by the CNC with its report: the tool "
       "it was called for, whose total and answer the report gives; 0 from a version 3 CNC",
       writable=True),
    # Offset entries (version 5).
    _r("request_entry", 51, U16, "offset number", "pull: the offset entry of the tool the "
       "request is for (Fanuc's offset number, Siemens' D, LinuxCNC's wear entry); 0 the "
       "tool's own"),
    _r("cnc_entry", 52, U16, "offset number", "pull, written by the CNC with its report: the "
       "offset entry it was called for; 0 the tool's own (and from a version 4 CNC)",
       writable=True),
    _r("cnc_version", 53, U16, "-", "pull, written by the CNC: 5 when its subroutine applies "
       "offset entries (requests for another entry than a tool's own are posted only then); "
       "0 from a version 4 CNC", writable=True),
    # Each offset entry of the job in force (version 5): written by the gauge.
    *(reg for k in range(1, ENTRY_BLOCKS + 1) for reg in _entry_block(k)),
    # Results for the part program (version 5): the "feature measured" handshake, the part's
    # verdict, and each feature's result in the part under way.
    _r("measure_feature", RESULTS_BASE, U16, "number", "written by the CNC with "
       "`measure_request`: the feature under the laser to measure (the job's number; it is "
       "the feature named, as `feature`)", writable=True),
    _r("measure_request", RESULTS_BASE + 1, U16, "count", "written by the CNC: a new number "
       "(1-65535, wrapping past 0) asks for `measure_feature` measured; 0 none (drops a "
       "request waiting, and `measured_seq` reads 0)",
       writable=True),
    _r("measured_seq", RESULTS_BASE + 2, U16, "count", "the request answered last: equal to "
       "`measure_request` once it is answered; 0 after `measure_request` 0"),
    _r("measured_feature", RESULTS_BASE + 3, U16, "number", "the feature it answered for"),
    _r("measured_verdict", RESULTS_BASE + 4, U16, "code", "1 in tolerance, 2 out, 3 refused "
       "(`measured_reason` says why)"),
    _r("measured_reason", RESULTS_BASE + 5, U16, "code", "0 measured; else why not (the "
       "reason codes below)"),
    _r("measured_value", RESULTS_BASE + 6, I32, "0.1 um", "the feature's diameter in the part "
       "when answered, fused; no value when refused"),
    _r("measured_deviation", RESULTS_BASE + 8, I32, "0.1 um", "that diameter less its "
       "nominal"),
    _r("measured_uncertainty", RESULTS_BASE + 10, I32, "0.1 um", "its standard uncertainty"),
    _r("part_verdict", RESULTS_BASE + 12, U16, "code", "the part `part`: 0 a feature not "
       "measured yet, 1 every feature in tolerance, 2 a feature out (as soon as one is), 3 "
       "ended without every feature"),
    _r("part", RESULTS_BASE + 13, U16, "number", "the part under way: the CNC's "
       "`part_counter`, or the gauge's own count when the CNC counts none (wraps)"),
    _r("result_seq", RESULTS_BASE + 14, U16, "count", "moves when any result below or the "
       "part's verdict moves (wraps)"),
    _r("features", RESULTS_BASE + 15, U16, "count", "the job's features: the blocks in use"),
    *(reg for k in range(1, FEATURE_BLOCKS + 1) for reg in _feature_block(k)),
)

BY_NAME: dict[str, Register] = {r.name: r for r in REGISTERS}
SIZE = max(r.address + r.kind.words for r in REGISTERS)


def _check_contiguous() -> None:
    pos = 0
    for reg in sorted(REGISTERS, key=lambda r: r.address):
        if reg.address != pos:
            raise AssertionError(f"register map: gap or overlap at {pos} ({reg.name})")
        pos += reg.kind.words


_check_contiguous()


class StatusBit(enum.IntFlag):
    """Bits of the ``status`` register."""

    HEALTHY = 1 << 0
    CAMERA_STREAMING = 1 << 1
    MEASUREMENT_VALID = 1 << 2
    IN_TOLERANCE = 1 << 3
    COMPENSATION_ACTIVE = 1 << 4
    SHADOW_MODE = 1 << 5
    PLC_CONNECTED = 1 << 6
    CALIBRATED = 1 << 7
    RULE_VIOLATION = 1 << 8      # SPC: a run rule fired at the latest subgroup
    RUNOUT_KNOWN = 1 << 9        # the run-out (and the form) of the surface is known


class FaultBit(enum.IntFlag):
    """Bits of the ``faults`` register."""

    CAMERA_LOST = 1 << 0
    NO_MEASUREMENT = 1 << 1
    OUT_OF_TOLERANCE = 1 << 2
    SAFE_AREA_STOP = 1 << 3
    OFFSET_WRITE_FAILED = 1 << 4
    NO_CALIBRATION = 1 << 5
    STALE_MEASUREMENT = 1 << 6
    MASTER_CHECK_DUE = 1 << 7
    GAUGE_STUDY_FAILED = 1 << 8  # the type-1 study failed (Cgk too low) or is overdue
    RUNOUT_BEYOND_LIMIT = 1 << 9  # TIR beyond spindle.max_tir_mm: no offset is written
    NOT_CONCENTRIC = 1 << 10     # off the spindle axis, no angle to measure it: refused


class Command(enum.IntEnum):
    """Codes of the ``command`` register."""

    NONE = 0
    MEASURE_NOW = 1
    RESET_COMPENSATION = 2
    ACKNOWLEDGE_ALARM = 3


def to_words(value: int, kind: RegisterType, order: WordOrder) -> list[int]:
    """Register words of a value (two's complement for int32)."""
    if kind is RegisterType.U16:
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"{value} does not fit uint16")
        return [value]
    lo_lim, hi_lim = (-(1 << 31), (1 << 31) - 1) if kind is RegisterType.I32 else (0, (1 << 32) - 1)
    if not lo_lim <= value <= hi_lim:
        raise ValueError(f"{value} does not fit {kind.value}")
    raw = value & 0xFFFFFFFF
    hi, lo = raw >> 16, raw & 0xFFFF
    return [hi, lo] if order is WordOrder.BIG else [lo, hi]


def from_words(words: list[int], kind: RegisterType, order: WordOrder) -> int:
    """The value of register words."""
    if kind is RegisterType.U16:
        return words[0]
    hi, lo = (words[0], words[1]) if order is WordOrder.BIG else (words[1], words[0])
    raw = (hi << 16) | lo
    if kind is RegisterType.I32 and raw & 0x80000000:
        raw -= 1 << 32
    return raw


def mm_to_units(value_mm: float | None) -> int:
    """mm to 0.1 um counts; None, NaN, infinity or out of range give ``NO_VALUE``."""
    if value_mm is None or not math.isfinite(value_mm):
        return NO_VALUE
    units = round(value_mm * 1000.0 / UM_PER_UNIT)
    return units if -(1 << 31) < units < (1 << 31) else NO_VALUE


def units_to_mm(units: int) -> float | None:
    """0.1 um counts to mm; ``NO_VALUE`` gives None."""
    return None if units == NO_VALUE else units * UM_PER_UNIT / 1000.0


class RegisterBank:
    """The current register values, shared between the service and the Modbus server.

    Thread-safe. Values are set and read by name in their own type; the Modbus server reads
    and writes raw words.
    """

    def __init__(self, order: WordOrder = WordOrder.BIG) -> None:
        self.order = WordOrder(order)
        self._words = [0] * SIZE
        self._lock = threading.Lock()
        self.set("test_pattern", TEST_PATTERN)
        self.set("map_version", MAP_VERSION)
        for name in ("diameter", "uncertainty", "nominal", "proposed_offset",
                     "cumulative_offset", "runout_tir", "ront", "measured_value",
                     "measured_deviation", "measured_uncertainty",
                     *(f"feature{k}_{what}" for k in range(1, FEATURE_BLOCKS + 1)
                       for what in ("value", "deviation", "uncertainty"))):
            self.set(name, NO_VALUE)
        self.set("runout_phase", 0xFFFF)
        self.set("tol_upper", 0)
        self.set("tol_lower", 0)

    def set(self, name: str, value: int) -> None:
        """Set a register (pair) by name."""
        self.set_many({name: value})

    def set_many(self, values: dict[str, int]) -> None:
        """Set several registers at once (a reader never sees half of the update)."""
        encoded = []
        for name, value in values.items():
            reg = BY_NAME[name]
            encoded.append((reg.address, to_words(int(value), reg.kind, self.order)))
        with self._lock:
            for address, words in encoded:
                self._words[address:address + len(words)] = words

    def get(self, name: str) -> int:
        """A register (pair) by name."""
        reg = BY_NAME[name]
        with self._lock:
            words = self._words[reg.address:reg.address + reg.kind.words]
        return from_words(words, reg.kind, self.order)

    def words(self, address: int, count: int) -> list[int]:
        """Raw words."""
        with self._lock:
            return self._words[address:address + count]

    def write_words(self, address: int, words: list[int]) -> None:
        """Store raw words (after the server validated the write)."""
        with self._lock:
            self._words[address:address + len(words)] = list(words)


def markdown_tables() -> str:
    """The register, status-bit, fault-bit and command tables as Markdown (the text that
    ``docs/modbus-register-map.md`` must contain; a test checks it)."""
    lines = ["| address | name | type | unit | access | meaning |",
             "|---:|---|---|---|---|---|"]
    # The blocks of entries and features 2 and on: one line each.
    rest = {ENTRY_BLOCK_BASE + ENTRY_BLOCK_WORDS: (RESULTS_BASE, "entry", ENTRY_BLOCKS,
                                                   "offset entries", ENTRY_BLOCK_WORDS),
            FEATURE_BLOCK_BASE + FEATURE_BLOCK_WORDS: (SIZE, "feature", FEATURE_BLOCKS,
                                                       "features", FEATURE_BLOCK_WORDS)}
    skip_to = 0
    for r in REGISTERS:
        if r.address in rest:
            end, name, n, what, words = rest[r.address]
            lines.append(f"| {r.address}-{end - 1} | `{name}2_*` ... `{name}{n}_*` | | | read "
                         f"| the same block for the job's {what} 2 to {n}, {words} registers "
                         "each |")
            skip_to = end
        if r.address < skip_to:
            continue
        span = str(r.address) if r.kind.words == 1 else f"{r.address}-{r.address + 1}"
        lines.append(f"| {span} | `{r.name}` | {r.kind.value} | {r.unit} | "
                     f"{'read/write' if r.writable else 'read'} | {r.description} |")
    for title, flags in (("status", StatusBit), ("faults", FaultBit)):
        lines += ["", f"`{title}` bits:", "", "| bit | name |", "|---:|---|"]
        lines += [f"| {int(f).bit_length() - 1} | `{f.name.lower()}` |" for f in flags]
    lines += ["", "`command` codes:", "", "| code | command |", "|---:|---|"]
    lines += [f"| {int(c)} | `{c.name.lower()}` |" for c in Command]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(markdown_tables(), end="")
