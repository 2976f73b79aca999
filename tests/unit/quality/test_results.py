"""The "feature measured" handshake and the verdict codes the part program reads back
(service.quality.results), against what each case must give."""

from __future__ import annotations

from service.quality import results
from service.quality.parts import FeatureResult, PartRecord
from service.quality.results import IN, INCOMPLETE, NONE, OUT, UNDER_WAY, Answer, MeasureHandshake


def test_a_request_is_answered_after_its_good_measurements_of_the_feature() -> None:
    h = MeasureHandshake(measurements=3, answer_within_s=5.0)
    assert h.measured(1, "", 0.0, 0.0) is None  # nothing asked: nothing answered
    assert h.request(7, 1, 10.0)
    assert not h.request(7, 1, 10.1)  # the same request written again (mb2hal every cycle)
    assert h.measured(1, "", 10.1, 10.1) is None
    assert h.measured(2, "", 10.2, 10.2) is None  # another feature's counts for nothing
    assert h.measured(None, "uncertain", 10.3, 10.3) is None
    assert h.measured(1, "", 10.4, 10.4) is None
    assert h.measured(1, "", 10.5, 10.5) == Answer(7, 1, 0)
    assert not h.open and h.measured(1, "", 10.6, 10.6) is None and h.tick(99.0) is None
    assert h.request(8, 1, 11.0)  # a new number opens a new one, counted afresh
    assert h.measured(1, "", 11.1, 11.1) is None
    # Frames taken before the request, published after it, count for nothing.
    for _ in range(5):
        assert h.measured(1, "", 10.9, 11.2) is None
    assert h.measured(1, "", 11.2, 11.3) is None
    assert h.measured(1, "", 11.3, 11.4) == Answer(8, 1, 0)


def test_a_request_not_measured_in_time_is_refused_with_the_last_reason() -> None:
    h = MeasureHandshake(measurements=2, answer_within_s=5.0)
    h.request(1, 2, 0.0)
    assert h.tick(4.9) is None
    assert h.tick(5.0) == Answer(1, 2, results.BY_NAME["nothing_measured"].code)
    h.request(2, 2, 10.0)
    h.measured(None, "no_stripe", 10.5, 10.5)
    h.measured(2, "", 11.0, 11.0)
    assert h.measured(None, "not_concentric", 15.0, 15.0) == Answer(
        2, 2, results.BY_NAME["not_concentric"].code)
    h.request(3, 2, 20.0)
    assert h.measured(None, "no_feature", 25.0, 25.0) == Answer(
        3, 2, results.BY_NAME["no_feature"].code)
    assert h.request(3, 1, 30.0)  # the same number for another feature is a new request
    # 0: none. It drops the request waiting and forgets the number: the same one again
    # (a program started again) is a new request.
    assert h.request(0, 0, 31.0) and not h.open and h.tick(99.0) is None
    assert not h.request(0, 0, 31.1)
    assert h.request(3, 1, 32.0) and h.open


def test_every_measurement_status_but_ok_has_a_reason_code() -> None:
    from service.measure.result import Status

    codes = [r.code for r in results.REFUSALS]
    assert len(set(codes)) == len(codes) and 0 not in codes
    for status in Status:
        if status is not Status.OK:
            assert status.value in results.BY_NAME, status


def test_the_verdicts_of_a_feature_and_a_part() -> None:
    def res(d, verdict):
        return FeatureResult(1, "journal", 30.0, d, 0.001, 3, verdict, -0.01, 0.01)

    assert results.feature_verdict(None) == NONE
    assert results.feature_verdict(res(None, "missing")) == NONE
    assert results.feature_verdict(res(30.0, "ok")) == IN
    assert results.feature_verdict(res(30.02, "above")) == OUT

    def part(verdict):
        return PartRecord("P-1", 0.0, "P", (), verdict)

    assert results.part_verdict(None, False) == UNDER_WAY
    assert results.part_verdict(part("incomplete"), False) == UNDER_WAY
    assert results.part_verdict(part("incomplete"), True) == INCOMPLETE
    assert results.part_verdict(part("out"), False) == OUT  # as soon as one feature is out
    assert results.part_verdict(part("ok"), False) == IN
