"""The loop closed through the whole service: ``shaftgauge serve`` measures what its simulated
camera shows, and the camera shows what a virtual lathe cuts with the simulated CNC's applied
total (read over Modbus); the offsets the gauge writes change what it sees a dead time later.

The lathe's time is driven by the test in step with the gauge: it moves on as far as the
frames the gauge has measured (``LathePacer``), and stands until the first, however long the
service takes to start (``sim_lathe_paced``). It moves by the frames' own clock: a slow or
loaded machine measures fewer frames of the same seconds, as a slow gauge on a real lathe
would, and the dead times typed in seconds stay true (paced by the frames' count, the lathe
slowed under load while the law's seconds did not, and the law overshot). A test that needs
as much to measure from each frame whatever the load paces it by their count instead
(``per_frame_s``).
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Callable

import httpx

from drivers.plc.registers import UM_PER_UNIT
from drivers.plc.sim import SimPlc
from drivers.sim.control import control
from tests.e2e.conftest import TECH_KEY, start_service, stop_service, wait_ready
from tests.integration.conftest import free_port

WEAR_UM_PER_MIN = 60.0   # 1 um a second: out of +-20 um in 20 s uncompensated
TOLERANCE_MM = 0.020


def camera(wear_um_per_min: float = WEAR_UM_PER_MIN, thermal_um: float = 0.0,
           thermal_tau_s: float = 1200.0) -> str:
    return f"""sim_lathe = true
sim_lathe_paced = true
sim_drift_um_per_min = {wear_um_per_min}
sim_drift_period_min = 0
sim_lathe_dead_time_s = 1.0
sim_lathe_thermal_um = {thermal_um}
sim_lathe_thermal_tau_s = {thermal_tau_s}
sim_replay_frames = 2
"""
# A ring of 2 frames: the frames sent after a change show the old diameter until the ring is
# rendered again, which a loaded machine does slowly (a ring of 8 added seconds of dead time
# under a loaded suite, and the insert-change loop swung out to 61 um).


# The window law (the default until the predictive one held on varied lathes): its dead time
# covers the lathe's (1 s: 10 frames), the camera's ring (rendered again after a change) and
# the window (5 measurements).
COMPENSATION = f"""[compensation]
law = "window"
gain = 0.7
nominal_mm = 30.0
tol_upper_mm = {TOLERANCE_MM}
tol_lower_mm = -{TOLERANCE_MM}
window = 5
deadband_mm = 0.003
dead_time_measurements = 10
dead_time_s = 3.0
max_step_mm = 0.010
shadow = true
"""
# The default law, the predictive one, with its dead time as it is: from the cut to the
# laser (1 s) and the camera's ring (2 frames) to a measurement that shows it, with a margin.
PREDICTIVE = f"""[compensation]
nominal_mm = 30.0
tol_upper_mm = {TOLERANCE_MM}
tol_lower_mm = -{TOLERANCE_MM}
dead_time_measurements = 0
dead_time_s = 1.5
max_step_mm = 0.010
shadow = true
"""


class LathePacer:
    """Drives the camera's lathe: as far as the time of the last frame the service has
    measured (``per_frame_s``: that much for each frame measured), read five times a second,
    until closed. ``before`` (a CNC of the test's) is called before each step: the lathe
    never cuts on with a total it was not told."""

    def __init__(self, svc, before: Callable[[], None] | None = None,
                 per_frame_s: float | None = None) -> None:
        self.svc, self.before, self.per_frame_s = svc, before, per_frame_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _frame_time_s(self) -> float | None:
        """When the frame of the latest measurement was received, or the frames measured
        times ``per_frame_s`` (None: none yet)."""
        if self.per_frame_s is not None:
            measured = self.svc.get("/api/v1/status").json()["pipeline"]["measured"]
            return int(measured) * self.per_frame_s if measured else None
        r = self.svc.get("/api/v1/measurements/latest")
        if r.status_code != 200:
            return None
        m = r.json()
        return float(m["time"]) - float(m["latency_ms"]) / 1000.0

    def _run(self) -> None:
        last = None
        control(self.svc.control_port, {"do": "advance_lathe", "s": 0.0})
        while not self._stop.wait(0.2):
            with contextlib.suppress(httpx.HTTPError, OSError, KeyError, TypeError):
                now = self._frame_time_s()
                if now is not None and last is None:
                    last = now  # the first frame: the lathe starts here
                elif now is not None and now > last:
                    if self.before is not None:
                        self.before()
                    control(self.svc.control_port, {"do": "advance_lathe", "s": now - last})
                    last = now

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10)


def lathe(svc) -> dict:
    """The virtual lathe's sample under the laser now (the truth the gauge should see)."""
    return control(svc.control_port, {"get": "stats"})["stats"]["lathe"]


def follow(svc, lathe_seconds: float, every_s: float = 0.5) -> list[dict]:
    """The lathe's truth every ``every_s`` of the lathe's time, for ``lathe_seconds`` of it
    (however long that takes the machine)."""
    out = []
    first = lathe(svc)["time_s"]
    deadline = time.monotonic() + 20 * lathe_seconds + 60  # ends a loop that stopped
    while len(out) * every_s < lathe_seconds:
        s = lathe(svc)
        if s["time_s"] >= first + len(out) * every_s:
            out.append(s)
        assert time.monotonic() < deadline, f"the lathe stood at {s['time_s']} s"
        time.sleep(0.05)
    return out


def test_offsets_written_by_the_service_hold_the_cut_in_tolerance(tmp_path) -> None:
    svc = start_service(tmp_path, camera_toml=camera(), compensation_toml=COMPENSATION)
    pacer = None
    try:
        assert wait_ready(svc)
        pacer = LathePacer(svc)
        r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": False},
                      headers={"X-API-Key": TECH_KEY}, timeout=10)
        assert r.status_code == 200, r.text
        loop = follow(svc, 30.0)
        deviations_um = [round((s["cut_diameter_mm"] - 30.0) * 1000.0, 1) for s in loop]
        # What the camera shows follows the CNC: held in tolerance while the tool wears 30 um.
        assert loop[-1]["wear_mm"] - loop[0]["wear_mm"] > 0.025, loop[-1]
        assert max(abs(d) for d in deviations_um) < TOLERANCE_MM * 1000.0, deviations_um
        # The lathe's CNC total is the simulated PLC's applied total, which is the sum of the
        # gauge's applied offsets, each once.
        r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": True},
                      headers={"X-API-Key": TECH_KEY}, timeout=10)
        assert r.status_code == 200, r.text
        follow(svc, 1.0)  # the last offset settled
        applied = svc.get("/api/v1/compensation/log", params={"kinds": "applied",
                                                              "limit": 1000}).json()["items"]
        assert applied and len({d["offset_seq"] for d in applied}) == len(applied)
        total = lathe(svc)["cnc_total_mm"]
        assert abs(sum(d["offset_mm"] for d in applied) - total) < 1e-6, (applied, total)
        assert abs(svc.get("/api/v1/status").json()["compensation"]["cnc_total_mm"]
                   - total) < 1e-6
        # Shadow mode from here: offsets proposed into the void, the CNC's total stays and
        # the tool wears the part out of tolerance.
        # 1 um of wear a second: out within 40 s from anywhere in the tolerance (a cut held
        # at -19 um needs 39 s; 24 s of lathe time, as long as the loop was near nominal).
        shadow = follow(svc, 24.0)
        while len(shadow) * 0.5 < 48.0 and max(
                abs(s["cut_diameter_mm"] - 30.0) for s in shadow) <= TOLERANCE_MM:
            shadow += follow(svc, 4.0)
        worst_um = max(abs(s["cut_diameter_mm"] - 30.0) for s in shadow) * 1000.0
        print(f"\nFIGURES compensated 30 s: {min(deviations_um)}..{max(deviations_um)} um, "
              f"{len(applied)} offsets, CNC total {total * 1000:+.1f} um; then shadow "
              f"{len(shadow) * 0.5:.0f} s: worst {worst_um:.1f} um")
        assert all(s["cnc_total_mm"] == total for s in shadow)
        assert worst_um > TOLERANCE_MM * 1000.0, shadow[-1]
        assert svc.get("/api/v1/compensation/log",
                       params={"kinds": "proposed"}).json()["items"], "nothing proposed"
    finally:
        if pacer is not None:
            pacer.close()
        stop_service(svc)


class HandCnc:
    """The CNC for the insert change: the simulated PLC's offset registers in this process
    (so the test can zero its wear offset by hand, as an operator at the panel), its total
    told to the camera's virtual lathe as it changes."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        threading.Thread(target=self.loop.run_forever, daemon=True).start()
        self.plc = SimPlc(port=free_port())
        self.port = asyncio.run_coroutine_threadsafe(self.plc.start(), self.loop).result(10)
        self._stop = threading.Event()

    def tell(self, control_port: int) -> None:
        """Tell the camera's lathe the CNC's total now (the pacer does, before each step of
        the lathe's time: on a loaded machine a thread of its own fell seconds of the
        lathe's time behind, and the loop swung on a dead time it could not know)."""
        total = self.plc.total_units * UM_PER_UNIT / 1000.0
        with contextlib.suppress(OSError):
            control(control_port, {"set": {"cnc_total_mm": total}})

    def zero_by_hand(self) -> None:
        self.loop.call_soon_threadsafe(self.plc.set_total_by_hand, 0)

    def close(self) -> None:
        self._stop.set()
        asyncio.run_coroutine_threadsafe(self.plc.stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)


def test_an_insert_change_that_loses_the_growth_comes_back_by_itself(tmp_path) -> None:
    """The machine has grown 30 um and the tool worn 10 um when the operator changes the
    insert and zeroes its wear offset: the parts jump out by the growth the offset carried.
    Nobody acknowledges anything: the gauge sees the CNC's total changed by hand, takes the
    parts cut after it as a new insert's, and brings the cut back into the tolerance."""
    cnc = HandCnc()
    svc = pacer = None
    try:
        svc = start_service(tmp_path, camera_toml=camera(20.0, 30.0, 6.0),
                            compensation_toml=PREDICTIVE, plc_port=cnc.port)
        assert wait_ready(svc)
        cnc.tell(svc.control_port)
        pacer = LathePacer(svc, before=lambda: cnc.tell(svc.control_port))
        r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": False},
                      headers={"X-API-Key": TECH_KEY}, timeout=10)
        assert r.status_code == 200, r.text
        before = follow(svc, 20.0)
        # The offset comes to carry the growth and the wear (36 um by now): on a loaded
        # machine the loop may take a few more seconds of the lathe's time.
        for _ in range(8):
            if lathe(svc)["cnc_total_mm"] < -0.030:
                break
            before += follow(svc, 2.5)
        held_um = [round((s["cut_diameter_mm"] - 30.0) * 1000.0, 1) for s in before]
        assert max(abs(d) for d in held_um[-10:]) < 20.0, held_um
        assert lathe(svc)["cnc_total_mm"] < -0.030  # growth and wear carried by the offset
        assert control(svc.control_port, {"do": "new_insert"})["ok"]
        cnc.zero_by_hand()
        after = follow(svc, 16.0)
        deviations_um = [round((s["cut_diameter_mm"] - 30.0) * 1000.0, 1) for s in after]
        print(f"\nFIGURES insert change, zeroed by hand: {deviations_um} um")
        assert max(abs(d) for d in deviations_um) > TOLERANCE_MM * 1000.0, \
            deviations_um  # it went out
        assert max(abs(d) for d in deviations_um[-12:]) < TOLERANCE_MM * 1000.0, \
            deviations_um  # and came back by itself
        log = svc.get("/api/v1/compensation/log", params={"limit": 1000}).json()["items"]
        assert any(d["code"] == "cnc_total_changed" for d in log), log[:20]
        assert not any(d["kind"] in ("acknowledged", "reset") and d["who"] != "gauge"
                       for d in log)
        comp = svc.get("/api/v1/status").json()["compensation"]
        assert comp["state"] in ("active", "pending")
        dead = comp["dead_time"]
        print(f"FIGURES dead time after the loop: {dead}")
        assert dead["typed"] == {"measurements": 0, "seconds": 1.5}, dead
        # Typed in seconds, a measured dead time that differs is used in seconds too.
        assert dead["in_use"] == (dead["typed"] if not dead["differs"] else {
            "measurements": 0, "seconds": dead["measured"]["seconds"]}), dead
    finally:
        if pacer is not None:
            pacer.close()
        if svc is not None:
            stop_service(svc)
        cnc.close()
