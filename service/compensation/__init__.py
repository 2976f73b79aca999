"""Tool-wear compensation: measurements in, tool-wear offsets out, as a CNC's measuring cycle
would, without I/O (time is passed in).

- ``settings``: ``CompensationSettings``, the bands, the law and the limits;
- ``bands``: where a measured part stands (in or out of tolerance, implausible, unsafe);
- ``laws``: the predictive law (a robust double EWMA of the process without compensation)
  and the window law;
- ``exchange``: the offset's arithmetic (step, cumulative limit, resolution) and what the
  CNC's registers say of an offset in flight;
- ``records``: measurements, decisions, the persisted state;
- ``handshake``: an offset's life from the order to write it to its settlement;
- ``controller``: ``CompensationController``, the state machine that ties them;
- ``job``: a part program's features and the tools that finish them;
- ``combine``: how a tool's features make one correction, and when they disagree;
- ``tools``: one controller per tool (``JobCompensation`` routes a feature's measurement).
"""

from service.compensation.bands import PartBand, part_band
from service.compensation.controller import CompensationController, refusal
from service.compensation.exchange import clip_step, cnc_verdict, effect_mm, limit_veto
from service.compensation.laws import Predictor, WindowLaw
from service.compensation.records import (
    QUIET_KINDS,
    CncReading,
    ControllerState,
    Decision,
    Kind,
    MeasurementIn,
    State,
)
from service.compensation.settings import CompensationSettings

__all__ = [
    "QUIET_KINDS", "CncReading", "CompensationController", "CompensationSettings",
    "ControllerState", "Decision", "Kind", "MeasurementIn", "PartBand", "Predictor", "State",
    "WindowLaw", "clip_step", "cnc_verdict", "effect_mm", "limit_veto", "part_band", "refusal",
]
