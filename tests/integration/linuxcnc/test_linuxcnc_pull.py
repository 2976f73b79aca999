"""A real CNC on the other end: LinuxCNC's simulated lathe (Debian's linuxcnc-uspace, headless,
started by deploy/linuxcnc/run-sim.sh) polls the gauge's Modbus server with mb2hal and applies
its offsets through the shipped subroutine deploy/linuxcnc/nc/shaftgauge_comp.ngc, which the
test calls as a part program would, before each finishing pass.

The gauge's side is the service's own: ``GaugeModbusServer`` on its ``RegisterBank``, the
heartbeat, ``PullCnc``. One LinuxCNC per machine: these tests run one at a time.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.plc.client import Outcome
from drivers.plc.pull import PullCnc, read_report
from drivers.plc.registers import RegisterBank, StatusBit
from drivers.plc.server import GaugeModbusServer, run_heartbeat
from drivers.sim.lathe import LatheConfig, VirtualLathe
from service.compensation import (
    CompensationController,
    CompensationSettings,
    ControllerState,
    Decision,
    Kind,
    MeasurementIn,
)
from service.compensation.entries import EntryCompensation
from service.compensation.job import Job, JobFeature, JobTool, OffsetEntry
from service.runtime.offset_channel import OffsetChannel

ROOT = Path(__file__).resolve().parents[3]
RUN_SIM = ROOT / "deploy" / "linuxcnc" / "run-sim.sh"
DRIVER = ROOT / "deploy" / "linuxcnc" / "drive.py"
LINUXCNC_PARTS = "rtapi_app|milltask|linuxcncsvr|/usr/bin/io |mb2hal|shaftgauge_link"


class Gauge:
    """The gauge's Modbus side on a loop of its own thread (the tests talk to LinuxCNC's
    driver synchronously)."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.bank = RegisterBank()
        self.server = GaugeModbusServer(self.bank, port=0)
        self.set_healthy(True)
        self.port = self.run(self.server.start())
        self._beat = self.loop.create_task(run_heartbeat(self.bank, lambda: self.healthy,
                                                         period_s=0.25))
        self.transport = PullCnc(self.bank, ack_timeout_s=0.2)
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()

    def set_healthy(self, healthy: bool) -> None:
        """As the service: healthy in the status bits, and the heartbeat counts only then."""
        self.healthy = healthy
        self.bank.set("status", int(StatusBit.HEALTHY) if healthy else 0)

    def restart_server(self, away_s: float) -> None:
        """The gauge's Modbus server gone for ``away_s``, then back on its port."""
        self.run(self.server.stop())
        time.sleep(away_s)
        self.server = GaugeModbusServer(self.bank, port=self.port)
        self.run(self.server.start())

    def killed_and_restarted(self, away_s: float) -> None:
        """The gauge killed (-9) and started again after ``away_s``: its registers start
        empty, a new transport over them (the service offers its unsettled offset again)."""
        self.run(self.server.stop())
        self.loop.call_soon_threadsafe(self._beat.cancel)
        time.sleep(away_s)
        self.bank = RegisterBank()
        self.set_healthy(True)
        self.server = GaugeModbusServer(self.bank, port=self.port)
        self.run(self.server.start())
        self._beat = asyncio.run_coroutine_threadsafe(self._start_beat(), self.loop).result()
        self.transport = PullCnc(self.bank, ack_timeout_s=0.2)

    async def _start_beat(self) -> asyncio.Task:
        return asyncio.get_running_loop().create_task(
            run_heartbeat(self.bank, lambda: self.healthy, period_s=0.25))

    def run(self, coro):
        if self.loop.is_running():
            return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout=30)
        return self.loop.run_until_complete(coro)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self._beat.cancel)
        self.run(self.server.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=5)


class LinuxCnc:
    """LinuxCNC's simulated lathe in ``run_dir`` and the driver that talks to it."""

    def __init__(self, run_dir: Path, port: int) -> None:
        self.run_dir, self.port = run_dir, port
        self.proc: subprocess.Popen | None = None
        self.driver: subprocess.Popen | None = None

    def start(self) -> None:
        self.log = open(self.run_dir.with_suffix(".log"), "a")  # noqa: SIM115
        self.proc = subprocess.Popen([str(RUN_SIM), str(self.run_dir), "127.0.0.1",
                                      str(self.port)], stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        # Up when the task answers: the driver retries until LinuxCNC's NML channels exist.
        deadline = time.monotonic() + 60
        while True:
            self.driver = subprocess.Popen(["/usr/bin/python3", str(DRIVER)],
                                           stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                           stderr=subprocess.PIPE, text=True,
                                           env=dict(os.environ, HOME=str(self.run_dir)))
            answer = self.ask(do="ready")
            if answer.get("ok"):
                return
            self.driver.kill()
            self.driver.wait()
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError(f"LinuxCNC did not come up: {answer}; see {self.log.name}")
            time.sleep(1.0)

    def ask(self, **request: object) -> dict:
        assert self.driver is not None and self.driver.stdin and self.driver.stdout
        try:
            self.driver.stdin.write(json.dumps(request) + "\n")
            self.driver.stdin.flush()
            line = self.driver.stdout.readline()
        except (BrokenPipeError, OSError) as err:
            return {"ok": False, "error": str(err)}
        return json.loads(line) if line else {"ok": False, "error": "driver ended: "
                                                + (self.driver.stderr.read() or "")[-500:]}

    def call(self) -> int:
        """The shipped subroutine, as a part program calls it; its return value."""
        answer = self.ask(do="call", tool=1)
        assert answer["ok"] and not answer["errors"], answer
        return round(answer["value"])

    def tool_x_mm(self) -> float:
        return self.ask(do="tool", number=1)["x"]

    def stop(self) -> None:
        if self.driver is not None:
            self.driver.stdin.close()
            self.driver.wait(timeout=10)
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            self.proc.wait(timeout=60)
        # Its realtime part and components end after it: wait for them (one LinuxCNC a
        # machine, and the next tests' timing).
        deadline = time.monotonic() + 30
        while subprocess.run(["pgrep", "-f", LINUXCNC_PARTS], capture_output=True,
                             check=False).returncode == 0:
            if time.monotonic() > deadline:
                raise RuntimeError(f"LinuxCNC's processes did not end; see {self.log.name}")
            time.sleep(0.2)
        self.log.close()


@pytest.fixture(scope="module")
def lathe(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Gauge, LinuxCnc]]:
    gauge = Gauge()
    cnc = LinuxCnc(tmp_path_factory.mktemp("linuxcnc") / "run", gauge.port)
    cnc.start()
    try:
        yield gauge, cnc
    finally:
        cnc.stop()
        gauge.close()


def reported(gauge: Gauge, timeout_s: float = 5.0) -> None:
    """Until the CNC's report (mb2hal writes it every cycle) is whole in the registers."""
    deadline = time.monotonic() + timeout_s
    while read_report(gauge.bank) is None:
        assert time.monotonic() < deadline, "no report from the CNC"
        time.sleep(0.05)


def offset_once(gauge: Gauge, cnc: LinuxCnc, offset_mm: float, seq: int) -> Outcome:
    """Post an offset while the part program calls the subroutine; what the gauge made of
    it, settled."""
    gauge.run(gauge.transport.read_cnc())
    pending = asyncio.run_coroutine_threadsafe(gauge.transport.write_offset(offset_mm, seq),
                                               gauge.loop)
    time.sleep(0.05)
    cnc.call()
    result = pending.result(timeout=30)
    if result.outcome is Outcome.UNKNOWN:  # answered after the wait: read the report
        time.sleep(0.3)
        reading = gauge.run(gauge.transport.read_cnc())
        return Outcome.APPLIED if reading.ack_seq == seq else Outcome.NOT_APPLIED
    return result.outcome


def test_the_shipped_subroutine_applies_each_offset_once(lathe) -> None:
    gauge, cnc = lathe
    cnc.call()  # the first look reports the tool's total
    reported(gauge)
    start_x = cnc.tool_x_mm()
    applied = []
    for seq, offset_um in enumerate((-1.2, -0.8, 2.4, -3.1), start=1):
        assert offset_once(gauge, cnc, offset_um / 1000.0, seq) is Outcome.APPLIED
        applied.append(offset_um)
        for _ in range(2):  # later calls find the request settled: nothing more
            cnc.call()
        # The tool table holds a radius: half the diameter's offset, exactly.
        assert cnc.tool_x_mm() == pytest.approx(start_x + sum(applied) / 2000.0, abs=1e-9)
        reading = gauge.run(gauge.transport.read_cnc())
        assert reading.total_mm == pytest.approx(2 * cnc.tool_x_mm(), abs=1e-9)


def test_a_request_for_another_base_is_refused_and_changes_nothing(lathe) -> None:
    """Someone set the tool's offset by hand after the gauge read it: the CNC does not apply
    an offset meant for the old value, and says so."""
    gauge, cnc = lathe
    cnc.call()
    reported(gauge)
    gauge.run(gauge.transport.read_cnc())
    pending = asyncio.run_coroutine_threadsafe(gauge.transport.write_offset(0.002, 100),
                                               gauge.loop)
    hand = cnc.tool_x_mm() + 0.01
    cnc.ask(do="mdi", lines=["G8 G21", f"G10 L1 P1 X{hand:.6f}", "G43"])
    assert cnc.call() == 2
    assert pending.result(timeout=30).outcome in (Outcome.NOT_APPLIED, Outcome.UNKNOWN)
    time.sleep(0.3)
    reading = gauge.run(gauge.transport.read_cnc())
    assert (reading.ack_seq, reading.request_seq) == (0, 0)  # refused: certainly not applied
    assert cnc.tool_x_mm() == pytest.approx(hand, abs=1e-9)


def test_an_unhealthy_gauge_is_not_trusted(lathe) -> None:
    """Its status says so, its heartbeat stands still: the request it posted is not applied
    until it is healthy again, then once."""
    gauge, cnc = lathe
    cnc.call()
    reported(gauge)
    gauge.run(gauge.transport.read_cnc())
    before = cnc.tool_x_mm()
    gauge.set_healthy(False)
    time.sleep(0.6)  # the heartbeat stops
    pending = asyncio.run_coroutine_threadsafe(gauge.transport.write_offset(0.001, 200),
                                               gauge.loop)
    assert cnc.call() == -1
    assert pending.result(timeout=30).outcome is Outcome.UNKNOWN
    assert cnc.tool_x_mm() == before
    gauge.set_healthy(True)
    time.sleep(0.6)
    assert cnc.call() == 1  # trusted again: the request, still posted, applies once
    assert cnc.tool_x_mm() == pytest.approx(before + 0.0005, abs=1e-9)
    assert cnc.call() == 0


def test_linuxcnc_restarted_before_the_gauge_heard_applies_nothing_twice(lathe) -> None:
    """LinuxCNC applied an offset, then restarted (its memory of what it settled gone, its
    tool table kept); the gauge posts the offset again, as after its own restart: the CNC
    finds its total already at base + offset and answers APPLIED without applying it."""
    gauge, cnc = lathe
    cnc.call()
    reported(gauge)
    assert offset_once(gauge, cnc, -0.0016, 300) is Outcome.APPLIED
    after = cnc.tool_x_mm()
    base_mm = round(2 * (after + 0.0008) * 1e4) / 1e4
    cnc.stop()
    cnc.start()
    gauge.run(gauge.transport.resume(300, -0.0016, base_mm))
    assert cnc.call() == 1
    assert cnc.tool_x_mm() == pytest.approx(after, abs=1e-9)
    time.sleep(0.3)
    assert gauge.run(gauge.transport.read_cnc()).ack_seq == 300


def test_the_sample_part_program_takes_the_offset_before_its_finishing_pass(lathe) -> None:
    gauge, cnc = lathe
    cnc.call()
    reported(gauge)
    gauge.run(gauge.transport.read_cnc())
    before = cnc.tool_x_mm()
    pending = asyncio.run_coroutine_threadsafe(gauge.transport.write_offset(-0.002, 400),
                                               gauge.loop)
    time.sleep(0.1)
    part = ROOT / "deploy" / "linuxcnc" / "nc" / "shaftgauge_part.ngc"
    answer = cnc.ask(do="run", path=str(cnc.run_dir / "nc" / part.name))
    assert answer["ok"] and not answer["errors"], answer
    pending.result(timeout=30)
    assert cnc.tool_x_mm() == pytest.approx(before - 0.001, abs=1e-9)
    time.sleep(0.3)
    assert gauge.run(gauge.transport.read_cnc()).ack_seq == 400


def test_the_gauge_away_for_ten_seconds_then_back(lathe) -> None:
    """mb2hal never reconnects by itself: while the gauge is away the subroutine trusts
    nothing; once it is back, shaftgauge_link.py loads mb2hal anew and the offset still
    posted applies, once."""
    gauge, cnc = lathe
    cnc.call()
    reported(gauge)
    gauge.run(gauge.transport.read_cnc())
    before = cnc.tool_x_mm()
    pending = asyncio.run_coroutine_threadsafe(gauge.transport.write_offset(0.0014, 500),
                                               gauge.loop)
    assert pending.result(timeout=30).outcome is Outcome.UNKNOWN  # the NC has not looked
    reloads = cnc.ask(do="pin", name="shaftgauge-link.reloads")["value"]
    away = threading.Thread(target=gauge.restart_server, args=(10.0,))
    away.start()
    time.sleep(3.0)
    assert cnc.call() == -1  # errors counting, heartbeat frozen: not trusted
    assert cnc.tool_x_mm() == before
    away.join()
    deadline = time.monotonic() + 20
    while cnc.ask(do="pin", name="shaftgauge-link.reloads")["value"] == reloads:
        assert time.monotonic() < deadline, "mb2hal was not loaded again"
        time.sleep(0.5)
    assert cnc.call() == 1
    assert cnc.tool_x_mm() == pytest.approx(before + 0.0007, abs=1e-9)
    assert cnc.call() == 0
    time.sleep(0.3)
    assert gauge.run(gauge.transport.read_cnc()).ack_seq == 500


def test_the_gauge_killed_after_the_cnc_applied_and_before_it_heard(lathe) -> None:
    """The CNC applied the offset; the gauge died before its report arrived and came back
    with empty registers, offering the offset again (its log says unsettled): the CNC
    answers applied and applies nothing twice."""
    gauge, cnc = lathe
    cnc.call()
    reported(gauge)
    reading = gauge.run(gauge.transport.read_cnc())
    before = cnc.tool_x_mm()
    pending = asyncio.run_coroutine_threadsafe(gauge.transport.write_offset(-0.0022, 600),
                                               gauge.loop)
    assert pending.result(timeout=30).outcome is Outcome.UNKNOWN
    assert cnc.call() == 1  # applied; the gauge dies before it reads the report
    applied_x = cnc.tool_x_mm()
    assert applied_x == pytest.approx(before - 0.0011, abs=1e-9)
    reloads = cnc.ask(do="pin", name="shaftgauge-link.reloads")["value"]
    gauge.killed_and_restarted(3.0)
    deadline = time.monotonic() + 20
    while cnc.ask(do="pin", name="shaftgauge-link.reloads")["value"] == reloads:
        assert time.monotonic() < deadline, "mb2hal was not loaded again"
        time.sleep(0.5)
    gauge.run(gauge.transport.resume(600, -0.0022, reading.total_mm))
    assert cnc.call() in (0, 1)  # settled already (0) or found applied (1): never applied
    assert cnc.tool_x_mm() == pytest.approx(applied_x, abs=1e-9)
    time.sleep(0.3)
    assert gauge.run(gauge.transport.read_cnc()).ack_seq == 600


FAST_PART = """; a part whose finishing pass takes well under a second (the test's part program)
G7 G18 G21 G90 G94
T1 M6 G43
o<shaftgauge_comp> call [1]
G0 X40 Z2
G1 Z-5 F3000
G0 X44
G0 Z2
M2
"""


TWO_TOOL_PART = """; four diameters: T1 finishes features 1 and 2, T2 features 3 and 4
G7 G18 G21 G90 G94
T1 M6 G43
o<shaftgauge_comp> call [1]
G0 X40 Z2
G1 Z-5 F1500
G1 X36 Z-10
G0 X44
G0 Z2
T2 M6 G43
o<shaftgauge_comp> call [2]
G0 X30 Z-10
G1 Z-15 F1500
G1 X26 Z-20
G0 X44
G0 Z2
M2
"""

JOB = Job("SHAFT-4", "four diameters, two tools", (
    JobFeature(1, "journal", 40.0, 0.020, -0.020, tool=1),
    JobFeature(2, "bearing seat", 36.0, 0.015, -0.015, tool=1),
    JobFeature(3, "collar", 30.0, 0.020, -0.020, tool=2),
    # A slender end that springs away from the tool: it always cuts 6 um larger than the
    # collar; T2 learns the difference and aims between the two (``combine.aim``).
    JobFeature(4, "pin", 26.0, 0.020, -0.020, tool=2),
))
WEAR_MM_PER_PART = {1: 0.0025, 2: 0.0012}
DEFLECTION_MM = {4: 0.006}


def make_job_parts(gauge: Gauge, cnc: LinuxCnc, shadow: bool, parts: int = 20) -> tuple[
        dict[int, list[float]], dict[int, list[Decision]], dict[int, float]]:
    """Parts of ``JOB`` cut by a two-tool virtual lathe with LinuxCNC's tool offsets (each
    tool wearing at its own rate, each feature with the scatter of a part and its own
    deflection), each feature measured with the gauge's noise and judged by its tool's
    channel (one controller a tool, over the pull transport of that tool); the shipped
    subroutine takes each tool's offset at that tool's call in the next part's program.
    Returns each feature's deviations (um), each tool's decisions and its X change (mm)."""
    program = cnc.run_dir / "nc" / "two_tool_part.ngc"
    program.write_text(TWO_TOOL_PART)
    # The gauge looks at each report as it comes (each tool reports its total at its call).
    watcher = asyncio.run_coroutine_threadsafe(gauge.transport.watch(), gauge.loop)
    answer = cnc.ask(do="mdi", lines=["T2 M6 G43", "o<shaftgauge_comp> call [2]",
                                      "T1 M6 G43", "o<shaftgauge_comp> call [1]"])
    assert answer["ok"] and not answer["errors"], answer
    settings = CompensationSettings(nominal_mm=40.0, tol_upper_mm=0.02, tol_lower_mm=-0.02,
                                    shadow=shadow, law="predictive", gain=0.4,
                                    trend_gain=0.2, deadband_mm=0.002,
                                    dead_time_measurements=0, dead_time_s=0.0)
    decisions: dict[int, list[Decision]] = {1: [], 2: []}
    channels = {}
    for t in (1, 2):
        tool = EntryCompensation(JOB, t, settings)
        channels[t] = OffsetChannel(tool.controller, gauge.transport.tool(t), None,
                                    on_decision=decisions[t].append, compensation=tool)
    try:
        time.sleep(0.3)
        for ch in channels.values():
            gauge.run(ch.refresh())  # each tool's total: the baseline of its limit
        x0 = {t: cnc.ask(do="tool", number=t)["x"] for t in (1, 2)}
        rng = np.random.default_rng(21)
        deviations: dict[int, list[float]] = {f.number: [] for f in JOB.features}
        seq = 0
        for k in range(parts):
            answer = cnc.ask(do="run", path=str(program))
            assert answer["ok"] and not answer["errors"], answer
            time.sleep(0.15)  # the report through mb2hal
            for ch in channels.values():  # as the settler: the CNC's answers, each tool's total
                gauge.run(ch.settle())
                gauge.run(ch.refresh())
            offset = {t: 2.0 * (cnc.ask(do="tool", number=t)["x"] - x0[t]) for t in (1, 2)}
            for f in JOB.features:
                cut = f.nominal_mm + WEAR_MM_PER_PART[f.tool] * (k + 1) + offset[f.tool] + \
                    DEFLECTION_MM.get(f.number, 0.0) + rng.normal(0.0, 0.001)
                deviations[f.number].append((cut - f.nominal_mm) * 1000.0)
                seq += 1
                measured = cut + rng.normal(0.0, 0.0015)
                gauge.run(channels[f.tool].on_measurement(
                    MeasurementIn(seq, time.monotonic(), "ok", measured, 0.0015), f))
        answer = cnc.ask(do="run", path=str(program))  # the last offers taken
        assert answer["ok"] and not answer["errors"], answer
        time.sleep(0.3)
        for ch in channels.values():
            gauge.run(ch.settle())
        x_change = {t: cnc.ask(do="tool", number=t)["x"] - x0[t] for t in (1, 2)}
    finally:
        watcher.cancel()
        # T1 in the spindle again, its total reported: as the other tests expect.
        cnc.ask(do="mdi", lines=["T1 M6 G43", "o<shaftgauge_comp> call [1]"])
    return deviations, decisions, x_change


def out_of_tolerance(deviations: dict[int, list[float]]) -> dict[int, list[int]]:
    """For each feature, the parts (0-based) outside its tolerance."""
    out = {}
    for n, devs in deviations.items():
        f = JOB.feature(n)
        out[n] = [k for k, d in enumerate(devs)
                  if not f.tol_lower_mm * 1000 <= d <= f.tol_upper_mm * 1000]
    return out


def test_two_tools_four_features_in_tolerance_under_compensation(lathe) -> None:
    """T1 wears 2.5 um a part, T2 1.2 um: uncompensated, feature 2 (+-15 um) is out by part
    7. Compensated, every feature of 20 parts is in tolerance, and each tool's table entry
    moved by exactly the offsets the gauge logged as applied to that tool, each once."""
    gauge, cnc = lathe
    deviations, decisions, x_change = make_job_parts(gauge, cnc, shadow=False)
    applied = {t: [d for d in ds if d.kind is Kind.APPLIED] for t, ds in decisions.items()}
    print(f"\nFIGURES two tools, compensated: "
          f"{ {n: [round(d, 1) for d in v] for n, v in deviations.items()} } um; applied "
          f"{ {t: len(a) for t, a in applied.items()} }; X change (um) "
          f"{ {t: round(x * 1000, 4) for t, x in x_change.items()} }")
    assert not any(out_of_tolerance(deviations).values()), deviations
    for t in (1, 2):
        assert applied[t], f"tool {t} was never compensated"
        assert len({d.offset_seq for d in applied[t]}) == len(applied[t])
        # No offset reaches another tool: each entry moved by its own tool's, exactly.
        assert sum(d.offset_mm for d in applied[t]) == pytest.approx(2.0 * x_change[t],
                                                                     abs=1e-9)
        assert not [d for d in decisions[t] if d.kind in (Kind.NOT_APPLIED, Kind.ALARM,
                                                          Kind.STOPPED)]
    # Feature 4's 6 um is within what T2's features may differ (half of 40 um): not held.
    assert not [d for d in decisions[2] if d.code == "features_disagree"]


def test_two_tools_four_features_in_shadow_mode_leave_the_tolerance(lathe) -> None:
    gauge, cnc = lathe
    deviations, decisions, x_change = make_job_parts(gauge, cnc, shadow=True, parts=9)
    out = out_of_tolerance(deviations)
    print(f"\nFIGURES two tools, shadow: parts out per feature "
          f"{ {n: len(v) for n, v in out.items()} }")
    assert x_change == {1: 0.0, 2: 0.0}
    assert all(any(d.kind is Kind.PROPOSED for d in ds) for ds in decisions.values())
    assert out[2] and out[2][0] <= 7, deviations


def test_an_insert_change_zeroed_by_hand_leaves_the_tolerance_and_comes_back(lathe) -> None:
    """The machine has grown 25 um and the tool worn when, at part 15, the operator changes
    the insert and sets the tool's wear offset back by MDI (G10 L1), as a shop does: the
    part cut next carries the growth the offset held and is out of tolerance. Nobody
    acknowledges or resets: the gauge reads the CNC's total changed by hand, takes the parts
    cut after it as a new insert's, and its offsets through the shipped subroutine bring the
    parts back; the tool table moves by the hand's change and the applied offsets, exactly."""
    gauge, cnc = lathe
    program = cnc.run_dir / "nc" / "fast_part.ngc"
    program.write_text(FAST_PART)
    cnc.call()
    reported(gauge)
    settings = CompensationSettings(nominal_mm=30.0, tol_upper_mm=0.02, tol_lower_mm=-0.02,
                                    shadow=False, dead_time_measurements=0, dead_time_s=0.0)
    decisions: list[Decision] = []
    channel = OffsetChannel(CompensationController(settings, ControllerState()),
                            gauge.transport, None, on_decision=decisions.append)
    gauge.run(channel.refresh())
    lathe_ = VirtualLathe(LatheConfig(nominal_mm=30.0, wear_per_part_mm=0.002,
                                      thermal_mm=0.025, thermal_tau_min=3.0,
                                      insert_changes=(15,), part_sigma_mm=0.001), seed=11)
    rng = np.random.default_rng(12)
    x0 = cnc.tool_x_mm()
    deviations, hand_mm = [], 0.0
    for k in range(30):
        if k == 15:  # the new insert; its wear offset set back by hand
            hand_mm = 2.0 * (x0 - cnc.tool_x_mm())
            cnc.ask(do="mdi", lines=["G8 G21", f"G10 L1 P1 X{x0:.6f}", "G43"])
        answer = cnc.ask(do="run", path=str(program))
        assert answer["ok"] and not answer["errors"], answer
        time.sleep(0.15)  # the report through mb2hal
        gauge.run(channel.settle())  # the settler: the CNC's answer, its total
        gauge.run(channel.refresh())
        part = lathe_.cut_part(2.0 * (cnc.tool_x_mm() - x0))
        deviations.append((part.diameter_mm - 30.0) * 1000.0)
        measured = part.diameter_mm + rng.normal(0.0, 0.0015)
        gauge.run(channel.on_measurement(MeasurementIn(k + 1, time.monotonic(), "ok",
                                                       measured, 0.0015)))
    cnc.call()
    time.sleep(0.3)
    gauge.run(channel.settle())
    applied = [d for d in decisions if d.kind is Kind.APPLIED]
    print(f"\nFIGURES insert change by hand at part 15: deviations "
          f"{[round(d, 1) for d in deviations]} um, {len(applied)} offsets applied")
    assert hand_mm > 0.02  # the offset held the growth and the wear
    assert max(abs(d) for d in deviations[:15]) < 20.0, deviations
    assert max(deviations[15:17]) > 20.0, deviations  # out: the growth the offset held
    out_after = [k for k in range(15, 30) if abs(deviations[k]) > 20.0]
    assert len(out_after) <= 2 and max(abs(d) for d in deviations[18:]) < 20.0, deviations
    assert any(d.code == "cnc_total_changed" for d in decisions)
    assert not any(d.kind in (Kind.ALARM, Kind.STOPPED) for d in decisions)
    assert sum(d.offset_mm for d in applied) + hand_mm == pytest.approx(
        2.0 * (cnc.tool_x_mm() - x0), abs=1e-9)


ENTRY_PART = """; one insert, two offset entries: T202 (tool 2 with wear entry 10002) finishes
; the collar, T212 (wear entry 10012) the slender pin, whose deflection grows as it wears
G7 G18 G21 G90 G94
T202 M6
o<shaftgauge_comp> call [2] [10002]
G0 X30 Z2
G1 Z-10 F1500
G0 X44
G0 Z2
T212 M6
o<shaftgauge_comp> call [2] [10012]
G0 X26 Z-10
G1 Z-20 F1500
G0 X44
G0 Z2
M2
"""

ENTRY_JOB = Job("SHAFT-E", "one insert, two entries", (
    JobFeature(1, "collar", 30.0, 0.020, -0.020, tool=2),
    JobFeature(2, "pin", 26.0, 0.020, -0.020, tool=2, entry=10012)),
    (JobTool(2, wear_entry=10002),))
TAPER_UM_PER_PART = 0.8  # the pin springs away more as the insert wears: 12 um in 15 parts


def test_two_entries_of_one_insert_each_moved_only_by_its_own_offsets(lathe) -> None:
    """The LinuxCNC way of two offsets on one insert (``index_lathe_tool_with_wear``: T202 is
    tool 2 with wear entry 10002, T212 with 10012): the collar and the pin each on their own
    entry. The insert wears 1.2 um a part and the pin's taper grows 0.8 um a part: one
    correction for both would leave the pin 12 um behind. Each entry's channel posts its own
    requests (naming tool and entry), the shipped subroutine applies each to its entry, both
    features stay in tolerance, each wear entry moved by exactly its own applied offsets and
    the tool's geometry (T2) not at all."""
    gauge, cnc = lathe
    program = cnc.run_dir / "nc" / "entry_part.ngc"
    program.write_text(ENTRY_PART)
    watcher = asyncio.run_coroutine_threadsafe(gauge.transport.watch(), gauge.loop)
    answer = cnc.ask(do="run", path=str(program))  # each entry's total reported
    assert answer["ok"] and not answer["errors"], answer
    settings = CompensationSettings(nominal_mm=30.0, tol_upper_mm=0.02, tol_lower_mm=-0.02,
                                    shadow=False, law="predictive", gain=0.4,
                                    trend_gain=0.2, deadband_mm=0.002,
                                    dead_time_measurements=0, dead_time_s=0.0)
    entries = ENTRY_JOB.entries()
    assert entries == (OffsetEntry(2, 10002), OffsetEntry(2, 10012))
    decisions: dict[OffsetEntry, list[Decision]] = {e: [] for e in entries}
    channels = {}
    for e in entries:
        comp = EntryCompensation(ENTRY_JOB, e, settings)
        channels[e] = OffsetChannel(comp.controller, gauge.transport.entry(e.tool, e.number),
                                    None, on_decision=decisions[e].append, compensation=comp)
    slots = (2, 10002, 10012)
    try:
        time.sleep(0.3)
        for ch in channels.values():
            gauge.run(ch.refresh())  # each entry's total: the baseline of its limit
        x0 = {s: cnc.ask(do="tool", number=s)["x"] for s in slots}
        rng = np.random.default_rng(31)
        deviations: dict[int, list[float]] = {1: [], 2: []}
        seq = 0
        for k in range(15):
            answer = cnc.ask(do="run", path=str(program))
            assert answer["ok"] and not answer["errors"], answer
            time.sleep(0.15)  # the report through mb2hal
            for ch in channels.values():  # the settler: the CNC's answers, each entry's total
                gauge.run(ch.settle())
                gauge.run(ch.refresh())
            for f in ENTRY_JOB.features:
                slot = ENTRY_JOB.entry_of(f).number
                offset = 2.0 * (cnc.ask(do="tool", number=slot)["x"] - x0[slot])
                cut = f.nominal_mm + 0.0012 * (k + 1) + offset + rng.normal(0.0, 0.001) + (
                    TAPER_UM_PER_PART / 1000 * (k + 1) if f.number == 2 else 0.0)
                deviations[f.number].append((cut - f.nominal_mm) * 1000.0)
                seq += 1
                gauge.run(channels[ENTRY_JOB.entry_of(f)].on_measurement(MeasurementIn(
                    seq, time.monotonic(), "ok", cut + rng.normal(0.0, 0.0015), 0.0015), f))
        answer = cnc.ask(do="run", path=str(program))  # the last offers taken
        assert answer["ok"] and not answer["errors"], answer
        time.sleep(0.3)
        for ch in channels.values():
            gauge.run(ch.settle())
        change = {s: cnc.ask(do="tool", number=s)["x"] - x0[s] for s in slots}
    finally:
        watcher.cancel()
        cnc.ask(do="mdi", lines=["T1 M6 G43", "o<shaftgauge_comp> call [1]"])
    applied = {e: [d for d in ds if d.kind is Kind.APPLIED] for e, ds in decisions.items()}
    print(f"\nFIGURES one insert, two entries: "
          f"{ {n: [round(d, 1) for d in v] for n, v in deviations.items()} } um; applied "
          f"{ {str(e): [round(d.offset_mm * 1000, 1) for d in a] for e, a in applied.items()} }"
          f"; X change (um) "
          f"{ {s: round(x * 1000, 4) for s, x in change.items()} }")
    for n, devs in deviations.items():
        assert all(-20.0 <= d <= 20.0 for d in devs), (n, devs)
    assert change[2] == 0.0  # the tool's geometry: no offset goes there
    for e in entries:
        assert applied[e], f"{e} was never compensated"
        assert len({d.offset_seq for d in applied[e]}) == len(applied[e])
        assert sum(d.offset_mm for d in applied[e]) == pytest.approx(2.0 * change[e.number],
                                                                     abs=1e-9)
        assert not [d for d in decisions[e] if d.kind in (Kind.NOT_APPLIED, Kind.ALARM,
                                                          Kind.STOPPED)]
    # The pin's entry took more than the collar's: the taper is its own.
    assert change[10012] < change[10002] < 0
