"""The gauge's links to the plant (``service.plant``), made from the settings and fed by the
running parts: the MQTT publisher (measurements, decisions, health), the OPC UA server (its
values and methods)."""

from __future__ import annotations

import asyncio
import contextlib
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from calib_store.outbox import Outbox
from drivers.camera.base import Camera, CameraError
from drivers.plc.client import OffsetWriter
from drivers.plc.pull import PullCnc
from service.compensation import Decision, Kind
from service.compensation.job import JobFeature, OffsetEntry
from service.config import Settings
from service.measurement_record import MeasurementRecord
from service.runtime.compensating import CompensationService
from service.runtime.feed import MeasurementFeed
from service.runtime.health import HealthReport
from service.runtime.job_service import JobService
from service.version import package_version

if TYPE_CHECKING:  # imported where MQTT is configured (aiomqtt)
    from service.plant.mqtt import MqttPublisher

MEASURE_NOW_TIMEOUT_S = 2.0


class PlantLink(Protocol):
    """A link to a plant system, run by the gauge beside its other tasks."""

    name: str

    async def run(self) -> None: ...

    async def close(self) -> None: ...

    def status(self) -> dict[str, Any]: ...

    def problems(self) -> list[tuple[str, str]]: ...


class LastOffset:
    """The last offset the CNC acknowledged (a decision listener)."""

    def __init__(self) -> None:
        self.offset_mm: float | None = None
        self.by_entry: dict[tuple[int | None, int | None], float] = {}  # (tool, entry)

    def __call__(self, d: Decision) -> None:
        if d.kind is Kind.APPLIED and d.offset_mm is not None:
            self.offset_mm = self.by_entry[d.tool, d.entry] = d.offset_mm


def entry_key(e: OffsetEntry) -> int | str:
    """An entry's name under ``Tools`` (``Tool<key>``): its T number, ``<T>_<offset>``."""
    return e.tool if e.number is None else f"{e.tool}_{e.number}"


def characteristic(f: JobFeature, latest: MeasurementRecord | None) -> dict[str, Any]:
    """A feature and its latest measurement as the OPC UA server shows it
    (``service.plant.opcua.CHARACTERISTIC``)."""
    value = latest.diameter_mm if latest is not None and latest.status == "ok" else None
    evaluation = "NotMeasured" if value is None else "InTolerance" if latest.in_tolerance \
        else "AboveTolerance" if (latest.deviation_mm or 0.0) > 0 else "BelowTolerance"
    return {"CharacteristicIdentifier": f.number, "Name": f.name, "Nominal": f.nominal_mm,
            "LowerTolerance": f.tol_lower_mm, "UpperTolerance": f.tol_upper_mm,
            "ResultValue": value, "ResultEvaluation": evaluation}


class OpcUaValues:
    """The OPC UA server's view of the gauge: values and methods (``GaugeView``)."""

    def __init__(self, feed: MeasurementFeed, compensation: CompensationService,
                 camera: Camera, writer: OffsetWriter | PullCnc | None,
                 form: Callable[[], dict[str, Any]] = dict,
                 jobs: JobService | None = None) -> None:
        self.feed, self.compensation, self.camera, self.writer = (feed, compensation, camera,
                                                                  writer)
        self.form, self.jobs = form, jobs
        self.last_offset = LastOffset()   # told each decision (serve.wire)

    def values(self) -> dict[str, Any]:
        """The variables' values by name (``service.plant.opcua.MONITORING`` and
        ``COMPENSATION``)."""
        r, w = self.feed.latest, self.writer
        plc = "none" if w is None else ("connected" if w.connected else
                                        "unreachable" if w.outage_since is not None else
                                        "idle")
        in_force = self.compensation.in_force()
        one = in_force[0][1].controller if len(in_force) == 1 else None
        out: dict[str, Any] = {
            "CameraState": self.camera.status().state.value, "PlcState": plc,
            "State": self.compensation.state.value,
            "CumulativeOffset": None if one is None else one.cumulative_mm,
            "LastOffset": None if one is None else self.last_offset.offset_mm,
            "Shadow": self.compensation.settings.shadow,
            "Tools": {entry_key(e): {"ToolNumber": e.tool, "OffsetNumber": e.number or 0,
                                     "State": ch.controller.state.value,
                                     "CumulativeOffset": ch.controller.cumulative_mm,
                                     "LastOffset": self.last_offset.by_entry.get(
                                         (e.tool, e.number))}
                      for e, ch in in_force}}
        f = self.form()
        out.update({name: f[key] for name, key in (
            ("RunoutTir", "tir_mm"), ("RunoutPhase", "eccentricity_deg"), ("Ront", "ront_mm"),
            ("Lobes", "lobes")) if f.get(key) is not None})
        if self.jobs is not None and self.jobs.job is not None:
            out["Characteristics"] = {f.number: characteristic(f, self.jobs.latest.get(f.number))
                                      for f in self.jobs.job.features}
        if r is not None:
            out.update(Diameter=r.diameter_mm, Uncertainty=r.uncertainty_mm,
                       FusedDiameter=r.fused_diameter_mm, Deviation=r.deviation_mm,
                       InTolerance=bool(r.in_tolerance), Status=r.status, Reason=r.reason,
                       MeasurementSeq=r.seq, CalibrationId=r.calibration_id)
        return out

    async def measure_now(self) -> tuple[float | None, str]:
        """The next measurement after asking the camera for a frame (a free-running camera
        is not asked: its next frame is the answer)."""
        queue = self.feed.subscribers.add()
        try:
            with contextlib.suppress(CameraError):
                self.camera.software_trigger()
            try:
                record = await asyncio.wait_for(queue.get(), MEASURE_NOW_TIMEOUT_S)
            except TimeoutError:
                return None, (f"no measurement within {MEASURE_NOW_TIMEOUT_S:g} s (camera "
                              f"{self.camera.status().state.value})")
        finally:
            self.feed.subscribers.remove(queue)
        return record.diameter_mm, record.status if record.status == "ok" else \
            f"{record.status}: {record.reason}"

    async def reset(self, who: str) -> str:
        """Reset compensation (as a technician over the API would); what happened."""
        d = await self.compensation.reset("opcua", who)
        return f"{d.kind.value}: {d.reason}"


@dataclass
class PlantLinks:
    """The links the settings ask for, and what of them ``serve.wire`` tells of the gauge's
    events (the MQTT publisher; the OPC UA server's view)."""

    links: list[PlantLink] = field(default_factory=list)
    mqtt: MqttPublisher | None = None
    opcua_values: OpcUaValues | None = None


def make_plant_links(settings: Settings, feed: MeasurementFeed,
                     compensation: CompensationService, camera: Camera,
                     writer: OffsetWriter | PullCnc | None, health: HealthReport,
                     jobs: JobService | None = None) -> PlantLinks:
    """The links the settings ask for, made from the gauge's parts (not yet told of its
    events: ``serve.wire`` does that)."""
    made = PlantLinks()
    links = made.links
    data_dir = settings.store.path.parent
    if settings.mqtt.host:
        from service.plant.mqtt import MqttPublisher

        try:
            outbox, problem = Outbox(data_dir / "mqtt-outbox.db", settings.mqtt.outbox_max), ""
        except sqlite3.Error as err:  # decisions still go out while the broker is there
            outbox = Outbox(":memory:", settings.mqtt.outbox_max)
            problem = f"MQTT outbox {data_dir / 'mqtt-outbox.db'} cannot be used ({err})"
        made.mqtt = MqttPublisher(settings.mqtt, outbox, health.summary,
                                  outbox_problem=problem)
        links.append(made.mqtt)
    ua = settings.opcua
    embedded = settings.camera.source == "sim"
    if ua.enabled or (ua.enabled is None and embedded):
        from service.plant.opcua import GaugeView, OpcUaServer

        if ua.none_security is None:
            ua = ua.model_copy(update={"none_security": embedded})

        values = made.opcua_values = OpcUaValues(feed, compensation, camera, writer,
                                                 health.form_position, jobs)
        links.append(OpcUaServer(ua, GaugeView(
            values.values, values.measure_now, values.reset,
            serial_number=settings.camera.device_id or settings.camera.sim_serial,
            software_revision=package_version()), Path(data_dir) / "opcua"))
    return made
