"""A simulated CNC/PLC: the offset registers a real CNC exposes, over real Modbus TCP.

On a write of offset and sequence (FC16 over both pairs) it applies the offset, after an
optional delay, if the sequence is new and still in its request registers, and echoes the
sequence into its acknowledgement register. A write of sequence 0 clears the request (what a
CNC does with a request it will not apply; see docs/modbus-register-map.md); with
``never_ack`` it keeps every request and applies none (a CNC that stopped its part of the
exchange). The request registers are volatile, as a PLC's exchange area is: after a restart
they read 0. Every write received and every offset applied goes into a log (in memory and, when
given, a JSON-lines file) so tests can prove that nothing was applied twice. Its applied total
and last sequence persist in a state file, as a real CNC keeps its offsets across power cycles.

With ``tools`` it keeps a block for each of offset numbers 1 to ``tools`` (a tool's own entry:
its T number), ``tool_stride`` registers apart (``PlcOffsetMap.for_offset``; number 1's is the
first): each entry's offsets, total and acknowledgement apart from the others'.
"""

from __future__ import annotations

import asyncio
import json
import logging
import ssl
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer, ModbusTlsServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.plc.offset_map import PlcOffsetMap
from drivers.plc.registers import RegisterType, from_words, to_words

log = logging.getLogger("shaftgauge.sim.plc")


@dataclass
class _Tool:
    """One block's CNC side: what it applied and the request in its registers."""

    total_units: int = 0
    last_seq: int = 0
    request_seq: int = 0


class SimPlc:
    """The simulated CNC's offset registers.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: any free port).
    offsets : PlcOffsetMap
        Register addresses.
    ack_delay_s : float
        Time between receiving an offset and applying plus acknowledging it.
    log_path, state_path : Path, optional
        JSON-lines log of writes and applications; JSON state kept across restarts.
    never_ack : bool
        Keep requests, apply and acknowledge none.
    sslctx : ssl.SSLContext, optional
        Speak Modbus/TCP Security (``drivers.plc.tls.server_context``), as a CNC that does.
    tools : int
        Offset numbers with a block of their own (1 to ``tools``, ``offsets.tool_stride``
        apart; 0 or 1: the first block only).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 5021,
                 offsets: PlcOffsetMap | None = None, ack_delay_s: float = 0.0,
                 log_path: Path | None = None, state_path: Path | None = None,
                 never_ack: bool = False, sslctx: ssl.SSLContext | None = None,
                 tools: int = 0) -> None:
        self.host, self.port = host, port
        self.sslctx = sslctx
        self.map = offsets or PlcOffsetMap()
        self.blocks = {n: self.map.for_offset(n) for n in range(1, max(1, int(tools)) + 1)}
        self.ack_delay_s = ack_delay_s
        self.never_ack = never_ack
        self.log_path, self.state_path = log_path, state_path
        self.events: list[dict[str, Any]] = []
        self.tools = {t: _Tool() for t in self.blocks}
        if state_path and state_path.exists():
            state = json.loads(state_path.read_text())
            self.tools[1] = _Tool(state["total_units"], state["last_seq"])
            for n, kept in state.get("offsets", {}).items():
                if int(n) in self.tools:
                    self.tools[int(n)] = _Tool(kept["total_units"], kept["last_seq"])
        self._regs: list[int] | None = None
        self._start = 0
        self._server: ModbusTcpServer | None = None
        self._tasks: set[asyncio.Task] = set()

    def _words(self, value: int, kind: RegisterType) -> list[int]:
        return to_words(value, kind, self.map.word_order)

    @property
    def total_units(self) -> int:
        """The first block's applied total, 0.1 um."""
        return self.tools[1].total_units

    @property
    def last_seq(self) -> int:
        """The first block's last applied sequence."""
        return self.tools[1].last_seq

    def _device(self) -> SimDevice:
        blocks = []
        for t, m in self.blocks.items():
            state = self.tools[t]
            blocks += [
                SimData(m.offset_address, count=4, values=0, datatype=DataType.REGISTERS),
                SimData(m.ack_address, values=self._words(state.last_seq, RegisterType.U32),
                        datatype=DataType.REGISTERS, readonly=True),
                SimData(m.total_address,
                        values=self._words(state.total_units, RegisterType.I32),
                        datatype=DataType.REGISTERS, readonly=True)]
        blocks.sort(key=lambda b: b.address)
        return SimDevice(id=self.map.unit_id, simdata=blocks, action=self._action)

    def _record(self, event: dict[str, Any]) -> None:
        event["time"] = time.time()
        self.events.append(event)
        if self.log_path:
            with self.log_path.open("a") as f:
                f.write(json.dumps(event) + "\n")

    async def _action(self, fc: int, start: int, address: int, count: int,
                      registers: list[int], values: list[int] | list[bool] | None
                      ) -> ExcCodes | None:
        self._regs, self._start = registers, start
        if values is None or fc in (3, 4):
            return None
        tool = next((t for t, m in self.blocks.items() if address == m.offset_address), None)
        if tool is None or count != 4:
            return ExcCodes.ILLEGAL_ADDRESS  # value and sequence go together, in one write
        words = [int(v) for v in values]
        value = from_words(words[:2], RegisterType.I32, self.map.word_order)
        seq = from_words(words[2:], RegisterType.U32, self.map.word_order)
        self.tools[tool].request_seq = seq
        named = {"offset": tool} if tool > 1 else {}
        if seq == 0:
            self._record({"event": "cleared", "seq": seq, "value_units": value, **named})
            return None
        self._record({"event": "write", "seq": seq, "value_units": value, **named})
        if self.never_ack:
            return None
        task = asyncio.get_running_loop().create_task(self._apply(seq, value, start, tool))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return None

    async def _apply(self, seq: int, value: int, start: int, tool: int = 1) -> None:
        if self.ack_delay_s:
            await asyncio.sleep(self.ack_delay_s)
        state, named = self.tools[tool], ({"offset": tool} if tool > 1 else {})
        if state.request_seq != seq:
            self._record({"event": "cancelled", "seq": seq, "value_units": value, **named})
            return
        if seq == state.last_seq:
            self._record({"event": "duplicate", "seq": seq, "value_units": value, **named})
        else:
            state.total_units += value
            state.last_seq = seq
            self._record({"event": "applied", "seq": seq, "value_units": value,
                          "total_units": state.total_units, **named})
            self._keep()
        self._publish(start)

    def set_total_by_hand(self, total_units: int, offset: int = 1) -> None:
        """An operator sets offset number ``offset``'s wear offset at the panel (zeroed at
        an insert change): the total changes without a request (call on the server's
        loop)."""
        self.tools[offset].total_units = int(total_units)
        self._record({"event": "set_by_hand", "total_units": int(total_units),
                      **({"offset": offset} if offset > 1 else {})})
        self._keep()
        self._publish(self._start)

    def _keep(self) -> None:
        if self.state_path:
            tmp = self.state_path.with_suffix(".tmp")
            first = self.tools[1]
            tmp.write_text(json.dumps({
                "total_units": first.total_units, "last_seq": first.last_seq,
                "offsets": {str(n): {"total_units": s.total_units, "last_seq": s.last_seq}
                            for n, s in self.tools.items() if n > 1}}))
            tmp.replace(self.state_path)

    def _publish(self, start: int) -> None:
        if self._regs is None:
            return
        for t, m in self.blocks.items():
            ack = self._words(self.tools[t].last_seq, RegisterType.U32)
            total = self._words(self.tools[t].total_units, RegisterType.I32)
            self._regs[m.ack_address - start:m.ack_address - start + 2] = ack
            self._regs[m.total_address - start:m.total_address - start + 2] = total

    async def start(self) -> int:
        """Listen on the running loop; return the bound port."""
        server = ModbusTcpServer(self._device(), address=(self.host, self.port)) \
            if self.sslctx is None else \
            ModbusTlsServer(self._device(), address=(self.host, self.port), sslctx=self.sslctx)
        await server.serve_forever(background=True)
        self._server = server
        sockets = getattr(server.transport, "sockets", None) or []
        if sockets:
            self.port = sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        """Stop listening (pending applications are abandoned, as on a power cut)."""
        for task in list(self._tasks):
            task.cancel()
        if self._server:
            await self._server.shutdown()
            self._server = None
