"""Writes tool-wear offsets to a CNC/PLC over Modbus TCP, once each, and proves they landed.

An offset goes out as one FC16 write of value and sequence. The writer then polls the CNC's
acknowledgement register until it echoes the sequence (or a timeout), and reads the written
registers back to verify them. Requests are serialised (pymodbus's client is not safe for
concurrent requests) and never retried by the library: a retried write is a second offset.
After a connection loss it reconnects with backoff; it never re-sends an offset, it only reads
the acknowledgement register to settle one whose fate was unknown.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import ssl
import time
from dataclasses import dataclass

from pymodbus.client import AsyncModbusTcpClient, AsyncModbusTlsClient
from pymodbus.exceptions import ModbusException

from drivers.plc.offset_map import PlcOffsetMap
from drivers.plc.registers import UM_PER_UNIT, RegisterType, from_words, mm_to_units, to_words
from service.compensation import CncReading

log = logging.getLogger("shaftgauge.plc")


class Outcome(enum.StrEnum):
    """What became of one offset."""

    APPLIED = "applied"            # acknowledged and verified
    NOT_APPLIED = "not_applied"    # certainly not applied (never reached the CNC, or refused)
    UNKNOWN = "unknown"            # written, then no acknowledgement: settle later


@dataclass(frozen=True)
class WriteResult:
    """The outcome of ``write_offset``, with what happened in words."""

    outcome: Outcome
    seq: int
    value_units: int
    message: str
    elapsed_s: float

    @property
    def applied(self) -> bool | None:
        """True, False, or None when unknown (the controller's terms)."""
        return {Outcome.APPLIED: True, Outcome.NOT_APPLIED: False}.get(self.outcome)


class OffsetWriter:
    """Modbus TCP client of the CNC's offset registers.

    Parameters
    ----------
    host, port : str, int
        The CNC/PLC.
    offsets : PlcOffsetMap
        Register addresses, unit id, word order.
    ack_timeout_s : float
        How long to wait for the acknowledgement echo.
    request_timeout_s : float
        Timeout of one Modbus request.
    reconnect_initial_s, reconnect_max_s : float
        Backoff between connection attempts.
    sslctx : ssl.SSLContext, optional
        Modbus/TCP Security (``drivers.plc.tls.client_context``): the CNC over TLS, each end
        showing its certificate. None: plain Modbus TCP.
    """

    def __init__(self, host: str, port: int, offsets: PlcOffsetMap | None = None,
                 ack_timeout_s: float = 3.0, request_timeout_s: float = 1.0,
                 reconnect_initial_s: float = 0.5, reconnect_max_s: float = 10.0,
                 sslctx: ssl.SSLContext | None = None) -> None:
        self.host, self.port = host, port
        self.sslctx = sslctx
        self.map = offsets or PlcOffsetMap()
        self.ack_timeout_s = ack_timeout_s
        self.request_timeout_s = request_timeout_s
        self.reconnect_initial_s, self.reconnect_max_s = reconnect_initial_s, reconnect_max_s
        self._lock = asyncio.Lock()
        self._client: AsyncModbusTcpClient | None = None
        self._backoff = reconnect_initial_s
        self._next_attempt = 0.0
        self.connected = False
        self.last_error = ""
        self.outage_since: float | None = None
        self._blocks: dict[int, PushBlock] = {}

    # ---- connection --------------------------------------------------------------------

    async def _connect(self) -> bool:
        """Connect if not connected, respecting the backoff. Caller holds the lock."""
        if self._client is not None and self._client.connected:
            return True
        now = time.monotonic()
        if now < self._next_attempt:
            return False
        if self._client is not None:
            self._client.close()
        if self.sslctx is not None:
            self._client = AsyncModbusTlsClient(
                self.host, sslctx=self.sslctx, port=self.port, timeout=self.request_timeout_s,
                retries=0, reconnect_delay=0, reconnect_delay_max=0)
        else:
            self._client = AsyncModbusTcpClient(
                self.host, port=self.port, timeout=self.request_timeout_s, retries=0,
                reconnect_delay=0, reconnect_delay_max=0)
        ok = False
        try:
            ok = bool(await self._client.connect())
        except (OSError, ModbusException) as err:
            self.last_error = f"cannot connect to {self.host}:{self.port}: {err}"
        if not ok and self.sslctx is not None and not self.last_error:
            self.last_error = (f"cannot connect to {self.host}:{self.port} over TLS (is it "
                               "listening, and does its certificate come from plc.tls.cafile "
                               "and name the host?)")
        if ok:
            if not self.connected:
                log.info("PLC %s:%d connected", self.host, self.port)
            self.connected, self.outage_since = True, None
            self._backoff = self.reconnect_initial_s
            return True
        self._mark_down(self.last_error or f"cannot connect to {self.host}:{self.port}")
        self._next_attempt = now + self._backoff
        self._backoff = min(self._backoff * 2.0, self.reconnect_max_s)
        return False

    def _mark_down(self, reason: str) -> None:
        if self.connected or self.outage_since is None:
            log.warning("PLC %s:%d: %s", self.host, self.port, reason)
        self.connected = False
        self.last_error = reason
        if self.outage_since is None:
            self.outage_since = time.monotonic()
        if self._client is not None:
            self._client.close()
            self._client = None

    async def close(self) -> None:
        """Close the connection."""
        async with self._lock:
            if self._client is not None:
                self._client.close()
                self._client = None
            self.connected = False

    async def _read_u32(self, address: int) -> int:
        assert self._client is not None  # every block has the unit id of the map
        rr = await self._client.read_holding_registers(address, count=2,
                                                       device_id=self.map.unit_id)
        if rr.isError():
            raise ModbusException(f"read of {address} refused: {rr}")
        return from_words(rr.registers, RegisterType.U32, self.map.word_order)

    # ---- the exchange ------------------------------------------------------------------

    async def read_ack(self) -> int | None:
        """The CNC's acknowledged sequence, or None when it cannot be read now."""
        async with self._lock:
            if not await self._connect():
                return None
            try:
                return await self._read_u32(self.map.ack_address)
            except (TimeoutError, ModbusException, OSError) as err:
                self._mark_down(f"reading the acknowledgement failed: {err}")
                return None

    def offset(self, number: int) -> PushBlock:
        """The transport of offset number ``number`` (a tool's own entry: its T number): its
        block of the CNC's registers (``PlcOffsetMap.for_offset``; the one block when the
        CNC keeps one, the same transport for every number; ValueError when the blocks would
        not fit)."""
        block = self.map.for_offset(number)
        key = block.offset_address
        if key not in self._blocks:
            self._blocks[key] = PushBlock(self, block)
        return self._blocks[key]

    async def read_cnc(self, block: PlcOffsetMap | None = None) -> CncReading | None:
        """The CNC's side of the exchange (request sequence, acknowledgement, total wear
        offset) in ``block`` (None: the single tool's), or None when it cannot be read
        now."""
        m = block or self.map
        async with self._lock:
            if not await self._connect():
                return None
            try:
                assert self._client is not None
                rr = await self._client.read_holding_registers(m.offset_address + 2, count=2,
                                                               device_id=m.unit_id)
                if rr.isError():
                    raise ModbusException(f"read of {m.offset_address + 2} refused: {rr}")
                request = from_words(rr.registers, RegisterType.U32, m.word_order)
                ack = await self._read_u32(m.ack_address)
                rr = await self._client.read_holding_registers(m.total_address, count=2,
                                                               device_id=m.unit_id)
                if rr.isError():
                    raise ModbusException(f"read of {m.total_address} refused: {rr}")
                total = from_words(rr.registers, RegisterType.I32, m.word_order)
            except (TimeoutError, ModbusException, OSError) as err:
                self._mark_down(f"reading the CNC's offset registers failed: {err}")
                return None
        return CncReading(ack, request, total * UM_PER_UNIT / 1000.0)

    async def write_offset(self, offset_mm: float, seq: int,
                           block: PlcOffsetMap | None = None) -> WriteResult:
        """Write one offset with its sequence number into ``block`` (None: the single tool's),
        exactly once.

        Returns APPLIED when the CNC echoed ``seq`` and the registers read back as written;
        NOT_APPLIED when the write never reached the CNC or was refused; UNKNOWN when it was
        sent but not acknowledged in time (settle it later with ``read_cnc``).
        """
        t0 = time.monotonic()
        units = mm_to_units(offset_mm)
        m = block or self.map

        def result(outcome: Outcome, message: str) -> WriteResult:
            return WriteResult(outcome, seq, units, message, time.monotonic() - t0)

        async with self._lock:
            if not await self._connect():
                return result(Outcome.NOT_APPLIED, f"CNC unreachable: {self.last_error}")
            words = (to_words(units, RegisterType.I32, m.word_order)
                     + to_words(seq, RegisterType.U32, m.word_order))
            try:
                wr = await self._client.write_registers(m.offset_address, words,
                                                        device_id=m.unit_id)
            except (TimeoutError, ModbusException, OSError) as err:
                # The request may or may not have reached the CNC: only its ack can tell.
                self._mark_down(f"offset write failed: {err}")
                return result(Outcome.UNKNOWN, f"no answer to the write: {err}")
            if wr.isError():
                return result(Outcome.NOT_APPLIED, f"CNC refused the write: {wr}")
            deadline = t0 + self.ack_timeout_s
            ack = None
            try:
                while time.monotonic() < deadline:
                    ack = await self._read_u32(m.ack_address)
                    if ack == seq:
                        break
                    await asyncio.sleep(0.02)
                if ack != seq:
                    return result(Outcome.UNKNOWN, f"no acknowledgement within "
                                  f"{self.ack_timeout_s:g} s (CNC echoes {ack})")
                rr = await self._client.read_holding_registers(m.offset_address, count=4,
                                                               device_id=m.unit_id)
            except (TimeoutError, ModbusException, OSError) as err:
                self._mark_down(f"lost the CNC while waiting for the acknowledgement: {err}")
                return result(Outcome.UNKNOWN, f"connection lost before the acknowledgement: "
                              f"{err}")
            if rr.isError() or list(rr.registers) != words:
                # Acknowledged, so applied; but what sits there now is not what we wrote.
                return result(Outcome.APPLIED, "acknowledged, but the read-back differs "
                              f"({getattr(rr, 'registers', rr)} != {words}): check the CNC")
            return result(Outcome.APPLIED, "acknowledged and verified")


class PushBlock:
    """One block's transport over the writer's connection (one request at a time on the
    connection, as every request)."""

    def __init__(self, writer: OffsetWriter, block: PlcOffsetMap) -> None:
        self.writer, self.block = writer, block

    async def read_cnc(self) -> CncReading | None:
        """The CNC's side of the exchange in the block."""
        return await self.writer.read_cnc(self.block)

    async def write_offset(self, offset_mm: float, seq: int) -> WriteResult:
        """Write one offset into the block, exactly once (``OffsetWriter``)."""
        return await self.writer.write_offset(offset_mm, seq, self.block)


class CncTotalReader:
    """Reads the CNC's total wear offset (``total_address``, int32, 0.1 um) over Modbus TCP,
    synchronously: for a simulator in its own thread (the virtual lathe follows the push
    CNC's applied total), never for the gauge's event loop. Calling it gives the total in mm;
    it raises OSError when the CNC cannot be read (and connects again on the next call)."""

    def __init__(self, host: str, port: int, offsets: PlcOffsetMap | None = None,
                 timeout_s: float = 1.0) -> None:
        from pymodbus.client import ModbusTcpClient

        self.map = offsets or PlcOffsetMap()
        self._client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)

    def __call__(self) -> float:
        m = self.map
        try:
            if not self._client.connected and not self._client.connect():
                raise OSError(f"cannot connect to the CNC at {self._client.comm_params.host}:"
                              f"{self._client.comm_params.port}")
            rr = self._client.read_holding_registers(m.total_address, count=2,
                                                     device_id=m.unit_id)
        except ModbusException as err:
            self._client.close()
            raise OSError(f"reading the CNC's total failed: {err}") from None
        if rr.isError():
            raise OSError(f"the CNC refused the read of its total ({m.total_address}): {rr}")
        units = from_words(rr.registers, RegisterType.I32, m.word_order)
        return units * UM_PER_UNIT / 1000.0

    def close(self) -> None:
        """Close the connection."""
        self._client.close()
