"""The surface's roundness in the running service: the run-out tracker's frames measured about
the surface's own centre (``runout_track.FormFrames``) made into its form every few seconds,
off the event loop (a form of 36 frames costs tens of milliseconds: on the loop, the
registers would wait for it). One owner of the figure; the status, the registers and the
plant read it."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from service.measure.form import Roundness
from service.runtime.calibration import CalibrationContext

log = logging.getLogger("shaftgauge.form")


class FormWatch:
    """Owns the latest roundness of the surface under the laser.

    Parameters
    ----------
    context : CalibrationContext
        Where the run-out tracker (and its frames) of the calibration in force are.
    upr : int
        The roundness filter's undulations per revolution (ISO 12181: 15 or 50).
    period_s : float
        How often the form is made again while new frames come.
    """

    def __init__(self, context: CalibrationContext, upr: int = 50, period_s: float = 2.0
                 ) -> None:
        self.context, self.upr, self.period_s = context, upr, period_s
        self.latest: Roundness | None = None
        self._seen: tuple[int, int] | None = None

    async def run(self) -> None:
        """Make the form again whenever frames came since; runs until cancelled."""
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(self.period_s)
            in_use = self.context.in_use
            tracker = in_use.runout if in_use is not None else None
            if tracker is None or tracker.runout is None:
                self.latest, self._seen = None, None
                continue
            seen = (id(tracker), tracker.form.added)
            if seen == self._seen:
                continue
            try:
                self.latest = await loop.run_in_executor(None, tracker.form.roundness,
                                                         self.upr)
            except Exception:  # keep the watch: a bug here must not end the service's form
                log.exception("roundness")
                continue
            self._seen = seen

    def status(self) -> dict[str, Any] | None:
        """JSON-ready: RONt, the reference circle, the harmonics and the dominant lobing, or
        why not (None while the run-out is not known)."""
        r = self.latest
        if r is None:
            return None
        if not r.ok:
            return {"ok": False, "reason": r.reason}
        return {"ok": True, "upr": self.upr, "radius_mm": r.radius_mm, "ront_mm": r.ront_mm,
                "ront_uncertainty_mm": r.ront_uncertainty_mm, "lobes": r.dominant_order,
                "odd_lobing": r.odd_lobing,
                "harmonics": [{"order": h.order, "amplitude_mm": h.amplitude_mm,
                               "phase_deg": h.phase_deg,
                               "amplitude_uncertainty_mm": h.amplitude_uncertainty_mm}
                              for h in r.harmonics[:8]],
                "profile_deg": [round(float(x), 2) for x in r.profile_deg[::4]],
                "profile_mm": [round(float(x), 7) for x in r.profile_mm[::4]]}
