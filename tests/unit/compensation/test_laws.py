"""The law interface: chosen once for the settings, each law answers an estimate or a hold
(never a value to be told apart by its type)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from service.compensation import CompensationSettings
from service.compensation.laws import (
    REVERSAL_NULL_BANDS,
    Estimate,
    Hold,
    PredictiveLaw,
    WindowLaw,
    law_of,
)

WINDOW = CompensationSettings(law="window", window=3, gain=0.5, dead_time_measurements=1,
                              dead_time_s=0.0, nominal_mm=30.0)


def test_the_settings_choose_the_law() -> None:
    assert isinstance(law_of(WINDOW), WindowLaw)
    assert isinstance(law_of(replace(WINDOW, law="predictive")), PredictiveLaw)


def test_the_window_holds_through_its_dead_time_and_filling_then_estimates() -> None:
    law = law_of(WINDOW)
    law.applied(0.004, 10.0)  # an offset: its dead time starts
    answers = [law.estimate(0.006, 0.001, 10.0 + k, 10.0 + k, 0.0, 0.0, 0.002)
               for k in range(1, 5)]
    assert [a.code for a in answers[:3] if isinstance(a, Hold)] == [
        "dead_time", "filling_window", "filling_window"]
    assert answers[3] == Estimate(pytest.approx(0.006), 0.5, 0.002)


def test_the_predictive_law_forecasts_with_the_offsets_applied_and_is_surer_to_reverse(
) -> None:
    law = law_of(replace(WINDOW, law="predictive", dead_time_measurements=0))
    first = law.estimate(0.006, 0.001, 1.0, 1.0, 0.0, 0.0, 0.002)
    assert isinstance(first, Hold) and first.code == "starting"
    got = law.estimate(0.006, 0.001, 2.0, 2.0, 0.0, 0.0, 0.002)
    assert isinstance(got, Estimate) and got.gain == 1.0
    assert got.deviation_mm == pytest.approx(0.006, abs=1e-4)
    # With an offset applied that took the last one's direction, a reversal needs more.
    again = law.estimate(0.006, 0.001, 3.0, 3.0, 0.0, +0.002, 0.002)
    assert isinstance(again, Estimate)
    assert again.null_mm == pytest.approx(REVERSAL_NULL_BANDS * got.null_mm)
