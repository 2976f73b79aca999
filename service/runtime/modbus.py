"""The Modbus server the CNC polls (``ModbusService``: its life and heartbeat). What the
registers show is ``register_view.RegisterView``'s; what the CNC writes is checked and carried
out in ``cnc_writes``."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from drivers.plc.registers import RegisterBank
from drivers.plc.server import GaugeModbusServer, ModbusAccess, run_heartbeat
from drivers.plc.tls import TlsFiles
from service.config import ModbusSettings
from service.runtime.register_view import RegisterView
from service.runtime.status_words import StatusSnapshot


class ModbusService:
    """The Modbus server of the register bank: it serves what ``RegisterView`` shows, refuses
    a write ``check`` refuses and hands the others to ``take``.

    Parameters
    ----------
    settings : ModbusSettings
        Where to serve, unit id, who may connect and write.
    bank : RegisterBank
        The registers.
    view : RegisterView
        Kept current from the status snapshot while serving.
    check, take : callable
        ``CncWriteRules.check`` and ``CncCommands.take``.
    """

    def __init__(self, settings: ModbusSettings, bank: RegisterBank, view: RegisterView,
                 check: Callable[[list[tuple[str, int]]], str],
                 take: Callable[[list[tuple[str, int]], str], None]) -> None:
        self.settings, self.bank, self.view = settings, bank, view
        self.server = GaugeModbusServer(
            bank, settings.host, settings.port, settings.unit_id, on_write=take,
            check=check, access=ModbusAccess.of(
                settings.allowed_clients, settings.writers, settings.max_connections),
            tls=TlsFiles(settings.tls.certfile, settings.tls.keyfile, settings.tls.cafile)
            if settings.tls else None)

    @property
    def port(self) -> int:
        """The port served (the bound one once started)."""
        return self.server.port

    async def start(self, snapshot: Callable[[], StatusSnapshot],
                    healthy: Callable[[], bool]) -> list[asyncio.Task]:
        """Serve (when enabled); returns the background tasks: the heartbeat (counting while
        ``healthy()``) and the status registers (from ``snapshot()`` every ``REFRESH_S``)."""
        if self.settings.enabled:
            try:
                await self.server.start()
            except (OSError, RuntimeError) as err:  # pymodbus: "Could not start listen"
                raise RuntimeError(f"the Modbus server cannot listen on "
                                   f"{self.settings.host}:{self.settings.port} (modbus.port: "
                                   f"is another program using it?): {err}") from err
        loop = asyncio.get_running_loop()
        return [loop.create_task(run_heartbeat(self.bank, healthy), name="heartbeat"),
                loop.create_task(self.view.refresh(snapshot), name="registers")]

    async def stop(self) -> None:
        """Stop serving."""
        await self.server.stop()
