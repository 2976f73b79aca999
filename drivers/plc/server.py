"""The Modbus TCP server the CNC polls (pymodbus 3.16, built on ``SimDevice``/``SimData``).

The register bank is the source of truth: pymodbus checks framing, the unit id, address
ranges and read-only registers; a ``SimDevice`` action copies the bank into the requested
range before every read, and validates every write (whole entries only, values in range,
known command codes) before it reaches the bank. Bad requests get Modbus exception replies:
illegal function (coil access), illegal data address (unmapped, read-only, or half of a 32-bit
pair), illegal data value (out of range), gateway target failed to respond (another unit id).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer
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

log = logging.getLogger("shaftgauge.modbus")

_READ_FCS = {3, 4}
_WRITE_FCS = {6, 16}
_BIT_FCS = {1, 2, 5, 15}


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
    if name == "command" and value not in {c.value for c in Command}:
        return f"{value} is not a command code (0-3)"
    return ""


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
        Called as ``on_write(name, value)`` for every accepted write of a writable register
        (nominal, tolerances, command), after the bank holds it.
    """

    def __init__(self, bank: RegisterBank, host: str = "127.0.0.1", port: int = 5020,
                 unit_id: int = 1,
                 on_write: Callable[[str, int], None] | None = None) -> None:
        self.bank, self.host, self.port, self.unit_id = bank, host, port, unit_id
        self.on_write = on_write
        self.requests = 0
        self.exceptions = 0
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
        entries, reason = check_write(address, [int(v) for v in values], self.bank.order)
        if reason:
            self.exceptions += 1
            log.info("modbus write refused: %s", reason)
            return ExcCodes.ILLEGAL_ADDRESS if reason.startswith("address") \
                else ExcCodes.ILLEGAL_VALUE
        self.bank.write_words(address, [int(v) for v in values])
        for reg, value in entries:
            if self.on_write:
                try:
                    self.on_write(reg.name, value)
                except Exception:  # a consumer's fault must not take the server down
                    log.exception("on_write(%s) failed", reg.name)
        return None

    async def start(self) -> int:
        """Listen in the background on the running event loop; return the bound port."""
        server = ModbusTcpServer(self._device(), address=(self.host, self.port))
        server.context = _OneUnit(self._device())
        await server.serve_forever(background=True)
        self._server = server
        sockets = getattr(server.transport, "sockets", None) or []
        if sockets:
            self.port = sockets[0].getsockname()[1]
        log.info("modbus server on %s:%d unit %d", self.host, self.port, self.unit_id)
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
