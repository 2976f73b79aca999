"""Settings of ``shaftgauge serve``: a TOML file plus environment variables (pydantic-settings).

Environment variables override the file: ``SHAFTGAUGE_<SECTION>__<NAME>``, e.g.
``SHAFTGAUGE_MODBUS__PORT=502`` or ``SHAFTGAUGE_API__KEYS='{"<key>": "admin"}'``. Every value
is validated at start; an error names the setting (``modbus.port: ...``). With no file the
embedded default runs the whole system on loopback with a simulated camera and PLC.
"""

from __future__ import annotations

import ipaddress
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_settings import BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict
from pydantic_settings.exceptions import SettingsError

from calib_store.model import format_validation_error
from service.compensation import CompensationSettings
from service.measure.result import Method


class ConfigError(ValueError):
    """Settings that cannot be used; the message names each bad setting."""


class _Section(BaseModel):
    # Frozen after load: what changes at run time has an owner that keeps it (the
    # compensation service for the feature, tuning and part temperature).
    model_config = ConfigDict(extra="forbid", frozen=True)


class CameraSettings(_Section):
    """Where frames come from."""

    source: Literal["sim", "gige", "rig"] = "sim"
    """``sim``: start a simulated GigE camera as a child process and stream from it over
    GigE Vision; ``gige``: a real camera by ``device_id``; ``rig``: the simulated rig in this
    process (no network; for tests)."""
    device_id: str | None = None
    pixel_format: Literal["Mono8", "Mono12", "Mono16"] = "Mono8"
    exposure_us: float | None = Field(None, gt=0)
    gain_db: float | None = None
    frame_rate_hz: float | None = Field(10.0, gt=0, le=1000)
    packet_size: int | None = Field(8192, ge=576, le=65000)
    packet_socket: bool = True
    socket_buffer_bytes: int | None = Field(None, gt=0)
    queue_size: int = Field(16, ge=1, le=1000)
    """Frames held for the measurement before the oldest is dropped (counted): 16 is 160 ms
    at 100 frames/s, enough that a pause of the service (a neighbour's burst on the same
    cores) loses no frame; a frame that waits shows in the latency."""
    auto_roi: bool | None = None
    """Narrow the sensor's region to the stripe (plus ``roi_margin_px``) and widen it again
    when the stripe nears its edge or is lost: fewer rows, more frames per second. None: on
    for the simulated cameras, off for a real one until it is tried there."""
    roi_margin_px: int = Field(32, ge=4, le=512)
    trigger: Literal["free_run", "hardware"] = "free_run"
    """``hardware``: a frame on each pulse at ``trigger_line`` (an encoder on the spindle:
    ``spindle.source = "encoder"``); ``free_run``: at ``frame_rate_hz``."""
    trigger_line: str = "Line0"
    """The camera's input line the trigger pulses reach (GenICam ``TriggerSource``)."""
    sim_serial: str = "SIM001"
    sim_diameter_mm: float = Field(30.0, gt=1, lt=500)
    sim_drift_um_per_min: float | None = None
    """The simulated tool wear, um a minute on the diameter; None: 0.4 with ``sim_feature``,
    else none."""
    sim_drift_period_min: float = Field(30.0, ge=0)
    """The wear starts again this often (a new insert; 0: it never does)."""
    sim_feature: bool = True
    """The embedded default's demonstration: with ``source = "sim"`` and no nominal set, the
    feature is the simulated shaft (its diameter, the compensation's tolerance, +-0.020 mm by
    default) and the tool wears slowly, so a newcomer sees a trend in its band, offsets
    proposed in shadow mode, the SPC view filling and a gauge study that passes."""
    sim_part: Literal["cylinder", "stepped"] = "stepped"
    """With ``sim_feature``: ``stepped`` shows the embedded default's stepped shaft (four
    diameters finished by two tools that wear at their own rates, part after part, with
    part-to-part scatter; its job is put in force on the first start); ``cylinder`` one
    diameter, ``sim_diameter_mm``."""
    sim_lathe: bool = False
    """The simulated camera shows what a virtual lathe cuts (``drivers/sim/lathe.py``,
    continuous turning): the tool wears at the drift's rate (a new insert every
    ``sim_drift_period_min``) and the CNC's wear offset moves the diameter, seen
    ``sim_lathe_dead_time_s`` after it was applied; the CNC is the simulated PLC (its applied
    total, read over Modbus) or, with ``plc.source = "pull"``, whoever sets it on the
    camera's control port (the LinuxCNC demo sets LinuxCNC's tool offset)."""
    sim_lathe_paced: bool = False
    """The virtual lathe's time stands until its camera's control port moves it
    (``{"do": "advance_lathe", "s": ...}``): a test drives it in step with the gauge's
    measurements, from the first frame on; off, it runs on the wall clock from the camera's
    start."""
    sim_lathe_dead_time_s: float = Field(1.2, ge=0, le=600)
    """From the cut to the laser line: laser distance over feed (2 mm at 100 mm/min)."""
    sim_lathe_thermal_um: float = Field(0.0, ge=-200, le=200)
    """The virtual lathe's machine grows by this much on the diameter as it warms up ..."""
    sim_lathe_thermal_tau_s: float = Field(1200.0, gt=0, le=86400)
    """... with this time constant (what an insert change loses when its wear offset is
    zeroed)."""
    sim_seed: int = 0
    sim_replay_frames: int = Field(32, ge=0, le=1000)
    """The simulated GigE camera renders a ring of this many frames at start and then only
    sends them (re-rendered in the background when the diameter changes); the in-process rig
    renders each when it first sends it (and again after a change of diameter); 0 renders
    every frame sent."""

    @property
    def roi_enabled(self) -> bool:
        """Whether the region of interest follows the stripe."""
        return self.source in ("sim", "rig") if self.auto_roi is None else self.auto_roi


class TlsSettings(_Section):
    """Modbus/TCP Security (TLS, port 802 by convention): this end's certificate and key,
    and the authority whose certificates the other end must show (PEM files)."""

    certfile: Path
    keyfile: Path
    cafile: Path


class PlcSettings(_Section):
    """The CNC/PLC the offsets go to: ``modbus`` writes them to its registers (``sim``: to
    the simulated PLC), ``pull`` posts them in the gauge's own registers for a CNC that polls
    (map version 2; ``deploy/linuxcnc``), ``none`` nowhere."""

    source: Literal["sim", "modbus", "pull", "none"] = "sim"
    host: str = "127.0.0.1"
    port: int = Field(5021, ge=1, le=65535)
    unit_id: int = Field(1, ge=0, le=255)
    offset_address: int = Field(100, ge=0, le=65533)
    ack_address: int = Field(104, ge=0, le=65534)
    total_address: int = Field(106, ge=0, le=65534)
    word_order: Literal["big", "little"] = "big"
    ack_timeout_s: float = Field(3.0, gt=0, le=60)
    tool_stride: int | None = Field(None, ge=0, le=10000)
    """Registers from one tool's offset block to the next in the CNC (tool n's at
    ``n * tool_stride`` past the addresses above): the offsets of a job of several tools then
    go each to its tool's block. 0: the CNC keeps one block, and such offsets are only
    proposed. None: 10 for the simulated PLC, 0 for a real one."""
    sim_ack_delay_s: float = Field(0.05, ge=0)
    tls: TlsSettings | None = None
    """``source = "modbus"`` over Modbus/TCP Security: the CNC's certificate must come from
    ``tls.cafile``'s authority and name ``host``; the gauge shows ``tls.certfile``. None:
    plain Modbus TCP."""

    def stride(self) -> int:
        """``tool_stride`` as in force (see there)."""
        if self.tool_stride is not None:
            return self.tool_stride
        return 10 if self.source == "sim" else 0

    @model_validator(mode="after")
    def _tls_for_a_real_cnc(self) -> PlcSettings:
        if self.tls is not None and self.source != "modbus":
            raise ValueError(f"plc.tls is for a CNC the gauge writes to (source = \"modbus\"),"
                             f" not for source = \"{self.source}\"")
        return self


class ModbusSettings(_Section):
    """The Modbus TCP server the CNC polls."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = Field(5020, ge=0, le=65535)
    unit_id: int = Field(1, ge=0, le=255)
    word_order: Literal["big", "little"] = "big"
    reset_command: bool = False
    """Whether the CNC may reset compensation through the ``command`` register (2). Off, a
    reset from the register is refused and logged; a technician resets over the API. On, the
    CNC's program takes that authority: its reset moves the reference of the cumulative limit
    as a technician's does."""
    acknowledge_command: bool = False
    """Whether the CNC may acknowledge a plausibility alarm through the ``command`` register
    (3). Off, it is refused and logged; a technician acknowledges over the API. The alarm
    (a deviation beyond the plausibility limit: nothing is written while it lasts) ends by
    itself at the next plausible measurement: acknowledging only ends it sooner."""
    result_measurements: int = Field(3, ge=1, le=100)
    """The good measurements of the feature, taken after a "feature measured" request
    (``measure_request``), that the gauge answers it with."""
    result_within_s: float = Field(5.0, gt=0.0, le=600.0)
    """A request not answered with a measurement this long after it is answered refused,
    with the reason of the last measurement the gauge could not use."""
    allowed_clients: list[str] = ["127.0.0.0/8", "::1"]
    """Addresses or networks that may connect (others are disconnected at once, counted and
    logged): loopback by default; on an installation the CNC's address and whoever reads the
    registers."""
    writers: list[str] = ["127.0.0.1", "::1"]
    """Those of ``allowed_clients`` that may write nominal, tolerances and commands (the
    CNC's address on an installation); the others read, and their writes get exception 0x01
    and change nothing."""
    max_connections: int = Field(16, ge=1, le=1000)
    """Clients connected at once; one more is disconnected."""
    tls: TlsSettings | None = None
    """Serve Modbus/TCP Security instead of plain Modbus TCP (set ``port = 802``): clients
    must show a certificate from ``tls.cafile``'s authority; the address checks above still
    apply. None: plain Modbus TCP."""

    @field_validator("allowed_clients", "writers")
    @classmethod
    def _addresses(cls, v: list[str]) -> list[str]:
        for item in v:
            try:
                ipaddress.ip_network(item, strict=False)
            except ValueError:
                raise ValueError(f"{item!r} is not an address or a network") from None
        return v


class ApiSettings(_Section):
    """The HTTP API and dashboard, and who may do what."""

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    open_read: bool = True
    """Reading without a key is allowed from ``read_networks``; elsewhere a key is needed."""
    read_networks: list[str] = ["127.0.0.0/8", "::1/128", "10.0.0.0/8", "172.16.0.0/12",
                                "192.168.0.0/16"]
    max_body_bytes: int = Field(1 << 20, ge=1024)
    """Largest request body (413 past it, checked before the body is read or the key)."""
    max_image_bytes: int = Field(32 << 20, ge=1024)
    """Largest image upload to a calibration session."""
    max_connections: int = Field(200, ge=4)
    """Connections and requests served at once (uvicorn's limit_concurrency; 503 past it)."""
    max_streams: int = Field(32, ge=1)
    """Live streams (SSE) open at once; 503 past it."""
    shutdown_s: float = Field(3.0, gt=0)
    """On SIGTERM, open connections (a dashboard's live stream never ends by itself) get this
    long before they are closed and the service stops."""
    max_calibration_sessions: int = Field(4, ge=1)
    """Calibration sessions open at once (409 past it; expired ones are deleted first)."""
    max_session_images: int = Field(200, ge=1)
    """Images one calibration session may hold."""
    session_expiry_h: float = Field(24.0, gt=0)
    """A calibration session untouched this long is deleted with its images."""
    calibration_step_budget_s: float = Field(600.0, gt=0, le=86400)
    """A calibration step (each in a worker process of its own) that runs longer is stopped
    and fails, naming this setting: 25 views of a 14x10 ChArUco board take under a minute
    of one core."""
    trusted_proxies: list[str] = []
    """Addresses of reverse proxies whose ``X-Forwarded-For``/``-Proto`` the gauge believes
    (uvicorn's ``forwarded_allow_ips``). Empty (the default): none, not even loopback; the
    peer's own address is what the lock-out after wrong keys, the audit and the host check
    see."""
    trusted_hosts: list[str] = []
    """Host names the API and dashboard answer to besides addresses, ``localhost`` and this
    machine's own name (others get 400: a page of another site cannot rebind its name to the
    gauge and read it)."""
    key_file: Path | None = None
    """The API keys kept as hashes (``shaftgauge api-key add`` makes one and prints it once;
    an installation's way: ``/etc/shaftgauge/api-keys.json``)."""
    tls_certfile: Path | None = None
    """HTTPS: the server's certificate (PEM, with its chain); with ``tls_keyfile``. None:
    plain HTTP (on a plant network keys then cross it readable)."""
    tls_keyfile: Path | None = None
    """HTTPS: the certificate's private key (PEM)."""
    tls_self_signed: bool = False
    """Make a self-signed certificate on first start where ``tls_certfile``/``tls_keyfile``
    name no file (beside the store when they are not set); its SHA-256 fingerprint is printed
    at every start, for the operator to compare with what the browser shows."""
    keys: dict[str, Literal["operator", "technician", "admin"]] = {}
    """API key -> role, in plain: for development and tests (an installation uses
    ``key_file``). Roles: operator reads where reading is not open; technician: calibrations,
    feature, shadow mode, commands, temperature; admin: also compensation tuning. Never in
    the repository."""

    @field_validator("read_networks")
    @classmethod
    def _networks(cls, v: list[str]) -> list[str]:
        for net in v:
            try:
                ipaddress.ip_network(net, strict=False)
            except ValueError as err:
                raise ValueError(f"{net!r} is not a network: {err}") from None
        return v

    @field_validator("keys")
    @classmethod
    def _key_length(cls, v: dict[str, str]) -> dict[str, str]:
        short = sum(1 for k in v if len(k) < 16)
        if short:  # never a key, nor a part of one, in a message
            raise ValueError(f"API keys must be at least 16 characters: {short} of the "
                             f"{len(v)} are shorter")
        return v

    @model_validator(mode="after")
    def _tls_pair(self) -> ApiSettings:
        if (self.tls_certfile is None) != (self.tls_keyfile is None):
            raise ValueError("tls_certfile and tls_keyfile go together: set both, or neither "
                             "(with tls_self_signed = true, neither puts them beside the store)")
        return self


class StoreSettings(_Section):
    """Where calibrations and the compensation log live."""

    path: Path = Path("shaftgauge-data/shaftgauge.db")
    create_if_missing: bool = True
    log_max_age_days: float = Field(365.0, gt=0)
    """Compensation decisions older than this are deleted."""
    log_max_rows: int = Field(1_000_000, ge=1000)
    """At most this many rows of compensation decisions are kept (the oldest go first; a run
    of identical quiet decisions is one row)."""
    archive_hz: float = Field(1.0, ge=0, le=100)
    """Measurements kept for the quality export (``/api/v1/export/aqdef``): at most this
    many a second (the latest record, with its fused value); 0: none."""
    archive_max_rows: int = Field(2_000_000, ge=1000)
    """At most this many archived measurements (the oldest go first)."""


class MeasurementSettings(_Section):
    """How frames become diameters."""

    method: Method = Method.AXIS
    workers: int = Field(2, ge=1, le=32)
    processes: bool = True
    """Measure in ``workers`` processes (else threads, which contend with the service's
    event loop for the interpreter: frame -> registers latency grows tenfold at 100
    frames/s)."""
    max_rate_hz: float | None = Field(None, gt=0)
    """At most this many frames a second are measured (a CPU budget on a shared PC); the
    camera's frames beyond it are dropped from its queue and counted. None: as many as the
    cores measure."""
    history: int = Field(20000, ge=10, le=10_000_000)
    fuse_frames: int = Field(10, ge=1, le=1000)
    axis_sigma_mm: float = Field(0.001, gt=0, le=1.0)
    optics_blur_px: float = Field(0.7, ge=0, le=10)
    sheet_correction: bool = True
    """Take out the error the light sheet's thickness leaves on a curved surface (axis,
    geometric)."""
    sheet_sigma_mm: float | None = Field(None, gt=0, le=5.0)
    """The sheet's thickness (Gaussian sigma, mm), e.g. from the laser's data sheet; unset, it
    is estimated from the stripe's width in each frame."""
    track_axis: bool = True
    reflection_check_hz: float = Field(5.0, ge=0)
    """Frames a second checked for a reflection beside the stripe (a machine part or the
    chuck mirroring the laser) while none is seen; every frame while one is. A lopsided
    stripe is always checked. ``inf``: every frame; 0: only lopsided ones."""
    max_age_s: float = Field(5.0, gt=0)
    """A measurement older than this no longer counts as current (status, Modbus)."""
    master_interval_h: float | None = Field(None, gt=0)
    """A master check is due this often; when overdue (or failed) no offset is written."""
    master_limit_mm: float = Field(0.003, gt=0)
    """A master check passes when the corrected master reads within this of its certificate."""
    max_correction_offset_mm: float = Field(0.02, gt=0)
    """A master correction whose offset is larger than this is refused (the calibration is
    wrong, or the master's certificate: calibrate again rather than correct)."""
    max_correction_scale_error: float = Field(0.002, gt=0)
    """A master correction whose scale differs from 1 by more than this is refused."""


class SpindleSettings(_Section):
    """Each frame's spindle angle, and the run-out the gauge takes.

    With the angle known, a surface that is not concentric with the spindle axis (raw stock,
    a second clamping, a part badly seated) is measured about its own centre at that angle
    once a revolution of frames has shown where it goes round; without it such a surface is
    refused as not concentric. Angles count right-handed about the calibration's
    ``axis.direction``."""

    source: Literal["none", "encoder"] = "none"
    """``encoder``: the camera is triggered by the spindle's encoder every ``deg_per_frame``
    degrees (``camera.trigger = "hardware"``; the simulated cameras turn their shaft that much
    a frame), so a frame's angle follows from its frame number. ``none``: not known."""
    deg_per_frame: float = Field(0.0, gt=-360, lt=360)
    """The spindle's turn from one triggered frame to the next (encoder pulses per frame
    times degrees per pulse; negative when the encoder counts against the axis direction)."""
    zero_deg: float = 0.0
    """The spindle angle at frame number 0 (only the run-out's phase depends on it)."""
    max_tir_mm: float = Field(0.02, gt=0)
    """Run-out (TIR, what a dial indicator reads) beyond which no offset is written: the
    surface under the laser is not the one the tool is cutting concentric."""

    @model_validator(mode="after")
    def _a_step(self) -> SpindleSettings:
        if self.source == "encoder" and self.deg_per_frame == 0:
            raise ValueError("spindle.deg_per_frame: the encoder's turn a frame is needed "
                             "with source = 'encoder'")
        return self


class TemperatureSettings(_Section):
    """Part temperature, for the diameter at 20 C."""

    part_temp_c: float | None = Field(None, ge=-50, le=300)
    alpha_per_k: float = Field(11.5e-6, ge=0, lt=1e-3)


class SpcConfig(_Section):
    """Statistical process control of the feature (``service/quality/monitor.py``)."""

    subgroup_size: int = Field(5, ge=2, le=25)
    member_spacing: int | None = Field(None, ge=1, le=100_000)
    """Measurements between two values of a subgroup; None: ``measurement.fuse_frames`` (no
    two values share a frame)."""
    every_s: float = Field(5.0, ge=0)
    """A subgroup is started this often (seconds)."""
    baseline_subgroups: int = Field(20, ge=2, le=1000)
    """Subgroups that set the control limits after a start, a reset or a new nominal."""
    window_subgroups: int = Field(125, ge=2, le=100_000)
    """Subgroups the capability figures are computed over (the latest)."""
    rules: list[int] = Field(default_factory=lambda: [1, 2, 3, 4, 5, 6, 7, 8])
    """Nelson's tests that raise an event (1-8)."""

    @field_validator("rules")
    @classmethod
    def _known_rules(cls, v: list[int]) -> list[int]:
        bad = [r for r in v if r not in range(1, 9)]
        if bad:
            raise ValueError(f"rules are numbered 1-8 (Nelson's tests), not {bad}")
        return v


class QualitySettings(_Section):
    """When the type-1 gauge study blocks offset writes (offsets only proposed, the
    ``gauge_study_failed`` fault bit set)."""

    study_max_age_h: float | None = Field(None, gt=0)
    """A study older than this blocks; None: no period."""
    min_index: float = Field(1.33, gt=0)
    """Cg and Cgk below this fail a study."""
    study_required: bool = False
    """No study yet blocks."""
    resolution_mm: float = Field(0.0001, gt=0)
    """The gauge's reported resolution (0.1 um: the Modbus registers' unit)."""


class MqttSettings(_Section):
    """The plant's MQTT broker (``docs/mqtt.md``): on when ``host`` is set."""

    host: str | None = None
    port: int = Field(1883, ge=1, le=65535)
    gauge_id: str | None = None
    """This gauge's name in the plant (topics, payloads); None: the host name."""
    topic_prefix: str | None = None
    """None: ``shaftgauge/<gauge_id>``."""
    client_id: str | None = None
    """None: ``shaftgauge-<gauge_id>`` (stable, so the broker knows the gauge again)."""
    username: str | None = None
    password: str | None = None
    """Set them in the environment (``SHAFTGAUGE_MQTT__PASSWORD``), not in the file."""
    tls_ca: Path | None = None
    """The CA that signed the broker's certificate: TLS on when set."""
    tls_cert: Path | None = None
    tls_key: Path | None = None
    """This gauge's client certificate and key, for brokers that ask for one."""
    qos_measurement: Literal[0, 1, 2] = 0
    qos_decision: Literal[1, 2] = 1
    qos_state: Literal[0, 1, 2] = 1
    measurement_hz: float = Field(10.0, gt=0, le=1000)
    health_s: float = Field(10.0, gt=0)
    decision_repeat_s: float = Field(10.0, ge=0)
    """A quiet decision (held, refused, proposed) that repeats the previous one's kind and
    code is sent again at most this often (with the count of repeats); every other decision
    is sent."""
    outbox_max: int = Field(100_000, ge=10)
    """Decisions kept for the broker while it is away; past this the oldest are dropped
    (counted, and a problem reported)."""
    keepalive_s: int = Field(15, ge=5, le=3600)
    reconnect_s: float = Field(2.0, gt=0, le=300)

    @model_validator(mode="after")
    def _tls_pair(self) -> MqttSettings:
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ValueError("tls_cert and tls_key: give both or neither")
        return self


class OpcUaSettings(_Section):
    """The OPC UA server (``docs/opcua.md``)."""

    enabled: bool | None = None
    """None: on for the embedded default (a simulated camera), off on an installation."""
    host: str = "127.0.0.1"
    port: int = Field(4840, ge=1, le=65535)
    technicians: dict[str, str] = Field(default_factory=dict)
    """User name -> password of the users with the technician role (may call ``MeasureNow``
    and ``ResetCompensation``); anonymous users read and subscribe only. Set it in the
    environment: ``SHAFTGAUGE_OPCUA__TECHNICIANS='{"anna": "..."}'``."""
    certificate_dir: Path | None = None
    """Where the server's certificate and key are kept (made on first start); None: beside
    the store."""
    none_security: bool | None = None
    """The unsecured endpoint (security policy None: anonymous reading, and a technician's
    password encrypted with the server's certificate but the session unsigned). None: on for
    the embedded default (a simulated camera), off on an installation, where only the signed
    and encrypted endpoint (Basic256Sha256) is offered."""
    trusted_dir: Path | None = None
    """The trust list: client certificates (PEM or DER), or the certificates of the
    authorities that issued them, that may open a secure channel; any other client
    certificate is refused, logged with its name. Read again at every connection. None:
    ``trusted`` in the certificate directory."""
    max_connections: int = Field(10, ge=1, le=1000)
    """Clients connected at once (an HMI, an aggregator, an engineer's browser: a few); one
    more is refused at connection."""
    max_subscriptions: int = Field(20, ge=1, le=1000)
    """Subscriptions in the whole server (BadTooManySubscriptions past it), at most 5 a
    session."""
    max_monitored_items: int = Field(1000, ge=1, le=100_000)
    """Monitored items in the whole server (BadTooManyMonitoredItems past it): the address
    space has a few hundred variables."""
    min_interval_ms: float = Field(100.0, ge=10.0, le=60_000.0)
    """The shortest sampling and publishing interval granted (a shorter one asked for is
    revised to it): the variables change every 100 ms at most."""


# The compensation settings are the controller's own dataclass, validated here at the edge
# (types, and no unknown keys); their consistency is checked by the controller when it starts.
CompensationSettings.__pydantic_config__ = ConfigDict(extra="forbid")  # type: ignore[attr-defined]


class Settings(BaseSettings):
    """Everything ``shaftgauge serve`` needs."""

    model_config = SettingsConfigDict(env_prefix="SHAFTGAUGE_", env_nested_delimiter="__",
                                      extra="forbid", frozen=True)

    camera: CameraSettings = CameraSettings()
    plc: PlcSettings = PlcSettings()
    modbus: ModbusSettings = ModbusSettings()
    api: ApiSettings = ApiSettings()
    store: StoreSettings = StoreSettings()
    measurement: MeasurementSettings = MeasurementSettings()
    temperature: TemperatureSettings = TemperatureSettings()
    spindle: SpindleSettings = SpindleSettings()
    compensation: CompensationSettings = CompensationSettings()
    spc: SpcConfig = SpcConfig()
    quality: QualitySettings = QualitySettings()
    mqtt: MqttSettings = MqttSettings()
    opcua: OpcUaSettings = OpcUaSettings()
    log_level: Literal["debug", "info", "warning", "error"] = "info"

    @model_validator(mode="after")
    def _encoder_triggers_the_camera(self) -> Settings:
        if self.spindle.source == "encoder" and self.camera.source == "gige" \
                and self.camera.trigger != "hardware":
            raise ValueError("spindle.source = 'encoder' needs camera.trigger = 'hardware': "
                             "a free-running camera's frames are not at fixed spindle steps")
        if self.spindle.source == "encoder" and not self.measurement.track_axis:
            raise ValueError("spindle.source = 'encoder' needs measurement.track_axis = true: "
                             "the run-out is fitted from the frames' free fits")
        return self

    @model_validator(mode="after")
    def _compensation_consistent(self) -> Settings:
        problems = self.compensation.problems()
        if problems:
            raise ValueError("compensation: " + "; ".join(problems))
        return self

    @classmethod
    def settings_customise_sources(
        cls, settings_cls: type[BaseSettings], init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource, dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        return (env_settings, init_settings)  # the environment overrides the file


def load_settings(path: str | Path | None = None) -> Settings:
    """Read the TOML file (if any) and the environment; validate.

    Raises
    ------
    ConfigError
        Naming the file and every bad setting.
    """
    data: dict[str, Any] = {}
    where = "environment"
    if path is not None:
        p = Path(path)
        where = str(p)
        try:
            data = tomllib.loads(p.read_text())
        except OSError as err:
            raise ConfigError(f"{p}: cannot read ({err.strerror})") from None
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"{p}: not valid TOML ({err})") from None
    try:
        return Settings(**data)
    except ValidationError as err:
        raise ConfigError(f"{where}: {format_validation_error(err, _without_keys)}") from None
    except SettingsError as err:  # a SHAFTGAUGE_... variable that is not valid JSON
        raise ConfigError(f"environment: a SHAFTGAUGE_ variable cannot be read ({err}); a "
                          "table such as SHAFTGAUGE_API__KEYS must be JSON") from None


def _without_keys(loc: tuple) -> tuple:
    """A field's path with an API key in it replaced (a key is its own field name in
    ``api.keys.<key>``)."""
    return (*loc[:2], "<a key>", *loc[3:]) if loc[:2] == ("api", "keys") and len(loc) > 2 \
        else loc
