"""A stepped shaft under the laser, part after part: what a simulated camera shows when the
gauge measures a part feature by feature (part to part).

The laser rests ``dwell_s`` on each segment in turn, then the next part comes. A segment's
diameter is its nominal, plus the wear of the tool that finishes it (its own rate, a new
insert every ``insert_every_min``), plus its deflection, plus the part's scatter (one draw a
part and segment, so that the frames of a segment agree as a real part's do), plus where
its tool was set up (``setup_mm``: no insert sits exactly where the last one did) and the
wear offsets the CNC cut the part with (given by the caller: a part is cut before the gauge
sees it, with the offsets in force when it was cut).

Pure: time in, a diameter out. Lengths in mm of diameter.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    """One diameter of the part, and the tool that finishes it."""

    diameter_mm: float
    tool: int = 1
    deflection_mm: float = 0.0


@dataclass(frozen=True)
class SteppedPart:
    """The parts the laser sees (see the module's docstring)."""

    segments: tuple[Segment, ...]
    dwell_s: float = 3.0
    wear_um_per_min: tuple[tuple[int, float], ...] = ((1, 0.4),)
    """Each tool's wear on the diameter, um a minute."""
    insert_every_min: float = 30.0
    part_sigma_mm: float = 0.0015
    seed: int = 0
    setup_mm: tuple[tuple[int, float], ...] = ()
    """Each tool's setting-up error on the diameter, mm (a tool not named: none)."""

    def __post_init__(self) -> None:
        if not self.segments or self.dwell_s <= 0:
            raise ValueError("a stepped part needs segments and a dwell above 0 s")
        rates = dict(self.wear_um_per_min)
        missing = sorted({s.tool for s in self.segments} - set(rates))
        if missing:
            raise ValueError(f"no wear rate for tools {missing} (wear_um_per_min)")

    def part_at(self, t_s: float) -> int:
        """Which part (0, 1, ...) is under the laser ``t_s`` seconds from the start."""
        return int(max(t_s, 0.0) // (self.dwell_s * len(self.segments)))

    def at(self, t_s: float, offsets_mm: Mapping[int, float] | None = None) -> float:
        """The diameter under the laser ``t_s`` seconds from the start, the part cut with
        each tool's wear offset ``offsets_mm`` (mm of diameter; a tool not named: none)."""
        part, into = divmod(max(t_s, 0.0), self.dwell_s * len(self.segments))
        index = min(int(into // self.dwell_s), len(self.segments) - 1)
        seg = self.segments[index]
        moved = dict(self.setup_mm).get(seg.tool, 0.0) + (offsets_mm or {}).get(seg.tool, 0.0)
        minutes = t_s / 60.0
        if self.insert_every_min > 0:
            minutes %= self.insert_every_min
        wear = dict(self.wear_um_per_min)[seg.tool] * minutes / 1000.0
        scatter = np.random.default_rng((self.seed, int(part), index)).normal(
            0.0, self.part_sigma_mm) if self.part_sigma_mm > 0 else 0.0
        return seg.diameter_mm + seg.deflection_mm + wear + float(scatter) + moved

    @property
    def tools(self) -> list[int]:
        """The tools that finish the part."""
        return sorted({s.tool for s in self.segments})

    @classmethod
    def from_json(cls, spec: str) -> SteppedPart:
        """From JSON: ``{"segments": [{"diameter_mm": 30, "tool": 1}, ...], "dwell_s": 3,
        "wear_um_per_min": {"1": 0.4, "2": 0.8}, ...}`` (ValueError naming what is wrong)."""
        try:
            doc = json.loads(spec)
            segments = tuple(Segment(**s) for s in doc.pop("segments"))
            wear = tuple((int(k), float(v)) for k, v in doc.pop("wear_um_per_min",
                                                                  {"1": 0.4}).items())
            setup = tuple((int(k), float(v)) for k, v in doc.pop("setup_mm", {}).items())
            return cls(segments, wear_um_per_min=wear, setup_mm=setup, **doc)
        except (json.JSONDecodeError, KeyError, TypeError, AttributeError) as err:
            raise ValueError(f"not a stepped part ({err}); e.g. "
                             '\'{"segments": [{"diameter_mm": 30, "tool": 1}], '
                             '"dwell_s": 3, "wear_um_per_min": {"1": 0.4}}\'') from None
