"""The Modbus TCP server the CNC polls (pymodbus 3.16, built on ``SimDevice``/``SimData``).

The register bank is the source of truth: pymodbus checks framing, the unit id, address
ranges and read-only registers; a ``SimDevice`` action copies the bank into the requested
range before every read, and validates every write (whole entries only, values in range,
known command codes) before it reaches the bank. Bad requests get Modbus exception replies:
illegal function (coil access, or a write from a client that may not write), illegal data
address (unmapped, read-only, or half of a 32-bit pair), illegal data value (out of range, or a
feature that would not hold together: nothing of the write is applied), gateway target failed
to respond (another unit id).

Who may connect and who may write is ``ModbusAccess``: a client from elsewhere is disconnected
at once, one past the connection limit too, both counted and logged with its address; every
accepted write is logged with its peer.
"""

from __future__ import annotations

import asyncio
import contextvars
import ipaddress
import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusTcpServer, ModbusTlsServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.simulator.simcore import SimCore

from drivers.plc.registers import (
    NO_VALUE,
    REGISTERS,
    Command,
    Register,
    RegisterBank,
    from_words,
)
from drivers.plc.tls import CountedRefusals, TlsFiles, peer_name, server_context

log = logging.getLogger("shaftgauge.modbus")
# Refusals come as fast as a client sends: their own logger, rate-limited (RateLimited).
refused_log = logging.getLogger("shaftgauge.modbus.refused")

Network = ipaddress.IPv4Network | ipaddress.IPv6Network
LOOPBACK = ("127.0.0.0/8", "::1")
# The client whose request is being answered (set by its connection's handler, read by the
# register action within the same task).
_PEER: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_peer", default="")


def networks(spec: Iterable[str]) -> tuple[Network, ...]:
    """Addresses or networks (``10.0.0.5``, ``10.0.0.0/24``, ``::1``); ValueError names a bad
    one."""
    out = []
    for item in spec:
        try:
            out.append(ipaddress.ip_network(str(item).strip(), strict=False))
        except ValueError:
            raise ValueError(f"{item!r} is not an address or a network") from None
    return tuple(out)


def _within(host: str, nets: tuple[Network, ...]) -> bool:
    try:
        addr = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return False
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return any(addr in n for n in nets)


READER_CONNECTIONS_PER_ADDRESS = 4
"""Connections one reading client may hold at once (a SCADA, a dashboard: one or two)."""


@dataclass(frozen=True)
class ModbusAccess:
    """Who may use the gauge's Modbus server.

    Attributes
    ----------
    allowed : tuple of networks
        Clients that may connect (others are disconnected at once).
    writers : tuple of networks
        Clients that may write (nominal, tolerances, command); others read, and their writes
        are answered with exception 0x01 and change nothing.
    max_connections : int
        Connections at once; one more is disconnected. Clients that only read get
        ``reader_slots()`` of them, four an address at most: the rest is the writers'.
    """

    allowed: tuple[Network, ...] = field(default_factory=lambda: networks(LOOPBACK))
    writers: tuple[Network, ...] = field(default_factory=lambda: networks(("127.0.0.1",
                                                                          "::1")))
    max_connections: int = 16

    @classmethod
    def of(cls, allowed: Iterable[str], writers: Iterable[str],
           max_connections: int = 16) -> ModbusAccess:
        """From addresses and networks as written in the settings."""
        return cls(networks(allowed), networks(writers), max_connections)

    def reader_slots(self) -> int:
        """Connections the clients that only read may hold at once: a quarter of
        ``max_connections`` (at least one) is kept for the writers, so that readers, however
        many or idle, never lock the CNC out."""
        return self.max_connections - max(1, self.max_connections // 4)

    def may_connect(self, host: str) -> bool:
        """Whether a client at ``host`` may connect."""
        return _within(host, self.allowed)

    def may_write(self, host: str) -> bool:
        """Whether a client at ``host`` may write."""
        return _within(host, self.allowed) and _within(host, self.writers)


class RateLimited(logging.Filter):
    """A logger's lines cut to ``max_chars`` and at most ``per_minute`` a minute, the rest
    counted and said with the next line let through: pymodbus logs a frame it cannot decode
    as a hex dump, a line per frame (30 MB of garbage made 10 MB of log), and a client
    refused again and again would fill the log as fast."""

    def __init__(self, max_chars: int = 200, per_minute: int = 20) -> None:
        super().__init__()
        self.max_chars, self.per_minute = max_chars, per_minute
        self._minute, self._count, self.suppressed = 0, 0, 0

    def filter(self, record: logging.LogRecord) -> bool:
        minute = int(time.monotonic() // 60)
        if minute != self._minute:
            self._minute, self._count = minute, 0
        self._count += 1
        if self._count > self.per_minute:
            self.suppressed += 1
            return False
        text = record.getMessage()
        if len(text) > self.max_chars:
            text = text[:self.max_chars] + f"... ({len(text)} characters)"
        if self.suppressed:
            text += f" [{self.suppressed} more pymodbus lines left out]"
            self.suppressed = 0
        record.msg, record.args = text, None
        return True


def quiet_logs() -> None:
    """Keep pymodbus's frame dumps and a flood of refusals out of the log (once per
    process; pymodbus logs through ``pymodbus.logging``)."""
    for name in ("pymodbus.logging", refused_log.name):
        logger = logging.getLogger(name)
        if not any(isinstance(f, RateLimited) for f in logger.filters):
            logger.addFilter(RateLimited())

_READ_FCS = {3, 4}
_WRITE_FCS = {6, 16}
_BIT_FCS = {1, 2, 5, 15}
_SERVED_FCS = _READ_FCS | _WRITE_FCS | _BIT_FCS  # bits: answered "illegal function" by _action


class _OneUnit(SimCore):
    """SimCore that answers only its own unit ids (others: gateway exception 0x0B)."""

    async def async_getValues(self, device_id, func_code, address, count=1):  # noqa: N802
        if device_id not in self.devices:
            raise NoSuchIdException(f"unit id {device_id}")
        return await super().async_getValues(device_id, func_code, address, count)

    async def async_setValues(self, device_id, func_code, address, values):  # noqa: N802
        if device_id not in self.devices:
            raise NoSuchIdException(f"unit id {device_id}")
        return await super().async_setValues(device_id, func_code, address, values)


def check_write(address: int, words: list[int], bank_order: str) -> tuple[list[tuple[Register,
                                                                                 int]], str]:
    """Decode a write into (register, value) pairs, or say why it is refused.

    Returns ``(entries, "")`` or ``([], reason)`` where reason starts with ``address`` or
    ``value``.
    """
    by_start = {r.address: r for r in REGISTERS}
    end = address + len(words)
    entries, pos = [], address
    while pos < end:
        reg = by_start.get(pos)
        if reg is None or pos + reg.kind.words > end:
            return [], f"address: {pos} is not the start of a whole entry within the write"
        if not reg.writable:
            return [], f"address: {reg.name} ({reg.address}) is read-only"
        value = from_words(words[pos - address:pos - address + reg.kind.words], reg.kind,
                           bank_order)
        problem = _value_problem(reg.name, value)
        if problem:
            return [], f"value: {reg.name} {problem}"
        entries.append((reg, value))
        pos += reg.kind.words
    return entries, ""


def _value_problem(name: str, value: int) -> str:
    if name == "nominal" and value != NO_VALUE and not 0 < value <= 10_000_000:
        return f"{value} must be above 0 and at most 1 m (or 0x80000000 to clear)"
    if name == "tol_upper" and not 0 <= value <= 1_000_000:
        return f"{value} must be within 0 .. 100 mm"
    if name == "tol_lower" and not -1_000_000 <= value <= 0:
        return f"{value} must be within -100 mm .. 0"
    if name == "feature" and not 0 <= value <= 99:
        return f"{value} is not a feature number (1-99, or 0 to recognise)"
    if name == "command" and value not in {c.value for c in Command}:
        return f"{value} is not a command code (0-3)"
    return ""


class _Handler(ServerRequestHandler):
    """One client's connection: refused at once when its address may not connect or the
    connections are full; its address set for the requests it sends."""

    def callback_connected(self) -> None:
        super().callback_connected()
        owner: _TcpServer = self.server
        peer = self.transport.get_extra_info("peername") if self.transport else None
        self.peer = str(peer[0]) if peer else ""
        self.name = peer_name(self.transport)  # its certificate's name over TLS
        gauge = owner.gauge
        access = gauge.access
        if not access.may_connect(self.peer):
            gauge.refuse(self, f"{self.peer} may not connect (not in modbus.allowed_clients)")
        elif len(owner.active_connections) > access.max_connections:  # this one in
            gauge.refuse(self, f"{self.peer}: {access.max_connections} connections "
                         "already (modbus.max_connections)")
        elif not access.may_write(self.peer):
            readers = [getattr(h, "peer", "") for h in owner.active_connections.values()
                       if not access.may_write(getattr(h, "peer", ""))]
            if len(readers) > access.reader_slots():
                gauge.refuse(self, f"{self.peer}: {access.reader_slots()} reader connections "
                             "already (the rest of modbus.max_connections is kept for the "
                             "writers: the CNC)")
            elif readers.count(self.peer) > READER_CONNECTIONS_PER_ADDRESS:
                gauge.refuse(self, f"{self.peer}: {READER_CONNECTIONS_PER_ADDRESS} connections "
                             "from this reader already")

    async def handle_request(self) -> None:
        peer, name = getattr(self, "peer", ""), getattr(self, "name", "")
        _PEER.set(f"{peer} ({name})" if name else peer)
        pdu = self.last_pdu
        if pdu is not None and pdu.function_code not in _SERVED_FCS:
            # pymodbus answers diagnostics (8), file records (20, 21) and its own identity
            # (17: "Pymodbus") itself, for anyone: the register map is all that is served.
            self.server.gauge.exceptions += 1
            answer = ExceptionResponse(pdu.function_code, ExcCodes.ILLEGAL_FUNCTION,
                                       device_id=pdu.dev_id, transaction=pdu.transaction_id)
            self.server_send(answer, self.last_addr)
            return
        await super().handle_request()


class _TcpServer(ModbusTcpServer):
    gauge: GaugeModbusServer

    def callback_new_connection(self) -> _Handler:
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class _TlsServer(ModbusTlsServer):
    gauge: GaugeModbusServer

    def callback_new_connection(self) -> _Handler:
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class GaugeModbusServer:
    """Serves a ``RegisterBank`` over Modbus TCP.

    Parameters
    ----------
    bank : RegisterBank
        The registers.
    host, port : str, int
        Where to listen (port 0: any free port; ``port`` holds the bound one after start).
    unit_id : int
        The unit (slave) id it answers to.
    on_write : callable, optional
        Called as ``on_write(entries, peer)`` for every accepted write of writable registers
        (nominal, tolerances, command), after the bank holds it: the write's (name, value)
        pairs, whole, and the client's address.
    check : callable, optional
        ``check(entries)`` says why a write that is well-formed register by register cannot
        be taken as a whole ("" when it can): the feature it would make does not hold
        together. Such a write gets exception 0x03 and changes nothing.
    access : ModbusAccess, optional
        Who may connect and write (loopback by default).
    tls : TlsFiles, optional
        Serve Modbus/TCP Security instead of plain Modbus TCP: TLS, and a client certificate
        from ``tls.cafile``'s authority required (``drivers.plc.tls``); the address checks
        above still apply.
    """

    def __init__(self, bank: RegisterBank, host: str = "127.0.0.1", port: int = 5020,
                 unit_id: int = 1,
                 on_write: Callable[[list[tuple[str, int]], str], None] | None = None,
                 check: Callable[[list[tuple[str, int]]], str] | None = None,
                 access: ModbusAccess | None = None, tls: TlsFiles | None = None) -> None:
        self.bank, self.host, self.port, self.unit_id = bank, host, port, unit_id
        self.tls = tls
        self.tls_refusals = CountedRefusals()
        # made now: a missing or broken file stops the gauge's start, naming it
        self._sslctx = server_context(tls, self.tls_refusals) if tls is not None else None
        self.on_write, self.check = on_write, check
        self.access = access or ModbusAccess()
        self.requests = 0
        self.exceptions = 0
        self.refused_connections = 0
        self.refused_writes = 0
        self.last_refused = ""
        self._server: ModbusTcpServer | None = None

    def _device(self) -> SimDevice:
        blocks = [SimData(r.address, count=r.kind.words, values=0,
                          datatype=DataType.REGISTERS, readonly=not r.writable)
                  for r in REGISTERS]
        return SimDevice(id=self.unit_id, simdata=blocks, action=self._action)

    async def _action(self, fc: int, start: int, address: int, count: int,
                      registers: list[int], values: list[int] | list[bool] | None
                      ) -> ExcCodes | None:
        self.requests += 1
        if fc in _BIT_FCS:
            self.exceptions += 1
            return ExcCodes.ILLEGAL_FUNCTION
        if values is None or fc in _READ_FCS:
            registers[address - start:address - start + count] = self.bank.words(address, count)
            return None
        if fc not in _WRITE_FCS:
            self.exceptions += 1
            return ExcCodes.ILLEGAL_FUNCTION
        peer = _PEER.get()
        if not self.access.may_write(peer.split(" ", 1)[0]):
            self.exceptions += 1
            self.refused_writes += 1
            self.last_refused = f"a write from {peer or 'an unknown peer'} (not in " \
                "modbus.writers)"
            refused_log.warning("modbus write to %d refused: %s may not write (not in "
                                "modbus.writers)", address, peer or "an unknown peer")
            return ExcCodes.ILLEGAL_FUNCTION
        entries, reason = check_write(address, [int(v) for v in values], self.bank.order)
        named = [(reg.name, value) for reg, value in entries]
        if not reason and self.check is not None:
            problem = self.check(named)
            reason = f"value: {problem}" if problem else ""
        if reason:
            self.exceptions += 1
            self.last_refused = f"a write from {peer or 'an unknown peer'}: {reason}"
            refused_log.warning("modbus write from %s refused: %s", peer, reason)
            return ExcCodes.ILLEGAL_ADDRESS if reason.startswith("address") \
                else ExcCodes.ILLEGAL_VALUE
        self.bank.write_words(address, [int(v) for v in values])
        log.info("modbus write from %s: %s", peer,
                 ", ".join(f"{name} = {value}" for name, value in named))
        if self.on_write:
            try:
                self.on_write(named, peer)
            except Exception:  # a consumer's fault must not take the server down
                log.exception("on_write(%s) failed", named)
        return None

    @property
    def connections(self) -> int:
        """Clients connected now."""
        return len(self._server.active_connections) if self._server is not None else 0

    def refuse(self, handler: ServerRequestHandler, why: str) -> None:
        """Disconnect a client at once, counted and logged."""
        self.refused_connections += 1
        self.last_refused = why
        refused_log.warning("modbus connection refused: %s", why)
        handler.close()

    async def start(self) -> int:
        """Listen in the background on the running event loop; return the bound port."""
        quiet_logs()
        server: _TcpServer | _TlsServer
        if self._sslctx is not None:
            server = _TlsServer(self._device(), address=(self.host, self.port),
                                sslctx=self._sslctx)
        else:
            server = _TcpServer(self._device(), address=(self.host, self.port))
        server.gauge = self
        server.context = _OneUnit(self._device())
        await server.serve_forever(background=True)
        self._server = server
        sockets = getattr(server.transport, "sockets", None) or []
        if sockets:
            self.port = sockets[0].getsockname()[1]
        log.info("modbus %sserver on %s:%d unit %d", "TLS " if self.tls else "", self.host,
                 self.port, self.unit_id)
        return self.port

    async def stop(self) -> None:
        """Stop listening and close connections."""
        if self._server is not None:
            await self._server.shutdown()
            self._server = None
            await asyncio.sleep(0)


async def run_heartbeat(bank: RegisterBank, healthy: Callable[[], bool],
                        period_s: float = 1.0) -> None:
    """Count the heartbeat register up once a period while ``healthy()``; runs until cancelled.
    A CNC watching it sees it stand still when the service is unhealthy or gone."""
    while True:
        await asyncio.sleep(period_s)
        if healthy():
            bank.set("heartbeat", (bank.get("heartbeat") + 1) & 0xFFFF)
