"""A job (part program): the part, its features (diameters) and the tools that finish them.

A feature is what a CNC programmer dimensions on the drawing: a number, a name, a nominal
and its tolerance, the tool (T number) that finishes it, and, as Siemens' measuring cycles
keep per feature, an **empirical value** (a fixed bias, from a CMM comparison, taken off
every deviation) and its own bands. A tool's law (gain, trend gain) is the tool's, since
one tool takes one correction however many features it finishes (``combine``).

Pure: documents in, ``Job`` out, every refusal naming its field (``features[2].nominal_mm``).
Lengths in mm of diameter.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, fields, replace
from typing import Any

from service.compensation.settings import BOUNDS, CompensationSettings, law_problems

MAX_FEATURES = 32
MAX_TOOLS = 16
MAX_TOOL_NUMBER = 9999
"""T numbers as a lathe's tool table holds them (LinuxCNC's wear entries are 10000 + n)."""
MAX_ENTRIES = 16
"""Offset entries a job corrects (tools' own and features' own together)."""
MAX_ENTRY_NUMBER = 65_535
"""Offset numbers as CNCs number them (Fanuc's 1-999, Siemens' D 1-32000, LinuxCNC's wear
entries 10000 + n), within a register of the map (``request_entry``)."""
MAX_TEXT = 80
"""The longest part number or name, characters (what a drawing's title block holds; the
exports cut them further to their own fields)."""
SINGLE_FEATURE = "single feature"
"""The part number and name of the settings' own feature as a job (``Job.single``)."""
RECOGNITION_WINDOW_MM = 0.5
"""A diameter within this of exactly one feature's nominal is that feature (when the CNC does
not name it)."""


class JobError(ValueError):
    """A job document that cannot be used; the message names the field."""


@dataclass(frozen=True)
class JobFeature:
    """One diameter of the part.

    Attributes
    ----------
    number : int
        1-99, as the CNC names it (register ``feature``, Renishaw's W1).
    name : str
        As on the drawing ("bearing seat").
    nominal_mm, tol_upper_mm, tol_lower_mm : float
        The nominal diameter and its tolerance (upper >= 0 >= lower, not both 0).
    tool : int
        The T number of the tool that finishes it.
    empirical_mm : float
        Taken off every deviation of this feature before it counts for its tool (a CMM
        comparison's bias, a known deflection of a slender segment).
    deadband_mm, mean_value_band_mm, plausibility_mm : float or None
        This feature's bands; None: the job's defaults (``CompensationSettings``).
    entry : int or None
        The offset entry its correction goes to, when not the tool's own: another offset on
        the same insert (Fanuc's offset number, T0211; Siemens' cutting edge D; LinuxCNC's
        wear entry). Features that share an entry take one correction; a feature on an
        entry of its own is held to its own nominal however far it drifts from the tool's
        other features (a slender segment deflecting more as the insert wears).
    """

    number: int
    name: str
    nominal_mm: float
    tol_upper_mm: float
    tol_lower_mm: float
    tool: int
    empirical_mm: float = 0.0
    deadband_mm: float | None = None
    mean_value_band_mm: float | None = None
    plausibility_mm: float | None = None
    entry: int | None = None


@dataclass(frozen=True, order=True)
class OffsetEntry:
    """What the CNC corrects: a tool (T number) and the offset number the correction goes to
    (None: the tool's own entry). One controller, one cumulative offset, one set of limits
    and one handshake an entry."""

    tool: int
    number: int | None = None

    def __str__(self) -> str:
        return f"T{self.tool}" if self.number is None else f"T{self.tool} offset {self.number}"


@dataclass(frozen=True)
class JobTool:
    """A tool of the job: its number, where its wear is kept, and its law.

    Attributes
    ----------
    number : int
        The T number.
    wear_entry : int or None
        The offset entry its features' corrections go to when they name none (LinuxCNC's
        wear entry ``10000 + n`` with the ``index_lathe_tool_with_wear`` remap, Fanuc's
        offset number); None: the tool's own entry.
    gain, trend_gain : float or None
        The tool's law (see ``CompensationSettings``); None: the job's defaults.
    max_disagreement_mm : float or None
        Its features' deviations may differ this much before the tool is held (a taper, a
        deflection): None: half the narrowest tolerance among them.
    programming : {'diameter', 'radius'} or None
        Whether its entries hold diameter or radius values (a CNC's tool table may keep one
        tool's offsets in radius); None: the settings' ``programming``.
    offset_sign : {+1, -1} or None
        +1 when a positive offset in its entries makes the part larger (an external
        diameter), -1 when smaller (a bore); None: the settings' ``offset_sign``.
    """

    number: int
    wear_entry: int | None = None
    gain: float | None = None
    trend_gain: float | None = None
    max_disagreement_mm: float | None = None
    programming: str | None = None
    offset_sign: int | None = None


@dataclass(frozen=True)
class Recognition:
    """Which feature a diameter is, or why none: ``feature`` is None with a ``reason``."""

    feature: JobFeature | None
    reason: str = ""


@dataclass(frozen=True)
class Job:
    """A part program's features and tools (see the module's docstring)."""

    part_number: str
    name: str
    features: tuple[JobFeature, ...]
    tools: tuple[JobTool, ...] = ()
    recognition_window_mm: float = RECOGNITION_WINDOW_MM

    # ---- reading ------------------------------------------------------------------------

    def feature(self, number: int) -> JobFeature:
        """The feature ``number`` (KeyError naming the job's numbers when there is none)."""
        for f in self.features:
            if f.number == number:
                return f
        raise KeyError(f"feature {number} is not in job {self.part_number!r} (its features: "
                       f"{', '.join(str(f.number) for f in self.features)})")

    def tool(self, number: int) -> JobTool:
        """The tool ``number``'s entry (its defaults when the job lists no entry for a tool
        its features name; KeyError when no feature names it)."""
        if number not in self.tool_numbers():
            raise KeyError(f"tool {number} finishes no feature of job {self.part_number!r} "
                           f"(its tools: {', '.join(map(str, self.tool_numbers()))})")
        return next((t for t in self.tools if t.number == number), JobTool(number))

    def tool_numbers(self) -> tuple[int, ...]:
        """The tools that finish a feature, in the order they first appear."""
        return tuple(dict.fromkeys(f.tool for f in self.features))

    def features_of(self, tool: int) -> tuple[JobFeature, ...]:
        """The features ``tool`` finishes."""
        return tuple(f for f in self.features if f.tool == tool)

    def entry_of(self, feature: JobFeature) -> OffsetEntry:
        """The offset entry ``feature``'s correction goes to: the one it names, else its
        tool's (``tools[].wear_entry``, else the tool's own)."""
        if feature.entry is not None:
            return OffsetEntry(feature.tool, feature.entry)
        return OffsetEntry(feature.tool, next((t.wear_entry for t in self.tools
                                               if t.number == feature.tool), None))

    def entries(self) -> tuple[OffsetEntry, ...]:
        """The offset entries the job corrects, in the order they first appear."""
        return tuple(dict.fromkeys(self.entry_of(f) for f in self.features))

    def features_on(self, entry: OffsetEntry) -> tuple[JobFeature, ...]:
        """The features whose correction goes to ``entry``."""
        return tuple(f for f in self.features if self.entry_of(f) == entry)

    def settings_for(self, feature: JobFeature, base: CompensationSettings
                     ) -> CompensationSettings:
        """``base`` with this feature's nominal, tolerance and bands, its tool's law and its
        entries' convention (diameter or radius, sign)."""
        tool = self.tool(feature.tool)
        own = {"nominal_mm": feature.nominal_mm, "tol_upper_mm": feature.tol_upper_mm,
               "tol_lower_mm": feature.tol_lower_mm, "deadband_mm": feature.deadband_mm,
               "mean_value_band_mm": feature.mean_value_band_mm,
               "plausibility_mm": feature.plausibility_mm, "gain": tool.gain,
               "trend_gain": tool.trend_gain, "programming": tool.programming,
               "offset_sign": tool.offset_sign}
        return replace(base, **{k: v for k, v in own.items()
                                if v is not None or k == "plausibility_mm"})

    def max_disagreement_mm(self, entry: OffsetEntry) -> float:
        """How far the deviations of the features on ``entry`` may differ before it is
        held."""
        set_ = self.tool(entry.tool).max_disagreement_mm
        if set_ is not None:
            return set_
        return 0.5 * min(f.tol_upper_mm - f.tol_lower_mm for f in self.features_on(entry))

    def recognise(self, diameter_mm: float) -> Recognition:
        """The feature whose nominal is within the recognition window of ``diameter_mm``:
        none, or two, is a refusal saying so (never a guess)."""
        if not math.isfinite(diameter_mm):
            return Recognition(None, f"the diameter {diameter_mm} is no number")
        near = sorted((abs(diameter_mm - f.nominal_mm), f.number, f) for f in self.features)
        within = [f for d, _, f in near if d <= self.recognition_window_mm]
        if not within:
            d, _, f = near[0]
            return Recognition(None, f"{diameter_mm:.4f} mm fits no feature of job "
                               f"{self.part_number!r}: the nearest, {f.number} ({f.name}, "
                               f"{f.nominal_mm:g} mm), is {d:.3f} mm away, beyond the "
                               f"recognition window of {self.recognition_window_mm:g} mm")
        if len(within) > 1:
            names = " and ".join(f"{f.number} ({f.nominal_mm:g} mm)" for f in within[:2])
            return Recognition(None, f"{diameter_mm:.4f} mm is within "
                               f"{self.recognition_window_mm:g} mm of features {names}: the "
                               "CNC must name the feature")
        return Recognition(within[0])

    # ---- checking ------------------------------------------------------------------------

    def problems(self, base: CompensationSettings | None = None) -> list[str]:
        """What is wrong, each naming its field (empty when the job can be used)."""
        base = base or CompensationSettings()
        p: list[str] = []
        if not self.part_number.strip():
            p.append("part_number: must not be empty")
        if not 1 <= len(self.features) <= MAX_FEATURES:
            p.append(f"features: 1 to {MAX_FEATURES}, not {len(self.features)}")
        if not 0 < self.recognition_window_mm <= 10.0:
            p.append("recognition_window_mm: must be within (0, 10]")
        numbers = [f.number for f in self.features]
        for i, f in enumerate(self.features):
            where = f"features[{i}]"
            if not 1 <= f.number <= 99:
                p.append(f"{where}.number: 1 to 99, not {f.number}")
            if numbers.count(f.number) > 1:
                p.append(f"{where}.number: {f.number} is given to two features")
            if not 1 <= f.tool <= MAX_TOOL_NUMBER:
                p.append(f"{where}.tool: 1 to {MAX_TOOL_NUMBER}, not {f.tool}")
            if not (math.isfinite(f.empirical_mm) and abs(f.empirical_mm) <= 1.0):
                p.append(f"{where}.empirical_mm: within +-1 mm")
            if f.entry is not None:
                other = next((g.tool for g in self.features
                              if g.entry == f.entry and g.tool != f.tool), None)
                if not 1 <= f.entry <= MAX_ENTRY_NUMBER:
                    p.append(f"{where}.entry: 1 to {MAX_ENTRY_NUMBER}, not {f.entry}")
                elif other is not None:
                    p.append(f"{where}.entry: offset {f.entry} is tool {other}'s too; an "
                             "offset entry corrects one tool")
            # The feature's nominal, tolerance and bands, in force (the base is checked)
            p += [f"{where}.{q}" for q in self.settings_for(f, base).problems()
                  if not q.startswith(("gain", "trend_gain", "programming", "offset_sign"))]
        listed = [t.number for t in self.tools]
        for i, t in enumerate(self.tools):
            where = f"tools[{i}]"
            if listed.count(t.number) > 1:
                p.append(f"{where}.number: tool {t.number} is listed twice")
            if t.number not in self.tool_numbers():
                p.append(f"{where}.number: tool {t.number} finishes no feature")
            if t.wear_entry is not None and not 1 <= t.wear_entry <= MAX_ENTRY_NUMBER:
                p.append(f"{where}.wear_entry: 1 to {MAX_ENTRY_NUMBER}, not {t.wear_entry}")
            own = {"gain": t.gain, "trend_gain": t.trend_gain}
            law = law_problems(base.gain if t.gain is None else t.gain,
                               base.trend_gain if t.trend_gain is None else t.trend_gain)
            p += [f"{where}.{name}: {bound}" for name, bound in law.items()
                  if own[name] is not None]
            if t.programming not in (None, "diameter", "radius"):
                p.append(f"{where}.programming: 'diameter' or 'radius', not "
                         f"{_shown(t.programming)}")
            if t.offset_sign not in (None, 1, -1):
                p.append(f"{where}.offset_sign: +1 or -1, not {t.offset_sign}")
            if t.max_disagreement_mm is not None and not (
                    math.isfinite(t.max_disagreement_mm)
                    and 0 < t.max_disagreement_mm <= BOUNDS["tol_upper_mm"]):
                p.append(f"{where}.max_disagreement_mm: within (0, {BOUNDS['tol_upper_mm']:g}]")
        if len(self.tool_numbers()) > MAX_TOOLS:
            p.append(f"features: at most {MAX_TOOLS} tools, not {len(self.tool_numbers())}")
        if len(self.entries()) > MAX_ENTRIES:
            p.append(f"features: at most {MAX_ENTRIES} offset entries, not "
                     f"{len(self.entries())}")
        return p

    # ---- documents -----------------------------------------------------------------------

    def to_doc(self) -> dict[str, Any]:
        """JSON-ready (``job_from_doc`` reads it back)."""
        return asdict(self)

    @property
    def is_single(self) -> bool:
        """Whether this is the settings' own single feature (``single``), not a stored job."""
        return self.part_number == SINGLE_FEATURE and self.name == SINGLE_FEATURE

    def tuning_problems(self, base: CompensationSettings) -> list[str]:
        """What ``base`` (new tuning: bands, law, limits) would make wrong for a feature of
        this job, each naming the feature (empty when the job holds with it)."""
        return [f"feature {f.number} ({f.name}) of job {self.part_number!r}: {q}"
                for f in self.features for q in self.settings_for(f, base).problems()]

    @classmethod
    def single(cls, settings: CompensationSettings, part_number: str = SINGLE_FEATURE,
               tool: int = 1) -> Job:
        """Today's one feature (the settings' nominal and tolerance) as a job of one feature
        finished by one tool."""
        if settings.nominal_mm is None:
            raise JobError("nominal_mm: a job of one feature needs the nominal")
        return cls(part_number, part_number, (JobFeature(
            1, "diameter", settings.nominal_mm, settings.tol_upper_mm, settings.tol_lower_mm,
            tool),))


def _make(kind: type, doc: Any, where: str) -> Any:
    if not isinstance(doc, dict):
        raise JobError(f"{where}: an object is needed, not {type(doc).__name__}")
    known = {f.name: f for f in fields(kind)}
    unknown = sorted(set(doc) - set(known))
    if unknown:
        raise JobError(f"{where}.{unknown[0]}: not a field of {kind.__name__} (its fields: "
                       f"{', '.join(known)})")
    missing = [n for n, f in known.items() if n not in doc and _required(f)]
    if missing:
        raise JobError(f"{where}.{missing[0]}: missing")
    values = {}
    for name, value in doc.items():
        if not _fits(known[name].type, value):
            raise JobError(f"{where}.{name}: {_shown(value)} is not {known[name].type}")
        why = _text_problem(value) if isinstance(value, str) else ""
        if why:
            raise JobError(f"{where}.{name}: {why}")
        floating = "float" in str(known[name].type) and isinstance(value, int)
        values[name] = float(value) if floating else value
    return kind(**values)


def _shown(value: Any) -> str:
    """A value as a refusal quotes it: its repr, cut short (a refusal echoes no megabyte)."""
    text = ascii(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _required(f: Any) -> bool:
    return f.default is MISSING and f.default_factory is MISSING


def _fits(declared: Any, value: Any) -> bool:
    text = str(declared)
    if value is None:
        return "None" in text
    if isinstance(value, bool):
        return False  # a bool is not a number, and no field is a bool
    if "int" in text and "float" not in text:
        return isinstance(value, int)
    if "float" in text:
        return isinstance(value, int | float) and math.isfinite(float(value))
    if "str" in text:
        return isinstance(value, str)
    return True


def _text_problem(value: str) -> str:
    """Why a name cannot be taken ("" when it can): printable text of at most ``MAX_TEXT``
    characters. A control character would break a line of /metrics or a Q-DAS file (0x0F
    and 0x14 are Q-DAS' own separators); a lone surrogate cannot be stored or sent."""
    if len(value) > MAX_TEXT:
        return f"at most {MAX_TEXT} characters, not {len(value)}"
    bad = next((c for c in value if not c.isprintable()), None)
    if bad is not None:
        return f"printable text only, not U+{ord(bad):04X} at {value.index(bad)}"
    return ""


def job_from_doc(doc: Any, base: CompensationSettings | None = None) -> Job:
    """A job from its JSON document (JobError naming the first bad field, or every problem
    of a job that does not hold together)."""
    if not isinstance(doc, dict):
        raise JobError("job: an object is needed")
    body = {k: v for k, v in doc.items() if k not in ("features", "tools")}
    features = doc.get("features")
    tools = doc.get("tools", [])
    if not isinstance(features, list):
        raise JobError("features: a list of features is needed")
    if not isinstance(tools, list):
        raise JobError("tools: a list is needed")
    body["features"] = tuple(_make(JobFeature, f, f"features[{i}]")
                             for i, f in enumerate(features))
    body["tools"] = tuple(_make(JobTool, t, f"tools[{i}]") for i, t in enumerate(tools))
    job = _make(Job, body, "job")
    problems = job.problems(base)
    if problems:
        raise JobError("; ".join(problems))
    return job


