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
"""

from __future__ import annotations

import asyncio
import json
import logging
import ssl
import time
from pathlib import Path
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer, ModbusTlsServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.plc.offsets import PlcOffsetMap
from drivers.plc.registers import RegisterType, from_words, to_words

log = logging.getLogger("shaftgauge.sim.plc")


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
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 5021,
                 offsets: PlcOffsetMap | None = None, ack_delay_s: float = 0.0,
                 log_path: Path | None = None, state_path: Path | None = None,
                 never_ack: bool = False, sslctx: ssl.SSLContext | None = None) -> None:
        self.host, self.port = host, port
        self.sslctx = sslctx
        self.map = offsets or PlcOffsetMap()
        self.ack_delay_s = ack_delay_s
        self.never_ack = never_ack
        self.request_seq = 0
        self.log_path, self.state_path = log_path, state_path
        self.events: list[dict[str, Any]] = []
        self.total_units = 0
        self.last_seq = 0
        if state_path and state_path.exists():
            state = json.loads(state_path.read_text())
            self.total_units, self.last_seq = state["total_units"], state["last_seq"]
        self._regs: list[int] | None = None
        self._start = 0
        self._server: ModbusTcpServer | None = None
        self._tasks: set[asyncio.Task] = set()

    def _words(self, value: int, kind: RegisterType) -> list[int]:
        return to_words(value, kind, self.map.word_order)

    def _device(self) -> SimDevice:
        m = self.map
        blocks = [
            SimData(m.offset_address, count=4, values=0, datatype=DataType.REGISTERS),
            SimData(m.ack_address, values=self._words(self.last_seq, RegisterType.U32),
                    datatype=DataType.REGISTERS, readonly=True),
            SimData(m.total_address, values=self._words(self.total_units, RegisterType.I32),
                    datatype=DataType.REGISTERS, readonly=True),
        ]
        return SimDevice(id=m.unit_id, simdata=blocks, action=self._action)

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
        m = self.map
        if address != m.offset_address or count != 4:
            return ExcCodes.ILLEGAL_ADDRESS  # value and sequence go together, in one write
        words = [int(v) for v in values]
        value = from_words(words[:2], RegisterType.I32, m.word_order)
        seq = from_words(words[2:], RegisterType.U32, m.word_order)
        self.request_seq = seq
        if seq == 0:
            self._record({"event": "cleared", "seq": seq, "value_units": value})
            return None
        self._record({"event": "write", "seq": seq, "value_units": value})
        if self.never_ack:
            return None
        task = asyncio.get_running_loop().create_task(self._apply(seq, value, start))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return None

    async def _apply(self, seq: int, value: int, start: int) -> None:
        if self.ack_delay_s:
            await asyncio.sleep(self.ack_delay_s)
        if self.request_seq != seq:
            self._record({"event": "cancelled", "seq": seq, "value_units": value})
            return
        if seq == self.last_seq:
            self._record({"event": "duplicate", "seq": seq, "value_units": value})
        else:
            self.total_units += value
            self.last_seq = seq
            self._record({"event": "applied", "seq": seq, "value_units": value,
                          "total_units": self.total_units})
            self._keep()
        self._publish(start)

    def set_total_by_hand(self, total_units: int) -> None:
        """An operator sets the wear offset at the panel (zeroed at an insert change): the
        total changes without a request (call on the server's loop)."""
        self.total_units = int(total_units)
        self._record({"event": "set_by_hand", "total_units": self.total_units})
        self._keep()
        self._publish(self._start)

    def _keep(self) -> None:
        if self.state_path:
            tmp = self.state_path.with_suffix(".tmp")
            tmp.write_text(json.dumps({"total_units": self.total_units,
                                       "last_seq": self.last_seq}))
            tmp.replace(self.state_path)

    def _publish(self, start: int) -> None:
        if self._regs is None:
            return
        m = self.map
        ack = self._words(self.last_seq, RegisterType.U32)
        total = self._words(self.total_units, RegisterType.I32)
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
