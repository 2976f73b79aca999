"""The gauge as an OPC UA server (asyncua): live variables, and two methods for technicians.

Address space (namespace ``urn:shaftgauge``; ``docs/opcua.md``), named after OPC 40001
(Machinery: ``Identification``, ``Monitoring``) and OPC 40501 (Machine Tools: ``Production``,
``Equipment``) where they have a name for the thing::

    Objects/Shaftgauge
        Identification   Manufacturer, Model, SerialNumber, SoftwareRevision
        Monitoring       Diameter, Uncertainty, FusedDiameter, Deviation (mm), InTolerance,
                         Status, Reason, MeasurementSeq, CalibrationId, CameraState, PlcState,
                         RunoutTir, RunoutPhase (deg), Ront (mm), Lobes
        Compensation     State, CumulativeOffset, LastOffset (mm), Shadow
        MeasureNow()         -> Diameter (mm), Status         technicians only
        ResetCompensation()  -> Result                        technicians only

Anonymous users read, browse and subscribe; users of ``opcua.technicians`` (user name and
password, sent encrypted with the server's certificate) may also call the methods. Nobody
writes variables. The server's certificate is made on first start and kept, its key readable
by the service alone. On an installation only the signed and encrypted endpoint is offered,
and a client's certificate must be in the trust list (``opcua.trusted_dir``); a certificate
refused and a login refused are logged and counted.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import math
import os
import socket
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from asyncua.server.user_managers import UserManager
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from service.config import OpcUaSettings
from service.failures import FailureWindow

log = logging.getLogger("shaftgauge.opcua")

NAMESPACE = "urn:shaftgauge"
UPDATE_S = 0.1
"""How often the variables are refreshed from the gauge (subscribers see changes at this
rate, at most)."""

_DOUBLE, _STRING, _BOOL, _INT = (ua.VariantType.Double, ua.VariantType.String,
                                 ua.VariantType.Boolean, ua.VariantType.Int64)
MONITORING = {"Diameter": _DOUBLE, "Uncertainty": _DOUBLE, "FusedDiameter": _DOUBLE,
              "Deviation": _DOUBLE, "InTolerance": _BOOL, "Status": _STRING,
              "Reason": _STRING, "MeasurementSeq": _INT, "CalibrationId": _INT,
              "CameraState": _STRING, "PlcState": _STRING, "RunoutTir": _DOUBLE,
              "RunoutPhase": _DOUBLE, "Ront": _DOUBLE, "Lobes": _INT}
COMPENSATION = {"State": _STRING, "CumulativeOffset": _DOUBLE, "LastOffset": _DOUBLE,
                "Shadow": _BOOL}
CHARACTERISTIC = {"CharacteristicIdentifier": _INT, "Name": _STRING, "Nominal": _DOUBLE,
                  "LowerTolerance": _DOUBLE, "UpperTolerance": _DOUBLE,
                  "ResultValue": _DOUBLE, "ResultEvaluation": _STRING, "InJob": _BOOL}
"""A feature of the job in force, in OPC 40210's names where they fit (lengths in mm; the
tolerances as deviations from the nominal; ``ResultEvaluation``: ``InTolerance``,
``AboveTolerance``, ``BelowTolerance``, or ``NotMeasured``)."""
TOOL = {"ToolNumber": _INT, "OffsetNumber": _INT, "State": _STRING,
        "CumulativeOffset": _DOUBLE, "LastOffset": _DOUBLE, "InJob": _BOOL}
"""An offset entry of the job in force (``Tools/Tool<t>`` for tool t's own entry,
``Tools/Tool<t>_<n>`` for its offset number n; ``OffsetNumber`` 0: the tool's own): its
compensation's state and offsets, mm. In a job of several entries the gauge-wide
``CumulativeOffset`` and ``LastOffset`` have no value (NaN): each entry's are here."""
GROUPS = {"Characteristics": ("Characteristic", CHARACTERISTIC), "Tools": ("Tool", TOOL)}
"""The objects made as the job in force has them: folder -> (object name's stem, variables);
one that leaves the job stays with ``InJob`` false."""
_DEFAULTS = {_DOUBLE: math.nan, _STRING: "", _BOOL: False, _INT: -1}

_CALL = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
_WRITE = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
_READ_ONLY = frozenset(ua.NodeId(t) for t in USER_TYPES) - {_CALL, _WRITE}


SUBSCRIPTIONS_A_SESSION = 5


def limit_clients(server: Server, s: OpcUaSettings) -> None:
    """What anonymous clients may ask of the server, so that no client starves the gauge's
    event loop (the CNC's Modbus link shares it): connections, subscriptions (in all and a
    session), monitored items, and the shortest sampling and publishing intervals (a
    shorter one is revised up, as the specification lets a server do). asyncua caps the
    first two in all; the rest are checked here, before its own services run."""
    iserver = server.iserver
    iserver.max_connections = s.max_connections
    iserver.max_subscriptions = s.max_subscriptions
    service = iserver.subscription_service
    create_subscription = service.create_subscription
    create_items = service.create_monitored_items

    async def limited_subscription(params: ua.CreateSubscriptionParameters, callback: Any,
                                   session_id: ua.NodeId, request_callback: Any = None) -> Any:
        own = sum(1 for sub in service.subscriptions.values() if sub.session_id == session_id)
        if own >= SUBSCRIPTIONS_A_SESSION:
            raise ServiceError(ua.StatusCodes.BadTooManySubscriptions)
        params.RequestedPublishingInterval = max(params.RequestedPublishingInterval,
                                                 s.min_interval_ms)
        return await create_subscription(params, callback, session_id, request_callback)

    async def limited_items(params: ua.CreateMonitoredItemsParameters) -> list:
        held = sum(len(sub.monitored_item_srv._monitored_items)  # asyncua keeps no count
                   for sub in service.subscriptions.values())
        room = max(0, s.max_monitored_items - held)
        asked = list(params.ItemsToCreate)
        for item in asked:
            item.RequestedParameters.SamplingInterval = max(
                item.RequestedParameters.SamplingInterval, s.min_interval_ms)
        params.ItemsToCreate = asked[:room]
        results = await create_items(params) if params.ItemsToCreate else []
        refused = ua.MonitoredItemCreateResult()
        refused.StatusCode = ua.StatusCode(ua.StatusCodes.BadTooManyMonitoredItems)
        return list(results) + [refused] * (len(asked) - len(params.ItemsToCreate))

    service.create_subscription = limited_subscription
    service.create_monitored_items = limited_items


def _same(a: Any, b: Any) -> bool:
    nan = isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)
    return nan or (type(a) is type(b) and a == b)


def _code_name(err: ua.UaError) -> str:
    code = getattr(err, "code", None)
    return ua.StatusCode(code).name if isinstance(code, int) else type(err).__name__


class TechnicianRoles(PermissionRuleset):
    """Anonymous: read, browse, subscribe. Technicians: that, and call methods. Writes: no
    one (the gauge's settings change through its REST API, logged with who)."""

    def check_validity(self, user: User | None, action_type_id: ua.NodeId,
                       body: Any) -> bool:
        if action_type_id in _READ_ONLY:
            return True
        if action_type_id == _CALL:
            return user is not None and user.role is UserRole.User
        return False


LOGIN_FAILURES = 10
LOGIN_WINDOW_S = 60.0
UNKNOWN_NAMES = "(names that are no technician's)"


class Technicians(UserManager):
    """Users from ``opcua.technicians``; anyone else connects anonymously or not at all.

    A name with ``LOGIN_FAILURES`` wrong passwords within ``LOGIN_WINDOW_S`` is refused,
    whatever the password, until the window has passed (asyncua does not tell a user manager
    the client's address, so the count is per name; the names that are no technician's
    share one count)."""

    def __init__(self, passwords: dict[str, str],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._passwords = dict(passwords)
        self._clock = clock
        self._failures = FailureWindow(LOGIN_FAILURES, LOGIN_WINDOW_S)
        self.refused = 0
        self.last_refused = ""

    def get_user(self, iserver: Any, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        if username is None:  # anonymous (a channel certificate alone is no user)
            return User(role=UserRole.Anonymous)
        known = self._passwords.get(username)
        who = username if known is not None else UNKNOWN_NAMES
        now = self._clock()
        wait_s = self._failures.retry_after(who, now)
        if wait_s > 0:
            self.refused += 1
            self.last_refused = (f"login of {username!r} refused: {LOGIN_FAILURES} wrong "
                                 f"passwords within {LOGIN_WINDOW_S:g} s; tried again too "
                                 f"soon (wait {wait_s:.0f} s)")
            return None  # said once, when the name was held
        if known is not None and hmac.compare_digest(known.encode(), (password or "").encode()):
            return User(role=UserRole.User, name=username)
        # a wrong password or an unknown user: refused, and said (never the password)
        self.refused += 1
        held = self._failures.failed(who, now) >= LOGIN_FAILURES
        self.last_refused = f"login of {username!r} refused: " + (
            "wrong password" if known is not None else "no such technician") + (
            f"; {who} held for {LOGIN_WINDOW_S:g} s after {LOGIN_FAILURES} failures"
            if held else "")
        log.warning("OPC UA %s (%d refused so far)", self.last_refused, self.refused)
        return None


@dataclass(frozen=True)
class GaugeView:
    """What the server shows and does, as callables into the gauge.

    ``values()`` returns the current values by variable name (``MONITORING`` and
    ``COMPENSATION``; None for "none"), and under ``Characteristics`` each feature of the job
    in force by its number (``CHARACTERISTIC``) and under ``Tools`` each tool by its T
    number (``TOOL``); ``measure_now()`` takes a new measurement
    and returns ``(diameter_mm or None, status)``; ``reset(who)`` resets compensation and
    returns what happened.
    """

    values: Callable[[], dict[str, Any]]
    measure_now: Callable[[], Awaitable[tuple[float | None, str]]]
    reset: Callable[[str], Awaitable[str]]
    serial_number: str = ""
    software_revision: str = ""


class OpcUaServer:
    """The OPC UA server of one gauge.

    Parameters
    ----------
    settings : OpcUaSettings
        Endpoint, technicians, where the certificate is kept.
    view : GaugeView
        The gauge's values and methods.
    certificate_dir : Path
        Where the certificate is kept when the settings do not say.
    """

    name = "opcua"

    def __init__(self, settings: OpcUaSettings, view: GaugeView, certificate_dir: Path) -> None:
        self.settings, self.view = settings, view
        self.certificate_dir = settings.certificate_dir or certificate_dir
        self.server: Server | None = None
        self.port: int | None = None
        self.problem = ""
        self.started = asyncio.Event()
        """Set once ``start`` has ended: serving (``server``) or not (``problem`` says why)."""
        self.trusted_dir = settings.trusted_dir or self.certificate_dir / "trusted"
        self.users = Technicians(settings.technicians)
        self.refused_certificates = 0
        self.last_refused_certificate = ""
        self._nodes: dict[str, Any] = {}
        self._written: dict[Any, Any] = {}
        self._members: dict[tuple[str, int | str], dict[str, Any]] = {}  # (folder, key)
        self._folders: dict[str, Any] = {}
        self._idx = 0
        self.calls = {"MeasureNow": 0, "ResetCompensation": 0}

    @property
    def endpoint(self) -> str:
        """``opc.tcp://host:port``."""
        return f"opc.tcp://{self.settings.host}:{self.port or self.settings.port}"

    async def _certificate(self) -> tuple[Path, Path]:
        self.certificate_dir.mkdir(parents=True, exist_ok=True)
        key, cert = self.certificate_dir / "server-key.pem", self.certificate_dir / "server.der"
        host = socket.gethostname()
        await setup_self_signed_certificate(
            key, cert, NAMESPACE, host, [ExtendedKeyUsageOID.SERVER_AUTH],
            {"commonName": f"shaftgauge@{host}", "organizationName": "shaftgauge"})
        os.chmod(key, 0o600)  # asyncua writes it with the process's umask
        return key, cert

    async def _validate(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        """A client's certificate: in date, naming the client's application URI, and in the
        trust list (itself or its issuer; read again each time, so a certificate put there
        counts at the next connection). Refused: logged with its name, and raised."""
        self.trusted_dir.mkdir(parents=True, exist_ok=True)
        store = TrustStore([self.trusted_dir], [])
        options = (CertificateValidatorOptions.TIME_RANGE | CertificateValidatorOptions.URI
                   | CertificateValidatorOptions.TRUSTED)
        try:
            try:
                await store.load()
            except ValueError:  # no certificate there at all (cryptography's empty store)
                raise ServiceError(ua.StatusCodes.BadCertificateUntrusted) from None
            await CertificateValidator(options, store).validate(cert, app)
        except ua.UaError as err:
            names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
            name = str(names[0].value) if names else cert.subject.rfc4514_string()
            self.refused_certificates += 1
            self.last_refused_certificate = (
                f"client certificate {name!r} of {app.ApplicationUri} refused: "
                f"{_code_name(err)} (trust it by putting it into {self.trusted_dir})")
            log.warning("OPC UA %s", self.last_refused_certificate)
            raise

    async def start(self) -> None:
        """Start serving (a port in use or a bad certificate: a problem, not a crash)."""
        s = self.settings
        try:
            server = Server(user_manager=self.users)
            await server.init()
            limit_clients(server, s)
            server.set_server_name("shaftgauge")
            await server.set_application_uri(NAMESPACE)
            key, cert = await self._certificate()
            await server.load_certificate(str(cert))
            await server.load_private_key(str(key))
            policies = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt]
            if s.none_security:
                policies.insert(0, ua.SecurityPolicyType.NoSecurity)
            server.set_security_policy(policies, permission_ruleset=TechnicianRoles())
            server.set_certificate_validator(self._validate)
            server.set_identity_tokens([ua.AnonymousIdentityToken, ua.UserNameIdentityToken])
            server.set_endpoint(f"opc.tcp://{s.host}:{s.port}/")
            await self._build(server)
            await server.start()
        except (OSError, ValueError, ua.UaError) as err:
            self.problem = f"OPC UA server on {s.host}:{s.port} did not start: {err}"
            log.error("%s", self.problem)
        else:
            self.server, self.port = server, s.port
            log.info("OPC UA server on %s", self.endpoint)
        finally:
            self.started.set()

    async def _build(self, server: Server) -> None:
        idx = await server.register_namespace(NAMESPACE)
        gauge = await server.nodes.objects.add_object(idx, "Shaftgauge")
        ident = await gauge.add_object(idx, "Identification")
        for name, value in (("Manufacturer", "shaftgauge"), ("Model", "shaftgauge"),
                            ("SerialNumber", self.view.serial_number),
                            ("SoftwareRevision", self.view.software_revision)):
            await ident.add_property(idx, name, value, _STRING)
        for folder, table in (("Monitoring", MONITORING), ("Compensation", COMPENSATION)):
            parent = await gauge.add_object(idx, folder)
            for name, vtype in table.items():
                self._nodes[name] = await parent.add_variable(
                    idx, name, ua.Variant(_DEFAULTS[vtype], vtype))
        self._idx = idx
        for folder in GROUPS:
            self._folders[folder] = await gauge.add_object(idx, folder)
        await gauge.add_method(idx, "MeasureNow", self._measure_now, [],
                               [ua.VariantType.Double, ua.VariantType.String])
        await gauge.add_method(idx, "ResetCompensation", self._reset, [],
                               [ua.VariantType.String])

    async def _measure_now(self, parent: ua.NodeId) -> list[ua.Variant]:
        self.calls["MeasureNow"] += 1
        diameter_mm, status = await self.view.measure_now()
        return [ua.Variant(math.nan if diameter_mm is None else diameter_mm, _DOUBLE),
                ua.Variant(status, _STRING)]

    async def _reset(self, parent: ua.NodeId) -> list[ua.Variant]:
        self.calls["ResetCompensation"] += 1
        return [ua.Variant(await self.view.reset("opcua:technician"), _STRING)]

    async def _member(self, folder: str, number: int | str) -> dict[str, Any]:
        """A feature's or an entry's object (``Characteristic<n>``, ``Tool<key>``), made when
        it is first seen."""
        nodes = self._members.get((folder, number))
        if nodes is None:
            stem, table = GROUPS[folder]
            obj = await self._folders[folder].add_object(self._idx, f"{stem}{number}")
            nodes = self._members[folder, number] = {
                name: await obj.add_variable(self._idx, name,
                                             ua.Variant(_DEFAULTS[vtype], vtype))
                for name, vtype in table.items()}
        return nodes

    async def _write(self, key: Any, node: Any, value: Any, vtype: ua.VariantType) -> None:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            value = _DEFAULTS[vtype]
        if key in self._written and _same(self._written[key], value):
            return
        await node.write_value(ua.Variant(value, vtype))
        self._written[key] = value

    async def refresh(self) -> None:
        """Write the gauge's current values into the variables that changed."""
        values = self.view.values()
        for folder, (_, table) in GROUPS.items():
            members: dict[int | str, dict[str, Any]] = values.get(folder) or {}
            known = {n for f, n in self._members if f == folder}
            for number in sorted({*members, *known}, key=str):
                nodes = await self._member(folder, number)
                got = {**members.get(number, {}), "InJob": number in members}
                for name, vtype in table.items():
                    await self._write((folder, number, name), nodes[name], got.get(name),
                                      vtype)
        for name, node in self._nodes.items():
            await self._write(name, node, values.get(name),
                              MONITORING.get(name) or COMPENSATION[name])

    async def run(self) -> None:
        """Start, then keep the variables current until cancelled."""
        await self.start()
        if self.server is None:
            return
        while True:
            await self.refresh()
            await asyncio.sleep(UPDATE_S)

    def status(self) -> dict[str, Any]:
        """Endpoint and state, JSON-ready."""
        return {"endpoint": self.endpoint, "running": self.server is not None,
                "problem": self.problem or None, "technicians": len(self.settings.technicians),
                "none_security": bool(self.settings.none_security),
                "refused_logins": self.users.refused,
                "last_refused_login": self.users.last_refused or None,
                "refused_certificates": self.refused_certificates,
                "last_refused_certificate": self.last_refused_certificate or None,
                "calls": dict(self.calls)}

    def problems(self) -> list[tuple[str, str]]:
        """What is wrong now, as (code, text)."""
        return [("opcua_down", self.problem)] if self.problem else []

    async def close(self) -> None:
        """Stop serving."""
        if self.server is not None:
            await self.server.stop()
            self.server = None
