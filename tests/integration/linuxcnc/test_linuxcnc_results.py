"""The part program reads the gauge's results back: LinuxCNC's simulated lathe runs the shipped
sample program deploy/linuxcnc/nc/shaftgauge_inspect.ngc, which asks for each feature measured
through deploy/linuxcnc/nc/shaftgauge_measure.ngc (mb2hal, register map version 5), waits for
each answer, and stops on a part out of tolerance.

The gauge is the service itself on the simulated rig camera, a two-feature job in force. The
test plays the lathe's laser: when the program asks for a feature, the camera looks at that
feature of the part being made (its diameters below). One LinuxCNC per machine: these tests
run one at a time (tests/conftest.py, ``machine``).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from drivers.plc.registers import BY_NAME
from service.api.app import create_app
from service.serve import Children, build
from tests.integration.linuxcnc.test_linuxcnc_pull import LinuxCnc
from tests.unit.service.conftest import TECHNICIAN, make_settings

JOB = {"part_number": "SH-4711", "name": "two steps", "features": [
    {"number": 1, "name": "journal", "nominal_mm": 30.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 1},
    {"number": 2, "name": "seat", "nominal_mm": 25.0, "tol_upper_mm": 0.05,
     "tol_lower_mm": -0.05, "tool": 2}]}
PARTS = [{1: 30.01, 2: 24.99}, {1: 30.0, 2: 25.09}, {1: 29.99, 2: 25.0}]
"""Each part's feature diameters, mm: the second's seat is 90 um over (tolerance +-50)."""


class Laser:
    """The lathe's laser: each new request for feature 1 starts the next part; the camera
    shows the requested feature of the part being made."""

    def __init__(self, gauge) -> None:
        self.gauge, self.part, self.asked = gauge, -1, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        bank, last = self.gauge.modbus.bank, (0, 0)
        while not self._stop.wait(0.005):
            request = (bank.get("measure_feature"), bank.get("measure_request"))
            if request[1] == 0 or request == last:
                continue
            last = request
            feature = request[0]
            if feature == 1:
                self.part += 1
            self.asked.append((self.part, feature))
            self.gauge.camera.diameter_mm = PARTS[min(self.part, len(PARTS) - 1)][feature]

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@pytest.fixture(scope="module")
def gauge_and_lathe(tmp_path_factory) -> Iterator[tuple[TestClient, LinuxCnc]]:
    tmp = tmp_path_factory.mktemp("results")
    gauge, _ = build(make_settings(tmp), Children())
    with TestClient(create_app(gauge)) as client:
        client.gauge = gauge
        r = client.post("/api/v1/jobs", headers={"X-API-Key": TECHNICIAN},
                        json={"document": JOB, "activate": True})
        assert r.status_code == 201, r.text
        cnc = LinuxCnc(tmp / "run", gauge.modbus.port)
        cnc.start()
        try:
            yield client, cnc
        finally:
            cnc.stop()


def test_the_sample_program_measures_each_feature_and_stops_on_a_part_out(gauge_and_lathe
                                                                         ) -> None:
    client, cnc = gauge_and_lathe
    laser = Laser(client.gauge)
    try:
        answer = cnc.ask(do="run", path=str(cnc.run_dir / "nc" / "shaftgauge_inspect.ngc"),
                         timeout_s=120.0)
    finally:
        laser.stop()
    # The second part's seat is out: the program stopped there, its third part never begun.
    assert cnc.ask(do="pin", name="motion.analog-out-09")["value"] == 2, answer
    assert laser.asked == [(0, 1), (0, 2), (1, 1), (1, 2)], laser.asked
    assert any("part out of tolerance" in e for e in answer["errors"]), answer
    bank = client.gauge.modbus.bank
    assert (bank.get("measured_feature"), bank.get("measured_verdict"),
            bank.get("part_verdict")) == (2, 2, 2)
    assert abs(bank.get("measured_value") / 1e4 - 25.09) < 0.005
    # The first part, finished when the second began: in tolerance, each feature measured.
    parts = client.get("/api/v1/parts").json()["items"]
    first = [p for p in parts if p["serial"] == "SH-4711-g1"]
    assert first and first[0]["verdict"] == "ok", parts
    assert [f["verdict"] for f in first[0]["features"]] == ["ok", "ok"]


def test_the_subroutine_reads_each_answer_and_a_refusal(gauge_and_lathe) -> None:
    """Called by hand (MDI), as a program would: the answer's verdict and the feature's
    diameter; a feature the gauge cannot measure in time (the camera unplugged): refused,
    and the reason says nothing was measured."""
    client, cnc = gauge_and_lathe
    client.gauge.camera.diameter_mm = 30.02
    answer = cnc.ask(do="mdi", lines=["o<shaftgauge_measure> call [1]",
                                      "M68 E9 Q[#<_value> * 1000 + #<_sg_reason>]"])
    assert answer["ok"] and not answer["errors"], answer
    assert cnc.ask(do="pin", name="motion.analog-out-09")["value"] == 1000  # in, no reason
    client.gauge.camera.unplug()
    try:
        cnc.ask(do="mdi", lines=["o<shaftgauge_measure> call [1]",
                                 "M68 E9 Q[#<_value> * 1000 + #<_sg_reason>]"])
    finally:
        client.gauge.camera.plug()
    assert cnc.ask(do="pin", name="motion.analog-out-09")["value"] == 3001  # nothing measured
    assert BY_NAME["measure_request"].address == 183  # the mb2hal transaction's registers
