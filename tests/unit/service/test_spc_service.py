"""The runtime's SPC (events when a rule fires, the feature followed) and the studies' gate
(a failed, an overdue and a missing study), and a study's values from frames received after
it started."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np

from calib_store.gauge_studies import GaugeStudyStore
from service.config import SpcConfig
from service.measurement_record import Feature
from service.runtime.feed import Subscribers
from service.runtime.spc_service import SpcService
from service.runtime.studies import GaugeStudies, StudyPolicy
from tests.integration.plant.test_mqtt import record


async def test_a_rule_that_fires_is_an_event_for_live_subscribers() -> None:
    feature = Feature(30.0, -0.02, 0.02)
    spc = SpcService(SpcConfig(subgroup_size=4, member_spacing=2, every_s=0,
                               baseline_subgroups=5), 10, lambda _: feature)
    q = spc.events.add()
    rng = np.random.default_rng(2)
    values = list(30.0 + rng.normal(0, 0.001, 60)) + [30.01] * 20  # then a 10 um shift
    for i, v in enumerate(values):
        spc(record(i, v)._replace(feature=1))
    assert spc.monitors[1].limits is not None and spc.rule_violation
    ev = await asyncio.wait_for(q.get(), 1)
    assert ev["rules"] and ev["rules"][0]["rule"] == 1 and ev["mean_mm"] > 30.003  # shifted
    assert ev["feature"] == 1
    figures = spc.figures()
    assert figures["nominal_mm"] == 30.0 and figures["usl_mm"] == 30.02
    feature = Feature(31.0, -0.02, 0.02)  # a new nominal: a new baseline
    spc(record(999, 31.0)._replace(feature=1))
    assert spc.monitors[1].limits is None and not spc.rule_violation


def test_each_feature_has_its_own_chart() -> None:
    features = {1: Feature(30.0, -0.02, 0.02), 2: Feature(25.0, -0.01, 0.01)}
    spc = SpcService(SpcConfig(subgroup_size=4, member_spacing=1, every_s=0,
                               baseline_subgroups=5), 10, lambda r: features[r.feature])
    rng = np.random.default_rng(3)
    for i in range(80):  # the laser goes from feature to feature
        n = 1 + (i // 4) % 2
        spc(record(i, features[n].nominal_mm + rng.normal(0, 0.001))._replace(feature=n))
    spc(record(80, 30.0)._replace(feature=None))  # fits no feature: no chart's
    one, two = spc.figures(1), spc.figures(2)
    assert abs(one["mean_mm"] - 30.0) < 0.002 and abs(two["mean_mm"] - 25.0) < 0.002
    assert two["usl_mm"] == 25.01 and one["features"] == [1, 2]
    assert spc.figures()["feature"] == 2  # the one measured last
    try:
        spc.figures(3)
    except KeyError as err:
        assert "features with SPC: [1, 2]" in err.args[0]
    else:
        raise AssertionError("feature 3 has no SPC")
    spc.forget()  # another job
    assert spc.figures()["features"] == []


def study(capable: bool, finished: float) -> dict:
    return {"id": 7, "finished": finished, "state": "done",
            "result": {"capable": capable, "reasons": [] if capable else ["Cgk 0.50 < 1.33"]}}


def gate(policy: StudyPolicy, latest: dict | None) -> GaugeStudies:
    g = GaugeStudies(None, None, None, 10, policy, lambda: None)  # type: ignore[arg-type]
    g._latest = latest
    return g


def test_the_gate_blocks_a_failed_an_overdue_and_a_missing_study() -> None:
    now = time.time()
    assert gate(StudyPolicy(), None).blocking() is None
    assert "no type-1 gauge study" in gate(StudyPolicy(required=True), None).blocking()
    assert "Cgk 0.50" in gate(StudyPolicy(), study(False, now)).blocking()
    assert gate(StudyPolicy(max_age_h=8), study(True, now - 3600)).blocking() is None
    old = gate(StudyPolicy(max_age_h=8), study(True, now - 9 * 3600)).blocking()
    assert "9.0 h old" in old and "study_max_age_h = 8" in old


class _Holds:
    def hold_offsets(self, *args: object, **kwargs: object) -> None:
        pass

    def release_hold(self, owner: str) -> bool:
        return True


async def test_a_study_takes_no_frame_received_before_it_started(tmp_path: Path) -> None:
    class Feed:
        subscribers = Subscribers()

    studies = GaugeStudies(GaugeStudyStore(tmp_path / "g.db"), Feed(), _Holds(),  # type: ignore[arg-type]
                           3, StudyPolicy(), lambda: None)
    sid = studies.start(30.0, 25, 0.04, "tech")
    await asyncio.sleep(0)  # the study subscribes
    now = time.time()
    # Still in the pipeline when the master went in: the part's other diameter.
    for i in range(5):
        Feed.subscribers.publish(record(i, 25.0)._replace(time=now + 0.01, latency_ms=1010.0))
    for i in range(5, 5 + 3 * 25):
        Feed.subscribers.publish(record(i, 30.0 + 0.0001 * (i % 3))._replace(
            time=now + 0.1, latency_ms=5.0))
        await asyncio.sleep(0)
    await asyncio.wait_for(studies._task, 5)  # type: ignore[arg-type]
    done = studies.store.latest_done()  # type: ignore[union-attr]
    assert done is not None and done["id"] == sid
    assert abs(done["result"]["mean"] - 30.0) < 0.001, done["result"]
