"""`shaftgauge serve` as a user starts it: a subprocess with simulated camera and PLC."""

from __future__ import annotations

import contextlib
import json
import os
import ssl
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser, sync_playwright
from playwright.sync_api import Error as PlaywrightError

from tests.integration.conftest import SHAFTGAUGE, free_port
from tests.processes import end_group

TECH_KEY = "e2e-technician-key-0123456789"
UI_WAIT_MS = 60_000
"""How long a browser test waits for what the page should come to show: a deadline for a
broken page, generous for a slow and loaded machine, never the pass mark."""
ADMIN_KEY = "e2e-admin-key-0123456789abcdef"


@dataclass
class Service:
    """A running service and what it announced."""

    proc: subprocess.Popen
    url: str
    modbus_port: int
    plc_port: int
    control_port: int
    data: Path
    log: Path
    tls_sha256: str = ""
    verify: ssl.SSLContext | bool = True
    """What httpx checks the server's certificate against (over HTTPS: its own file)."""

    def get(self, path: str, **kw) -> httpx.Response:
        return httpx.get(self.url + path, timeout=10, verify=self.verify, **kw)

    def stderr(self) -> str:
        """What the service wrote to its standard error so far."""
        return self.log.read_text(errors="replace") if self.log.exists() else ""


# The tests' compensation: a wide band, offsets written (the embedded default: +-0.020 mm,
# shadow mode).
# The window law, with the tuning the fault and handshake tests were written with (the
# exchange with the CNC does not depend on the law; the default law has its own loop tests).
TEST_COMPENSATION = """[compensation]
{nominal}
law = "window"
gain = 0.7
tol_upper_mm = 0.05
tol_lower_mm = -0.05
window = 5
deadband_mm = 0.004
dead_time_measurements = 3
dead_time_s = 0.5
max_step_mm = 0.01
shadow = false
"""


def start_service(tmp_path: Path, **kw: Any) -> Service:
    """``shaftgauge serve`` configured by ``spawn_service(tmp_path, **kw)``, once it has said
    it is ready."""
    proc, log, plc = spawn_service(tmp_path, **kw)
    line = proc.stdout.readline()
    if not line:
        raise RuntimeError(f"serve did not start: {log.read_text(errors='replace')[-3000:]}")
    ready = json.loads(line)
    data = kw.get("data") or tmp_path / "data"
    https = data / "https" / "certificate.pem"  # a self-signed certificate's place
    return Service(proc, ready["url"], ready["modbus_port"], plc,
                   ready.get("sim_camera_control_port", 0), data, log,
                   ready.get("tls_sha256", ""),
                   ssl.create_default_context(cafile=https) if https.exists() else True)


def spawn_service(tmp_path: Path, diameter: float = 30.0, extra_toml: str = "",
                  fps: float = 10.0, camera_device: str | None = None,
                  plc_port: int | None = None, data: Path | None = None,
                  env: dict[str, str] | None = None, nominal: float | None = 30.0,
                  opcua_port: int | None = None, embedded: bool = False,
                  processes: bool = False, camera_toml: str = "", modbus_toml: str = "",
                  compensation_toml: str | None = None, executable: str = SHAFTGAUGE,
                  api_toml: str = "", modbus_port: int | None = None,
                  api_port: int | None = None) -> tuple[subprocess.Popen, Path, int]:
    """``shaftgauge serve`` with the simulated camera and PLC as its children, or with an
    external camera (``camera_device``) and PLC (``plc_port``) that a test controls;
    ``nominal`` None leaves the feature unset; the OPC UA server only on ``opcua_port`` or
    with ``embedded`` (its start costs a second of CPU: the fault suite restarts the service
    dozens of times); ``embedded``: the embedded default's feature, tool wear and OPC UA
    server (``camera.sim_feature``), no nominal of the test's; ``processes``: measured in
    worker processes as an installation does (a spawned worker costs about 3 s of CPU at
    start, and the suites start the service dozens of times: threads unless asked);
    ``camera_toml``, ``modbus_toml`` and ``api_toml`` more lines of those tables,
    ``compensation_toml`` the whole ``[compensation]`` table in place of the tests' own;
    ``executable`` another installed ``shaftgauge`` (an installed wheel's); ``modbus_port``
    the gauge's Modbus port and ``api_port`` its API's (free ones by default). Not waited for:
    returns the process (in a session of its own), its log and the PLC's port."""
    api, modbus = api_port or free_port(), modbus_port or free_port()
    # The embedded default's OPC UA port (4840) is one a run's other services, or a gauge a
    # developer left running, could hold: a port of the test's own.
    opcua_port = opcua_port or (free_port() if embedded else None)
    plc = plc_port or free_port()
    data = data or tmp_path / "data"
    cfg = tmp_path / "gauge.toml"
    # A ring of 8 frames, not 32: rendering them is most of the simulated camera's start
    # (a second of CPU for 32), and the suites start the service dozens of times; the
    # embedded default keeps its own, as ``make run`` starts it.
    ring = "" if embedded or "sim_replay_frames" in camera_toml else "sim_replay_frames = 8\n"
    camera = (f'source = "gige"\ndevice_id = "{camera_device}"' if camera_device else
              f'source = "sim"\nsim_serial = "E2E001"\nsim_diameter_mm = {diameter}\n'
              f'sim_feature = {"true" if embedded else "false"}\n{ring}{camera_toml}')
    if embedded:
        nominal = None
    cfg.write_text(f"""
[camera]
{camera}
frame_rate_hz = {fps}
[plc]
source = "{'modbus' if plc_port else 'sim'}"
port = {plc}
sim_ack_delay_s = 0.05
[modbus]
port = {modbus}
{modbus_toml}
[api]
port = {api}
keys = {{ "{TECH_KEY}" = "technician", "{ADMIN_KEY}" = "admin" }}
{api_toml}
[store]
path = "{data / 'gauge.db'}"
[opcua]
{f"port = {opcua_port}" if opcua_port else ""}
{"" if opcua_port or embedded else "enabled = false"}
{compensation_toml if compensation_toml is not None else "" if embedded else
 TEST_COMPENSATION.format(nominal="" if nominal is None else f"nominal_mm = {nominal}")}
{extra_toml}
""")
    # Its log to a file: a pipe nobody reads would fill (64 KiB) with a long outage's
    # warnings and block the service on its next log line; the file is there to read after.
    log = tmp_path / f"serve-{api}.log"
    with log.open("w") as err:
        proc = subprocess.Popen([executable, "serve", "--config", str(cfg)],
                                stdout=subprocess.PIPE, stderr=err, text=True,
                                start_new_session=True,
                                env={**os.environ, "SHAFTGAUGE_MEASUREMENT__PROCESSES":
                                     "true" if processes else "false", **(env or {})})
    return proc, log, plc


def stop_service(svc: Service) -> None:
    """SIGTERM the service (it stops its simulators), then make sure nothing of its process
    group is left: a leftover simulated camera would hold the GigE Vision port."""
    # The service alone first: it stops its simulated camera and PLC itself (signalled too,
    # the camera would vanish under the gauge's feet and its stop wait for a dead device).
    end_group(svc.proc, term_wait_s=30)


def measuring_workers(pid: int) -> list[int]:
    """The measuring worker processes of the service ``pid`` (its children that
    multiprocessing spawned; not its resource tracker, not the simulators)."""
    out = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            parent = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
            if parent == pid and b"spawn_main" in (p / "cmdline").read_bytes():
                out.append(int(p.name))
        except (OSError, ValueError, IndexError):
            continue
    return out


def wait_ready(svc: Service, timeout_s: float = 60.0) -> bool:
    """Until ``/readyz`` says 200 (True) or the time is up (False)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if svc.get("/readyz").status_code == 200:
                return True
        except httpx.HTTPError:
            pass
        time.sleep(0.3)
    return False


def wait_opcua(svc: Service, timeout_s: float = 30.0) -> dict:
    """The OPC UA server's status once it serves or says why it cannot (its start, the
    standard address space and a certificate, runs beside the measuring and, on a busy
    machine, ends seconds after the first measurements: a plant's client retries)."""
    deadline, ua = time.monotonic() + timeout_s, {}
    while time.monotonic() < deadline:
        ua = svc.get("/api/v1/status").json()["plant"]["opcua"]
        if ua["running"] or ua["problem"]:
            break
        time.sleep(0.3)
    return ua


@pytest.fixture
def service(tmp_path) -> Iterator[Service]:
    svc = start_service(tmp_path)
    try:
        wait_ready(svc)
        yield svc
    finally:
        stop_service(svc)


@pytest.fixture(scope="class")
def watched(tmp_path_factory) -> Iterator[Service]:
    """``service`` shared by a class of tests that only read from it (a start: 5 s, and
    4.7 s of CPU with its simulators); stopped after the class, not the module, so that it
    does not stream beside the next tests' own services."""
    svc = start_service(tmp_path_factory.mktemp("watched"))
    try:
        wait_ready(svc)
        yield svc
    finally:
        stop_service(svc)


def wait_for_js(page, expression: str, timeout_s: float = UI_WAIT_MS / 1000) -> None:
    """Until ``expression`` is true in the page. Polled from here with ``page.evaluate``:
    Playwright's own ``wait_for_function`` polls by evaluating a string in the page, which
    the dashboard's Content-Security-Policy (no eval) rightly refuses."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise AssertionError(f"not true within {timeout_s} s: {expression}")
        time.sleep(0.1)


CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--disable-dev-shm-usage"]  # a container's /dev/shm can be 64 MB


@pytest.fixture(scope="module")
def chromium():
    """Debian's Chromium for the module: one Playwright, the browser launched when a test
    needs it and it is not running (a crash then fails one test, not every test after it)."""
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: deploy/bootstrap.sh installs Debian's chromium")
    with sync_playwright() as p:
        running: list[Browser] = []

        def launched() -> Browser:
            if not running or not running[-1].is_connected():
                running.append(p.chromium.launch(executable_path=CHROMIUM, args=ARGS))
            return running[-1]

        yield launched
        if running[-1:] and running[-1].is_connected():
            running[-1].close()


@pytest.fixture
def browser(chromium) -> Iterator[Browser]:
    """The browser, each test's pages closed after it: a dashboard left open polls its dead
    service for the rest of the module, burning the CPU the next tests need."""
    b = chromium()
    yield b
    for context in b.contexts:
        with contextlib.suppress(PlaywrightError):
            context.close()
