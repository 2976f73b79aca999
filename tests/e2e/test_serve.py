"""The whole system, started as a user starts it."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from pymodbus.client import AsyncModbusTcpClient

from drivers.plc.registers import RegisterType, WordOrder, from_words, mm_to_units, units_to_mm
from drivers.sim.control import control
from service.api.attempts import MAX_FAILURES
from tests.e2e.conftest import (
    TECH_KEY,
    measuring_workers,
    spawn_service,
    start_service,
    stop_service,
    wait_ready,
)
from tests.integration.conftest import free_port
from tests.processes import end_group
from tests.waiting import DEADLINE_S, until


def wait_for(predicate, timeout_s: float, step_s: float = 0.2):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step_s)
    return None


class TestReading:
    """What only reads from a service: one started for the class (a start is 5 s, with its
    simulators' 4.7 s of CPU)."""

    def test_rest_measures_the_simulated_shaft(self, watched) -> None:
        assert watched.get("/readyz").status_code == 200, watched.get("/readyz").text
        time.sleep(2.0)  # let the fusion window fill
        m = watched.get("/api/v1/measurements/latest").json()
        assert m["status"] == "ok"
        assert abs(m["diameter_mm"] - 30.0) < 0.010, m
        assert abs(m["fused_diameter_mm"] - 30.0) < 0.005, m
        st = watched.get("/api/v1/status").json()
        assert st["healthy"] and st["camera"]["state"] == "streaming"
        assert st["pipeline"]["rate_hz"] > 5

    def test_sse_delivers_updates(self, watched) -> None:
        seqs = []
        with httpx.stream("GET", watched.url + "/api/v1/stream", timeout=15) as r:
            assert r.headers["content-type"].startswith("text/event-stream")
            event = None
            for line in r.iter_lines():
                if line.startswith("event:"):
                    event = line.split(":", 1)[1].strip()
                elif line.startswith("data:") and event == "measurement":
                    seqs.append(json.loads(line[5:])["seq"])
                    if len(seqs) >= 4:
                        break
        assert seqs == sorted(seqs) and len(set(seqs)) == 4

    def test_modbus_registers_agree_with_rest(self, watched) -> None:
        async def read() -> tuple[int, int]:
            c = AsyncModbusTcpClient("127.0.0.1", port=watched.modbus_port)
            await c.connect()
            rr = await c.read_holding_registers(0, count=30, device_id=1)
            c.close()
            regs = rr.registers
            return (from_words(regs[6:8], RegisterType.I32, WordOrder.BIG),
                    from_words(regs[10:12], RegisterType.U32, WordOrder.BIG))

        for _ in range(20):
            diameter_units, seq = asyncio.run(read())
            rest = watched.get("/api/v1/measurements", params={"limit": 50}).json()["items"]
            same = [r for r in rest if r["seq"] == seq]
            if same:  # the register holds exactly the REST diameter, in 0.1 um
                assert diameter_units == mm_to_units(same[0]["diameter_mm"])
                assert abs(units_to_mm(diameter_units) - same[0]["diameter_mm"]) <= 0.5e-4
                return
        raise AssertionError("never saw the same measurement over Modbus and REST")

    def test_every_answer_carries_the_security_headers_and_a_foreign_host_is_refused(self, watched
                                                                                     ) -> None:
        for path in ("/ui/", "/api/v1/status", "/ui/manual/"):
            r = watched.get(path)
            assert r.status_code == 200, path
            assert r.headers["x-content-type-options"] == "nosniff"
            assert r.headers["x-frame-options"] == "DENY"
            csp = r.headers["content-security-policy"]
            assert "frame-ancestors 'none'" in csp and "default-src 'self'" in csp
            assert ("'unsafe-inline'" in csp) == path.startswith("/ui/manual"), (path, csp)
        # A DNS-rebinding page names its own host: refused, and nothing of the gauge read.
        r = watched.get("/api/v1/measurements/latest", headers={"Host": "evil.example:8000"})
        assert r.status_code == 400 and "trusted_hosts" in r.json()["detail"]
        assert r.headers["x-frame-options"] == "DENY"
        assert watched.get("/api/v1/status", headers={"Host": "localhost"}).status_code == 200


def test_drift_beyond_the_deadband_sends_an_offset_to_the_plc(service) -> None:
    log = service.data / "sim-plc.log"
    reply = control(service.control_port, {"set": {"diameter_mm": 30.012}})
    assert reply["ok"]

    def applied():
        if not log.exists():
            return None
        events = [json.loads(x) for x in log.read_text().splitlines()]
        return [e for e in events if e["event"] == "applied"] or None

    events = wait_for(applied, timeout_s=40)
    assert events, "no offset reached the simulated PLC"
    first = events[0]
    # oversize by 12 um, gain 0.7 -> about -8.4 um, never beyond the 10 um step limit
    assert -100 <= first["value_units"] < -40, first
    # The gauge learns of the application from the PLC's acknowledgement, a poll later than
    # the PLC's own log line.
    decisions = wait_for(lambda: service.get(
        "/api/v1/compensation/log", params={"kinds": "applied"}).json()["items"], timeout_s=10)
    assert decisions and decisions[0]["offset_seq"] == first["seq"], decisions
    st = service.get("/api/v1/status").json()
    assert st["compensation"]["cumulative_offset_mm"] < 0
    r = httpx.put(service.url + "/api/v1/compensation/shadow", json={"shadow": True},
                  headers={"X-API-Key": TECH_KEY}, timeout=10)
    assert r.status_code == 200


def test_sigterm_stops_the_service_with_a_live_stream_open(tmp_path) -> None:
    """A dashboard's live stream never ends by itself: on SIGTERM it gets ``api.shutdown_s``
    (3 s) and the service stops (systemd would otherwise wait and kill it)."""
    svc = start_service(tmp_path)
    try:
        assert wait_ready(svc)
        with socket.create_connection(svc.url.removeprefix("http://").split(":")) as s:
            s.sendall(b"GET /api/v1/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            assert s.recv(64).startswith(b"HTTP/1.1 200")
            os.killpg(svc.proc.pid, signal.SIGTERM)
            # 143: a stop that hung was cut short (after api.shutdown_s and a margin). A
            # stream that kept it waiting would keep it for ever: the deadline ends the test.
            assert svc.proc.wait(DEADLINE_S) in (0, 128 + signal.SIGTERM)
            assert in_session(svc.proc.pid) == []  # its simulators stopped and reaped
    finally:
        stop_service(svc)


def test_ctrl_c_stops_the_service_and_its_simulators_at_once(tmp_path) -> None:
    """Ctrl-C in a terminal signals the whole process group: the simulated camera dies with
    the service, which must not wait for it to answer (Aravis's retries took 12 s), and the
    service ends without a traceback (``_STOP_WAIT_S`` bounds the camera's release)."""
    svc = start_service(tmp_path)
    try:
        assert wait_ready(svc)
        os.killpg(svc.proc.pid, signal.SIGINT)
        assert svc.proc.wait(DEADLINE_S) == 130
        err = svc.stderr()
        assert "Traceback" not in err, err[-2000:]
    finally:
        stop_service(svc)


def in_session(sid: int) -> list[str]:
    """The processes of session ``sid`` (the service's own, as the tests start it), zombies
    of the service's included (it did not reap them); not those init adopted, which have
    ended (this container's init does not reap them)."""
    found = []
    for p in Path("/proc").iterdir():
        try:
            stat = (p / "stat").read_text()
            state, ppid, _, session = stat.rsplit(")", 1)[1].split()[:4]
            if p.name.isdigit() and int(session) == sid and (state, ppid) != ("Z", "1"):
                found.append(stat.split(" ", 1)[1][:60])
        except (OSError, ValueError, IndexError):
            continue
    return found


def gone(proc: subprocess.Popen, timeout_s: float = DEADLINE_S) -> None:
    """Until ``proc`` and every process of its session are gone (AssertionError naming what
    is left past ``timeout_s``)."""
    until(lambda: proc.poll() is not None and not in_session(proc.pid),
          lambda: f"the service's session gone (exit {proc.poll()}, {in_session(proc.pid)})",
          timeout_s, step_s=0.05)


def test_a_failed_start_ends_by_itself_and_says_why(tmp_path) -> None:
    """The Modbus port is taken: the start fails, what it had started (the camera, the
    simulators) is stopped, and the service ends with uvicorn's start-up failure (3)."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        proc, log, _ = spawn_service(tmp_path, modbus_port=taken.getsockname()[1])
        try:
            assert proc.stdout.readline() == ""  # never ready
            gone(proc)
            assert proc.returncode == 3
            err = log.read_text()
            assert f"cannot listen on 127.0.0.1:{taken.getsockname()[1]} (modbus.port" in err
            assert ": stopped (stopped)" in err  # the camera it had started
        finally:
            end_group(proc)


def test_a_start_on_a_taken_api_port_exits_at_once_with_nothing_listening(tmp_path) -> None:
    """The second outside probe: with the API's port taken, the start logged Errno 98 and then
    waited in uvicorn's shutdown for over 90 s while its Modbus server took the CNC's writes;
    it never exited, so systemd never restarted it. The API's port is bound first."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        modbus = free_port()
        proc, log, _ = spawn_service(tmp_path, api_port=taken.getsockname()[1],
                                     modbus_port=modbus)
        try:
            assert proc.stdout.readline() == ""  # never ready
            gone(proc)
            assert proc.returncode not in (0, None)
            err = log.read_text()
            assert f"cannot listen on 127.0.0.1:{taken.getsockname()[1]} (api.port" in err, err
            assert "sim-camera" not in err and "Waiting for application" not in err, err
            with socket.socket() as probe:  # nothing of it listens
                assert probe.connect_ex(("127.0.0.1", modbus)) != 0
        finally:
            end_group(proc)


@pytest.mark.parametrize("when", ["simulators starting", "kernels compiling"])
def test_sigterm_while_starting_ends_everything_before_it_serves(tmp_path, when: str) -> None:
    """A start under way ends at SIGTERM: while its simulators start (before uvicorn), or
    while the measuring kernels compile (an empty numba cache: 30-60 s), which uvicorn would
    have waited for before it stopped. Either way the start never completes: nothing was
    served before it ended."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "numba")} if when == "kernels compiling" else {}
    proc, log, _ = spawn_service(tmp_path, env=env)
    try:
        marker = "Waiting for application startup" if env else "sim-camera"
        deadline = time.monotonic() + 60
        while marker not in log.read_text() and not (env == {} and in_session(proc.pid)[1:]):
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.05)
        # The simulators' start takes about a second: a loaded machine's came to its end
        # within the second this waited, and the signal found the start past them.
        time.sleep(1.0 if env else 0.0)
        assert proc.poll() is None, log.read_text()[-2000:]
        proc.send_signal(signal.SIGTERM)
        gone(proc)
        assert proc.returncode == 128 + signal.SIGTERM
        assert "Application startup complete" not in log.read_text(), log.read_text()[-2000:]
    finally:
        end_group(proc)


def test_sigterm_to_the_service_alone_reaps_its_children_before_it_ends(tmp_path) -> None:
    """As ``systemctl stop`` with ``KillMode=mixed``, or a supervisor that signals the main
    process only: the simulators are stopped and reaped by the service itself."""
    svc = start_service(tmp_path)
    try:
        assert wait_ready(svc)
        assert len(in_session(svc.proc.pid)) >= 3  # the service and its two simulators
        svc.proc.send_signal(signal.SIGTERM)
        assert svc.proc.wait(10) == 0
        assert in_session(svc.proc.pid) == []
    finally:
        stop_service(svc)


def test_worker_processes_measure_and_one_killed_is_replaced(tmp_path) -> None:
    """As installed, frames are measured in worker processes: a worker killed (-9) breaks
    its pool; the pipeline starts new workers, counts it, and measures on. The service
    killed (-9) leaves no worker behind."""
    svc = start_service(tmp_path, fps=20.0, processes=True)
    try:
        wait_ready(svc)

        def workers() -> list[int]:
            return measuring_workers(svc.proc.pid)

        before = wait_for(workers, timeout_s=30)
        assert before, "no worker process"
        st = svc.get("/api/v1/status").json()["pipeline"]
        assert st["workers"]["processes"] and st["workers"]["restarts"] == 0
        measured = st["measured"]
        os.kill(before[0], signal.SIGKILL)
        restarted = wait_for(lambda: svc.get("/api/v1/status").json()["pipeline"]["workers"]
                             ["restarts"] >= 1, timeout_s=20)
        assert restarted
        later = wait_for(lambda: (p := svc.get("/api/v1/status").json()["pipeline"])
                         ["measured"] > measured + 40 and p, timeout_s=30)
        assert later, "no measurements after the worker was killed"
        assert set(workers()).isdisjoint({before[0]})
        m = svc.get("/api/v1/measurements/latest").json()
        assert m["status"] == "ok" and abs(m["diameter_mm"] - 30.0) < 0.010, m
        left = workers()
        os.kill(svc.proc.pid, signal.SIGKILL)
        svc.proc.wait(10)

        def gone() -> bool:
            for pid in left:
                try:
                    if Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] \
                            != "Z":
                        return False
                except OSError:
                    pass
            return True

        assert wait_for(gone, timeout_s=10), f"workers {left} outlived the service"
    finally:
        stop_service(svc)



def test_forwarded_addresses_are_not_believed_from_an_untrusted_peer(tmp_path) -> None:
    """No proxy is trusted by default, not even on loopback: a rotating X-Forwarded-For does
    not escape the lock-out after wrong keys, a change is audited with the real peer, and a
    forged "testclient" does not pass the host check (issue 50, finding 2)."""
    svc = start_service(tmp_path)
    try:
        assert wait_ready(svc)
        codes = []
        for i in range(MAX_FAILURES + 5):
            r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": True},
                          headers={"X-API-Key": f"wrong-{i}",
                                   "X-Forwarded-For": f"10.77.{i // 250}.{i % 250 + 1}"},
                          timeout=10)
            codes.append(r.status_code)
        assert codes[:MAX_FAILURES] == [401] * MAX_FAILURES and 429 in codes, codes
        time.sleep(0.1)
        host = httpx.get(svc.url + "/api/v1/status", timeout=10,
                         headers={"Host": "evil.example", "X-Forwarded-For": "testclient"})
        assert host.status_code == 400, host.text
    finally:
        stop_service(svc)
    (tmp_path / "again").mkdir()
    svc = start_service(tmp_path / "again")
    try:
        assert wait_ready(svc)
        r = httpx.put(svc.url + "/api/v1/compensation/shadow", json={"shadow": True},
                      headers={"X-API-Key": TECH_KEY, "X-Forwarded-For": "10.9.9.9"},
                      timeout=10)
        assert r.status_code == 200, r.text
        who = r.json()["decision"]["who"]
        assert "127.0.0.1" in who and "10.9.9.9" not in who, who
    finally:
        stop_service(svc)
