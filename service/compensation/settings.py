"""The compensation settings: bands, law and limits, in a CNC programmer's words.

Lengths in mm of diameter unless named otherwise. The bands, from the inside out
(``docs/integrating.md`` puts Siemens' and Renishaw's names beside these):

- ``deadband_mm``, the **null band**: a correction smaller than this is not made;
- ``mean_value_band_mm``, the **mean-value band**: a measurement within it of the process
  estimate goes into the mean value; beyond it, it is set aside until the next one says
  outlier (dropped) or step (followed at once);
- ``tol_lower_mm``/``tol_upper_mm``, the **workpiece tolerance**: a part outside it is
  flagged, and the tool is still corrected;
- ``plausibility_mm``, the **plausibility limit** (a dimension-difference check): a deviation
  beyond it is held with an alarm, which ends by itself with the next plausible measurement;
- ``safe_area_mm``, the **safe area**: beyond it the controller stops until a person resets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal

BOUNDS = {"nominal_mm": 2000.0, "tol_upper_mm": 10.0, "deadband_mm": 1.0,
          "mean_value_band_mm": 5.0, "plausibility_mm": 10.0, "safe_area_mm": 10.0,
          "max_step_mm": 1.0, "max_total_mm": 5.0, "window": 1000,
          "dead_time_measurements": 100_000, "dead_time_s": 3600.0, "max_age_s": 3600.0}
"""The largest value of each setting a machine could need (a shaft of 2 m, a wear offset of
5 mm in all, a dead time of an hour): anything beyond is a typing error, refused with its
name, and would switch a limit off (a cumulative limit of 1e308 is none)."""
TOL_LOWER_MIN_MM = -10.0

PLAUSIBILITY_TOLERANCES = 5.0
"""With no ``plausibility_mm`` set: this many times the wider side of the tolerance (within
the safe area)."""


@dataclass(frozen=True)
class CompensationSettings:
    """Tuning of the controller. Lengths in mm of diameter unless named otherwise.

    Attributes
    ----------
    nominal_mm : float or None
        Nominal diameter of the current feature; None holds everything.
    tol_upper_mm, tol_lower_mm : float
        Workpiece tolerance as deviations from nominal (upper >= 0 >= lower): a part outside
        it is flagged (fault bit, dashboard, plant) and the tool is still corrected.
    law : {'predictive', 'window'}
        ``predictive`` (the default): every measurement counts, tagged with the offsets in
        force when its surface was cut; the process without compensation is followed by a
        robust double EWMA and the total offset set to cancel its forecast where the next
        correction will show. The dead time then says when an applied offset becomes
        visible, not how long to wait. ``window``: a measuring cycle's mean value: wait out
        the dead time after a correction, fill the window, correct ``gain`` of its median or
        mean.
    judge : {'frame', 'segment'}
        What a law takes as one measurement. ``frame`` (the default): each frame measured.
        ``segment``: with a job, the frames of one feature in a row fused into one value (a
        part's segment under the laser; ``service.compensation.segments``), so that a part
        counts once and the dead time is counted in segments; for a gauge that sees each
        part's features in turn. Without a job, frames.
    gain : float
        The **feedback** (0-1]: ``predictive``: the share of each measurement taken into the
        process estimate (a mean value over about ``2 / gain - 1`` parts; Siemens' ``1/_K``);
        ``window``: the share of the filtered deviation corrected at once (Renishaw's F).
    trend_gain : float
        ``predictive``: the share of each change of the process estimate taken into its
        trend, the wear per part (0: a single EWMA, which lags behind linear wear).
    window : int
        ``window``: the **mean-value count**, good measurements in the filter.
    filter : {'median', 'mean'}
        ``window``: how the window is combined: the median, or the mean weighted by
        1 / uncertainty^2.
    deadband_mm : float
        The **null band**: no correction while the correction wanted (``window``: the
        filtered deviation) is within +-deadband.
    mean_value_band_mm : float
        ``predictive``: the **mean-value band** around the process estimate; a measurement
        beyond it is set aside until the next confirms a step or leaves it an outlier. 0
        (the default): four robust scales of the process's own scatter, estimated from the
        measurements, never less than the null band.
    plausibility_mm : float or None
        The **plausibility limit**: a deviation from nominal beyond it (a broken tool, a
        wrong part, a wrong setpoint) writes nothing and raises an alarm that ends by itself
        at the next plausible measurement (or when acknowledged). None: five times the wider
        side of the tolerance, within the safe area.
    safe_area_mm : float
        A deviation beyond this stops the controller until a person resets.
    max_step_mm : float
        Largest single offset, in offset units as sent (see ``programming``).
    max_total_mm : float
        Largest cumulative offset, in offset units.
    dead_time_measurements, dead_time_s : int, float
        After a correction, the next measurements within both limits were cut before it
        (the cut has to pass under the gauge first): ``window`` ignores them, ``predictive``
        counts the correction as in flight for them.
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
    deadband_mm: float = 0.001
    gain: float = 0.3
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
    law: Literal["window", "predictive"] = "predictive"
    judge: Literal["frame", "segment"] = "frame"
    trend_gain: float = 0.15
    mean_value_band_mm: float = 0.0
    plausibility_mm: float | None = None

    def plausibility(self) -> float:
        """The plausibility limit in force (mm of diameter)."""
        if self.plausibility_mm is not None:
            return self.plausibility_mm
        wider = max(self.tol_upper_mm, -self.tol_lower_mm)
        return min(PLAUSIBILITY_TOLERANCES * wider, self.safe_area_mm)

    def problems(self) -> list[str]:
        """What is inconsistent or beyond what a machine could need, each naming the setting
        (empty when fine)."""
        p = [f"{name} must be at most {top:g}" for name, top in BOUNDS.items()
             if getattr(self, name) is not None and getattr(self, name) > top]
        finite = all(math.isfinite(v) for v in (
            self.tol_upper_mm, self.tol_lower_mm, self.deadband_mm, self.gain,
            self.max_step_mm, self.max_total_mm, self.dead_time_s, self.safe_area_mm,
            self.max_uncertainty_fraction, self.max_age_s, self.offset_resolution_mm,
            self.mean_value_band_mm, self.plausibility()))
        if not finite:
            return ["settings: every number must be finite"]
        if self.nominal_mm is not None and not (math.isfinite(self.nominal_mm)
                                                and self.nominal_mm > 0):
            p.append("nominal_mm must be a positive diameter")
        if self.tol_lower_mm < TOL_LOWER_MIN_MM:
            p.append(f"tol_lower_mm must be at least {TOL_LOWER_MIN_MM:g}")
        if not self.tol_lower_mm <= 0 <= self.tol_upper_mm or \
                self.tol_upper_mm == self.tol_lower_mm:
            p.append("tolerance must satisfy tol_lower_mm <= 0 <= tol_upper_mm, not both 0")
        wider = max(self.tol_upper_mm, -self.tol_lower_mm)
        p += [f"{name} must be {bound}"
              for name, bound in law_problems(self.gain, self.trend_gain).items()]
        if self.window < 1:
            p.append("window must be at least 1")
        if self.filter not in ("median", "mean"):
            p.append("filter must be 'median' or 'mean'")
        if not 0 <= self.deadband_mm < wider:
            p.append("deadband_mm must be >= 0 and inside the tolerance")
        if self.mean_value_band_mm != 0 and not \
                self.deadband_mm <= self.mean_value_band_mm <= self.plausibility():
            p.append("mean_value_band_mm must be 0 (from the data) or between deadband_mm "
                     "and the plausibility limit")
        if not 0 < self.max_step_mm <= self.max_total_mm:
            p.append("max_step_mm must be > 0 and <= max_total_mm")
        if self.safe_area_mm <= wider:
            p.append("safe_area_mm must be larger than the tolerance")
        elif not wider < self.plausibility() <= self.safe_area_mm:
            p.append("plausibility_mm must be beyond the tolerance and within safe_area_mm")
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
        if self.judge not in ("frame", "segment"):
            p.append("judge must be 'frame' or 'segment'")
        return p


def law_problems(gain: float, trend_gain: float) -> dict[str, str]:
    """A law's gains out of the bounds the laws take, as {field: the bound}: the one check of
    the settings and of a job's tools (a trend gain of 1 would make the trend a copy of the
    last step, and the predictor refuses it)."""
    p = {}
    if not (math.isfinite(gain) and 0 < gain <= 1):
        p["gain"] = "within (0, 1]"
    if not (math.isfinite(trend_gain) and 0 <= trend_gain < 1):
        p["trend_gain"] = "within [0, 1)"
    return p


RANGES = {"gain": "(0, 1]", "trend_gain": "[0, 1)", "max_uncertainty_fraction": "(0, 1]",
          "tol_upper_mm": "0 to 10, above tol_lower_mm", "tol_lower_mm": "-10 to 0",
          "nominal_mm": "> 0, at most 2000; none: nothing judged",
          "deadband_mm": ">= 0, inside the tolerance",
          "mean_value_band_mm": "0 (from the data), or deadband to plausibility limit",
          "plausibility_mm": "beyond the tolerance, within safe_area_mm; none: the default",
          "safe_area_mm": "beyond the tolerance, at most 10",
          "max_step_mm": "> 0, at most max_total_mm and 1",
          "offset_resolution_mm": "> 0, at most max_step_mm", "offset_sign": "+1 or -1",
          "window": "1 to 1000", "max_age_s": "> 0, at most 3600"}
"""Each setting's range in words where ``problems`` checks more than ``BOUNDS`` (the table
of the manual's; ``problems`` is the check)."""
UNITS = {"_mm": "mm", "_s": "s", "_measurements": "measurements"}


def attribute_docs() -> dict[str, str]:
    """Each setting's description, from the class docstring's Attributes (numpydoc): its
    first sentence, in Markdown."""
    out: dict[str, str] = {}
    names: list[str] = []
    for line in (CompensationSettings.__doc__ or "").split("Attributes")[1].splitlines()[2:]:
        if line.startswith("    ") and not line.startswith("        ") and " : " in line:
            names = [n.strip() for n in line.split(" : ")[0].split(",")]
            for n in names:
                out[n] = ""
        elif line.startswith("        ") and names:
            for n in names:
                out[n] = (out[n] + " " + line.strip()).strip()
    return {n: text.split(". ")[0].rstrip(".").replace("``", "`") for n, text in out.items()}


def markdown_table() -> str:
    """The ``[compensation]`` settings as a Markdown table: type, range, default, unit and
    what each is (the text ``docs/integrating.md`` must contain; a test checks it)."""
    docs = attribute_docs()
    lines = ["| setting | type | range | default | unit | what it is |",
             "|---|---|---|---|---|---|"]
    for f in fields(CompensationSettings):
        typed = str(f.type)
        choices = typed.startswith("Literal")
        kind = "text" if choices else typed.split(" ")[0]
        top = BOUNDS.get(f.name)
        span = RANGES.get(f.name) or ("" if top is None else f">= 0, at most {top:g}")
        if not span and choices:
            span = typed.removeprefix("Literal[").removesuffix("]").replace("'", '"')
        if not span and typed == "bool":
            span = "true or false"
        unit = next((u for suffix, u in UNITS.items() if f.name.endswith(suffix)), "")
        default = "none" if f.default is None else str(f.default).lower() \
            if isinstance(f.default, bool) else repr(f.default).replace("'", '"')
        lines.append(f"| `{f.name}` | {kind} | {span} | {default} | {unit} | "
                     f"{docs.get(f.name, '')} |")
    return "\n".join(lines) + "\n"
