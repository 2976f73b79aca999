"""A virtual lathe: the diameter a finishing pass cuts follows from the CNC's state, never from
the gauge's bookkeeping.

The diameter cut is the programmed one plus what moves the tool's tip away from where the
CNC believes it is: the insert's wear (a break-in, then a rate per part or per minute that
may rise toward the end of the insert's life; an insert change that resets it; random
chipping steps), the machine's thermal growth (a warm-up curve, a cool-down during a stop,
the warm-up again) and part-to-part scatter; less the wear offset the CNC applies (its total, read
from the CNC: LinuxCNC's tool table, or the push CNC's applied total). Pure: time passes in
calls, chance comes from its own seeded generator, and every part's true diameter is logged.

Two ways of working share the model:

- **part to part**: ``cut_part`` at each part's finishing pass; the gauge measures it when it
  passes (``measured_after`` parts later: the dead time in parts);
- **continuous**: one long shaft, the laser a distance behind the tool; ``cut_at`` gives the
  diameter cut at a time, and the surface under the laser at time t was cut at
  ``t - laser_distance / feed`` (the dead time in seconds).

All diameters and offsets are mm of diameter; an offset's sign is the diameter's (a
positive total makes parts larger, as the gauge's ``offset_sign = +1`` with diameter
programming).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LatheConfig:
    """What the virtual lathe does to the diameter (mm of diameter unless named otherwise).

    Attributes
    ----------
    nominal_mm : float
        The diameter the program cuts with a new insert on a cold machine and no offset.
    wear_per_part_mm, wear_per_min_mm : float
        The insert's wear: the part grows by this much per part cut, or per minute of
        cutting (continuous work).
    break_in_mm, break_in_parts : float
        A new insert's break-in: a further ``break_in_mm (1 - exp(-n / break_in_parts))``
        after ``n`` parts (or minutes) on it: its first micrometres come fast.
    wear_knee_parts, wear_acceleration : float
        Toward the end of its life the wear rate rises: after ``wear_knee_parts`` parts (or
        minutes) on an insert it grows by ``wear_acceleration`` times the base rate every
        ``wear_knee_parts`` more (0: never).
    insert_changes : tuple of int
        Parts (part to part) or whole minutes (continuous) at which a new insert goes in:
        its wear starts from 0 again.
    insert_every : int
        ... and a new insert every this many parts or whole minutes (0: only those listed).
    chip_probability : float
        Chance that the edge chips during a part (per part) or a minute (continuous).
    chip_mm : tuple of float
        A chip's step in the diameter, drawn uniformly (low, high).
    thermal_mm, thermal_tau_min : float
        The machine's warm-up: the diameter moves by ``thermal_mm (1 - exp(-t / tau))``.
    stops : tuple of (int, float)
        Part to part: the machine stands still for so many minutes before that part; it
        cools meanwhile (toward no growth, ``cool_tau_min``) and warms up again after.
    cool_tau_min : float
        How fast it cools while it stands.
    part_sigma_mm : float
        Part-to-part scatter (1 sigma), from material, clamping, temperature of the part.
    cycle_min : float
        Time a part takes (part to part), minutes.
    feed_mm_per_min, laser_distance_mm : float
        Continuous work: the feed along the shaft and how far behind the tool the laser
        line is: the dead time is ``laser_distance_mm / feed_mm_per_min``.
    """

    nominal_mm: float = 30.0
    wear_per_part_mm: float = 0.0
    wear_per_min_mm: float = 0.0
    break_in_mm: float = 0.0
    break_in_parts: float = 5.0
    wear_knee_parts: float = 0.0
    wear_acceleration: float = 0.0
    insert_changes: tuple[int, ...] = ()
    insert_every: int = 0
    chip_probability: float = 0.0
    chip_mm: tuple[float, float] = (0.002, 0.006)
    thermal_mm: float = 0.0
    thermal_tau_min: float = 20.0
    stops: tuple[tuple[int, float], ...] = ()
    cool_tau_min: float = 30.0
    part_sigma_mm: float = 0.002
    cycle_min: float = 1.0
    feed_mm_per_min: float = 100.0
    laser_distance_mm: float = 50.0

    def wear_after(self, n: float, rate_mm: float) -> float:
        """An insert's wear after ``n`` parts (or minutes) on it at the base ``rate_mm``."""
        wear = rate_mm * n
        if self.break_in_mm:
            wear += self.break_in_mm * (1.0 - math.exp(-n / self.break_in_parts))
        if self.wear_knee_parts > 0 and n > self.wear_knee_parts:
            # The rate grows linearly past the knee: its integral.
            wear += rate_mm * self.wear_acceleration * (n - self.wear_knee_parts) ** 2 \
                / (2.0 * self.wear_knee_parts)
        return wear

    @property
    def dead_time_min(self) -> float:
        """Continuous work: from the cut to the laser, minutes."""
        return self.laser_distance_mm / self.feed_mm_per_min


@dataclass
class CutPart:
    """One part (or one sample of a continuous cut) as it came off the lathe."""

    index: int
    time_min: float
    diameter_mm: float        # the true diameter cut
    offset_mm: float          # the CNC's total wear offset in force when it was cut
    wear_mm: float            # the insert's wear then (chips included)
    thermal_mm: float


@dataclass
class VirtualLathe:
    """The lathe. ``cut_part(offset_mm)`` / ``cut_at(t, offset_mm)`` with the CNC's total
    wear offset as the CNC holds it; ``log`` keeps every part."""

    config: LatheConfig = field(default_factory=LatheConfig)
    seed: int = 0
    log: list[CutPart] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._wear = 0.0
        self._chips = 0.0
        self._part = 0
        self._on_insert = 0       # parts cut on the insert in the holder
        self._minute = 0
        self._stopped_min = 0.0   # part to part: minutes stood still so far
        self._changed_at: list[float] = []  # continuous: inserts changed by hand (minutes)
        self._theta = (0.0, 0.0)  # part to part: (time, thermal growth) last worked out

    def thermal_at(self, time_min: float) -> float:
        """The machine's thermal growth at a time, mm of diameter."""
        c = self.config
        return c.thermal_mm * (1.0 - math.exp(-time_min / c.thermal_tau_min)) \
            if c.thermal_tau_min > 0 else c.thermal_mm

    def _new_insert(self) -> None:
        self._wear = 0.0
        self._chips = 0.0
        self._on_insert = 0

    def _thermal_to(self, time_min: float, running: bool) -> float:
        """Part to part: the thermal growth carried forward to ``time_min``, the machine
        running (warming toward ``thermal_mm``) or standing (cooling toward 0)."""
        c = self.config
        t0, theta = self._theta
        target, tau = (c.thermal_mm, c.thermal_tau_min) if running else (0.0, c.cool_tau_min)
        theta = target + (theta - target) * math.exp(-(time_min - t0) / tau) \
            if tau > 0 else target
        self._theta = (time_min, theta)
        return theta

    def _chip(self) -> None:
        c = self.config
        if c.chip_probability > 0 and self._rng.random() < c.chip_probability:
            self._chips += self._rng.uniform(*c.chip_mm)

    def _diameter(self, time_min: float, offset_mm: float, thermal: float | None = None
                  ) -> tuple[float, float, float]:
        c = self.config
        wear = self._wear + self._chips
        thermal = self.thermal_at(time_min) if thermal is None else thermal
        noise = self._rng.normal(0.0, c.part_sigma_mm) if c.part_sigma_mm > 0 else 0.0
        return c.nominal_mm + wear + thermal + noise + offset_mm, wear, thermal

    def cut_part(self, offset_mm: float) -> CutPart:
        """The next part's finishing pass with the CNC's total wear offset ``offset_mm``."""
        c = self.config
        k = self._part
        if self._insert_at(k):
            self._new_insert()
        stop = sum(minutes for at, minutes in c.stops if at == k)
        if stop:  # it cools while it stands
            self._thermal_to(k * c.cycle_min + self._stopped_min, running=True)
            self._stopped_min += stop
            self._thermal_to(k * c.cycle_min + self._stopped_min, running=False)
        time_min = k * c.cycle_min + self._stopped_min
        self._wear = c.wear_after(self._on_insert, c.wear_per_part_mm)
        d, wear, thermal = self._diameter(time_min, offset_mm,
                                          self._thermal_to(time_min, running=True))
        part = CutPart(k, time_min, d, offset_mm, wear, thermal)
        self.log.append(part)
        self._on_insert += 1
        self._chip()
        self._part += 1
        return part

    def cut_at(self, time_min: float, offset_mm: float) -> CutPart:
        """Continuous work: the diameter cut at ``time_min`` (non-decreasing from call to
        call) with the CNC's total ``offset_mm``."""
        c = self.config
        while self._minute <= time_min:  # whole minutes passed: inserts, chips
            if self._insert_at(self._minute):
                self._new_insert()
            if self._minute > 0:
                self._chip()
            self._minute += 1
        self._wear = c.wear_after(time_min - self._last_change(time_min), c.wear_per_min_mm)
        d, wear, thermal = self._diameter(time_min, offset_mm)
        part = CutPart(len(self.log), time_min, d, offset_mm, wear, thermal)
        self.log.append(part)
        return part

    def _insert_at(self, index: int) -> bool:
        """Whether a new insert goes in at this part or whole minute."""
        every = self.config.insert_every
        return index in self.config.insert_changes or (every > 0 and index > 0
                                                      and index % every == 0)

    def change_insert_at(self, time_min: float) -> None:
        """Continuous work: a new insert goes in at ``time_min`` (by hand, not by the
        config's schedule): what is cut from then on has its wear."""
        self._changed_at.append(float(time_min))

    def _last_change(self, time_min: float) -> float:
        every = self.config.insert_every
        changes = [m for m in (*self.config.insert_changes, *self._changed_at)
                   if m <= time_min]
        if every > 0 and time_min >= every:
            changes.append(math.floor(time_min / every) * every)
        return float(max(changes)) if changes else 0.0


@dataclass
class LaserView:
    """What the camera sees of a continuous cut: the surface under the laser line at time t
    was cut at ``t - dead_time`` with the CNC's total wear offset in force then.

    The CNC's totals come in as it reports them (``cnc_total``); ``diameter_mm(now_s)`` is
    the diameter under the laser, one sample of the lathe per ``sample_s`` (the surface's
    scatter changes from sample to sample, not from frame to frame). Pure: time is passed in
    (seconds from the start of the cut), and every sample lands in the lathe's log.
    """

    lathe: VirtualLathe
    sample_s: float = 0.5
    _totals: list[tuple[float, float]] = field(default_factory=lambda: [(-math.inf, 0.0)])
    _sample: tuple[int, CutPart] | None = None

    @property
    def dead_time_s(self) -> float:
        """From the cut to the laser line, s."""
        return self.lathe.config.dead_time_min * 60.0

    def cnc_total(self, now_s: float, total_mm: float) -> None:
        """The CNC's total wear offset (mm of diameter) is ``total_mm`` from ``now_s`` on."""
        if total_mm != self._totals[-1][1]:
            self._totals.append((max(now_s, self._totals[-1][0]), float(total_mm)))

    def total_at(self, time_s: float) -> float:
        """The CNC's total in force at ``time_s``."""
        for t, total in reversed(self._totals):
            if t <= time_s:
                return total
        return self._totals[0][1]

    def cut_under_laser(self, now_s: float) -> CutPart:
        """The sample of the surface under the laser at ``now_s`` (non-decreasing)."""
        k = math.floor(max(now_s, 0.0) / self.sample_s)
        if self._sample is None or self._sample[0] < k:
            cut_s = max(k * self.sample_s - self.dead_time_s, 0.0)
            self._sample = (k, self.lathe.cut_at(cut_s / 60.0, self.total_at(cut_s)))
        return self._sample[1]

    def diameter_mm(self, now_s: float) -> float:
        """The diameter under the laser at ``now_s``, mm."""
        return self.cut_under_laser(now_s).diameter_mm
