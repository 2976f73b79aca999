"""The running gauge: its parts, started and stopped in order. ``service.serve.build`` is the
one place that makes and wires them (see ARCHITECTURE.md)."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from calib_store.compensation_log import CompensationLog
from drivers.camera.base import Camera
from drivers.plc.client import OffsetWriter
from drivers.plc.pull import PullCnc
from service.calibrate.session import CalibrationSessions
from service.config import Settings
from service.measure.compiled import compile_kernels
from service.runtime.calibration import CalibrationContext
from service.runtime.cnc_writes import CncCommands
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed
from service.runtime.form_watch import FormWatch
from service.runtime.health import HealthReport
from service.runtime.job_service import JobService
from service.runtime.metrics import GaugeMetrics
from service.runtime.modbus import ModbusService
from service.runtime.pipeline import FramePipeline
from service.runtime.plant import PlantLink
from service.runtime.spc_service import SpcService
from service.runtime.studies import GaugeStudies


@dataclass
class Gauge:
    """The parts of one running gauge (each owns its own state; see their modules)."""

    settings: Settings
    camera: Camera
    context: CalibrationContext
    pipeline: FramePipeline
    feed: MeasurementFeed
    compensation: CompensationService
    modbus: ModbusService
    health: HealthReport
    sessions: CalibrationSessions
    metrics: GaugeMetrics
    spc: SpcService
    studies: GaugeStudies
    jobs: JobService
    writer: OffsetWriter | PullCnc | None = None
    log: CompensationLog | None = None
    plant: list[PlantLink] = field(default_factory=list)
    form: FormWatch | None = None
    commands: CncCommands | None = None
    """The commands the CNC gives in its registers; the API runs them too."""
    _tasks: list[asyncio.Task] = field(default_factory=list)

    async def start(self) -> None:
        """Start the camera, the Modbus server and the background tasks; a start that fails
        stops what it had started before it raises (a camera left reconnecting would keep a
        service that never ran alive)."""
        loop = asyncio.get_running_loop()
        comp = self.compensation
        self._tasks = []
        try:
            # The core's compiled kernels are loaded (or, on a fresh checkout, compiled)
            # before the first frame, not by it.
            await loop.run_in_executor(None, compile_kernels)
            self._tasks += self.pipeline.start()
            self._tasks += [
                loop.create_task(comp.run(), name="compensation"),
                loop.create_task(comp.entries.run_settlers(), name="settlers"),
                loop.create_task(comp.follow_master_gate(
                    lambda: self.context.master_status()["blocking"]
                    or self.studies.blocking()), name="master-gate")]
            if isinstance(self.writer, PullCnc):  # an answer posts the next tool's request
                self._tasks.append(loop.create_task(self.writer.watch(), name="pull-watch"))
            self._tasks += await self.modbus.start(self.health.snapshot, self.health.healthy)
            self._tasks += [loop.create_task(link.run(), name=link.name) for link in self.plant]
            if self.form:
                self._tasks.append(loop.create_task(self.form.run(), name="form"))
        except BaseException:
            await self.stop()
            raise
        self.health.running = True

    async def stop(self) -> None:
        """Stop everything started by ``start``; what was decided is on disk afterwards."""
        self.health.running = False
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        await self.studies.stop()
        await self.pipeline.stop()
        await self.modbus.stop()
        for link in self.plant:
            await link.close()
        if self.writer is not None:
            await self.writer.close()
        if self.log is not None:
            await asyncio.to_thread(self.log.flush, 5.0)
