"""The ``shaftgauge`` command."""

from __future__ import annotations

import argparse
import json
import math
import socket
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from calib_store.model import CalibrationError, load_calibration
from service.measure.result import DEFAULT_METHOD, MAX_UNCERTAINTY_MM, Method
from service.version import describe

if TYPE_CHECKING:
    from drivers.sim.lathe import LatheConfig
    from service.measure.params import MeasureParams

# What a command needs it imports itself: every simulator the service starts is a
# `shaftgauge` command too, and the measurement's modules took each of them a second of CPU.

# The shafts of the reference paper's Tables 3-6 (mm).
PAPER_DIAMETERS_MM = (47.062, 39.76, 34.924, 29.8,
                      24.753, 27.664, 31.473, 27.492, 24.621, 21.687, 20.113)

EXIT_OK, EXIT_USAGE = 0, 2


def _fail(message: str) -> int:
    print(f"shaftgauge: error: {message}", file=sys.stderr)
    return EXIT_USAGE


def cmd_measure(args: argparse.Namespace) -> int:
    """Print one JSON line per image (or one fused line); exit 2 on bad input files."""
    from service.measure.params import MeasureParams
    from service.offline import (
        CorrectionError,
        ImageError,
        add_temperature,
        fused_record,
        load_correction,
        measure_images,
        measurement_record,
    )

    if args.part_temp is not None:
        from service.measure.thermal import diameter_at_reference

        try:
            diameter_at_reference(1.0, args.part_temp, args.alpha)
        except ValueError as err:
            return _fail(str(err))
    if not args.max_uncertainty_um > 0:
        return _fail(f"--max-uncertainty-um must be positive, got {args.max_uncertainty_um}")
    if not (args.fps > 0 and math.isfinite(args.fps)):
        return _fail(f"--fps must be a positive frame rate, got {args.fps}")
    if not args.reflection_check_hz >= 0:
        return _fail(f"--reflection-check-hz must be 0 or more, got {args.reflection_check_hz}")
    params = MeasureParams(max_uncertainty_mm=args.max_uncertainty_um / 1000.0)
    if args.form and args.spindle_deg is None:
        return _fail("--form needs --spindle-deg (the angles, or `estimate`): the run-out "
                     "and the roundness come from the frames' spindle angles")
    if args.spindle_deg is not None:
        return _measure_turning(args, params)
    try:
        correction = load_correction(args.correction) if args.correction else None
        calibration = load_calibration(args.calibration)
        results = measure_images(args.images, calibration, Method(args.method), params,
                                 correction, args.fps, args.reflection_check_hz)
        if args.fuse:
            paths, ms = [], []
            for path, m in results:
                paths.append(path)
                ms.append(m)
            records = [fused_record(paths, ms)]
        else:
            records = (measurement_record(path, m) for path, m in results)
        for record in records:
            if args.part_temp is not None:
                add_temperature(record, args.part_temp, args.alpha)
            print(json.dumps(record), flush=True)
    except (CalibrationError, ImageError, CorrectionError) as err:
        return _fail(str(err).replace("\n", " "))
    return EXIT_OK


def _measure_turning(args: argparse.Namespace, params: MeasureParams) -> int:
    """``measure --spindle-deg``: each frame about the surface's own centre (one line each),
    or with ``--form`` one line of the diameter, run-out and roundness."""
    from service.offline import (
        ImageError,
        add_temperature,
        form_record,
        measure_turning_files,
        measurement_record,
        parse_spindle_angles,
    )

    if args.method != Method.AXIS.value or args.fuse or args.correction:
        return _fail("--spindle-deg measures by the axis method about the surface's own "
                     "centre: without --method, --fuse or --correction")
    try:
        angles = None if args.spindle_deg.strip().lower() == "estimate" else \
            parse_spindle_angles(args.spindle_deg, len(args.images))
        calibration = load_calibration(args.calibration)
        turning = measure_turning_files(args.images, calibration, angles, params, args.form,
                                        args.upr)
    except (ValueError, CalibrationError, ImageError) as err:
        return _fail(str(err).replace("\n", " "))
    if args.form:
        records = [form_record(args.images, turning)]
    else:
        records = [measurement_record(p, m)
                   for p, m in zip(args.images, turning.measurements, strict=True)]
    for record in records:
        if args.part_temp is not None:
            add_temperature(record, args.part_temp, args.alpha)
        print(json.dumps(record), flush=True)
    return EXIT_OK


def cmd_study(args: argparse.Namespace) -> int:
    """A type-1 gauge study on image files of the master: one value per ``--frames-per-value``
    consecutive images (fused), printed as JSON."""
    from service.measure.fuse import fuse
    from service.measure.params import MeasureParams
    from service.offline import CorrectionError, ImageError, load_correction, measure_images
    from service.quality.gauge_study import type1_study

    k = args.frames_per_value
    if k < 1 or k == 2:
        return _fail(f"--frames-per-value: 1 (each image a value) or 3 and more (fused), "
                     f"got {k}")
    if len(args.images) % k:
        return _fail(f"{len(args.images)} images do not make whole values of {k} frames")
    try:
        correction = load_correction(args.correction) if args.correction else None
        calibration = load_calibration(args.calibration)
        ms = [m for _, m in measure_images(args.images, calibration, Method(args.method),
                                           MeasureParams(), correction)]
    except (CalibrationError, ImageError, CorrectionError) as err:
        return _fail(str(err).replace("\n", " "))
    values, refused = [], []
    for i in range(0, len(ms), k):
        f = ms[i] if k == 1 else fuse(ms[i:i + k])
        if f and f.diameter_mm is not None:
            values.append(f.diameter_mm)
        else:
            refused.append({"images": args.images[i:i + k], "reason": f.reason})
    try:
        study = type1_study(values, args.master, args.tolerance_mm,
                            resolution=args.resolution_mm, min_index=args.min_index)
    except ValueError as err:
        return _fail(f"{err} ({len(refused)} values refused: "
                     f"{refused[0]['reason'] if refused else ''})")
    print(json.dumps({**study.as_dict(), "values_mm": values, "refused": refused}))
    return EXIT_OK


def cmd_render(args: argparse.Namespace) -> int:
    """Render simulated frames and their calibration into a folder."""
    from drivers.sim.frames import write_frames

    paths = write_frames(args.output, args.diameter, args.count, args.seed)
    print(json.dumps({"output": args.output, "images": len(paths),
                      "calibration": f"{args.output}/calibration.json"}))
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    """Render the paper's shafts on the simulated rig, measure them, print a table."""
    from drivers.sim.frames import write_frames
    from service.offline import measure_files

    with tempfile.TemporaryDirectory(prefix="shaftgauge-demo-") as tmp:
        print(f"Rendering {len(PAPER_DIAMETERS_MM)} simulated stripe images (1376x1024) ...")
        paths = write_frames(tmp, list(PAPER_DIAMETERS_MM), 1, args.seed)
        calibration = load_calibration(f"{tmp}/calibration.json")
        print(f"Measuring with `shaftgauge measure --method {args.method}`:\n")
        print(f"{'true mm':>9}  {'measured mm':>11}  {'error um':>8}  {'arc deg':>7}  status")
        for d, rec in zip(PAPER_DIAMETERS_MM, measure_files([str(p) for p in paths],
                                                            calibration, Method(args.method)),
                          strict=True):
            got = rec["diameter_mm"]
            err = "" if got is None else f"{(got - d) * 1000:8.1f}"
            shown = "" if got is None else f"{got:11.4f}"
            print(f"{d:9.3f}  {shown:>11}  {err:>8}  {rec['arc_deg']:7.1f}  {rec['status']}")
    return EXIT_OK


def cmd_serve(args: argparse.Namespace) -> int:
    """Run the service."""
    from service.config import ConfigError, load_settings
    from service.serve import main as serve_main

    try:
        settings = load_settings(args.config)
    except ConfigError as err:
        return _fail(str(err))
    try:
        return serve_main(settings)
    except (ValueError, RuntimeError, OSError) as err:
        return _fail(str(err))


def lathe_config(spec: str, diameter_mm: float) -> LatheConfig:
    """A virtual lathe's settings from JSON (``LatheConfig``'s fields; the nominal is the
    camera's diameter unless given, no scatter between samples unless asked: the camera's
    speckle is the gauge's noise); ValueError names what is wrong."""
    from drivers.sim.lathe import LatheConfig

    try:
        fields = json.loads(spec)
    except json.JSONDecodeError as err:
        raise ValueError(f"not JSON: {err}") from None
    if not isinstance(fields, dict):
        raise ValueError("an object of LatheConfig's fields, e.g. "
                         '\'{"wear_per_min_mm": 0.03, "laser_distance_mm": 2}\'')
    known = set(LatheConfig.__dataclass_fields__)
    unknown = set(fields) - known
    if unknown:
        raise ValueError(f"unknown fields {sorted(unknown)}; known: {sorted(known)}")
    fields = {"nominal_mm": diameter_mm, "part_sigma_mm": 0.0, **fields}
    for name in ("insert_changes", "chip_mm"):
        if name in fields:
            fields[name] = tuple(fields[name])
    try:
        return LatheConfig(**fields)
    except TypeError as err:
        raise ValueError(str(err)) from None


def cmd_sim_camera(args: argparse.Namespace) -> int:
    """Serve a simulated GigE Vision camera until interrupted."""
    import os
    import signal
    import threading

    from calib_store.model import save_calibration
    from drivers.sim.control import serve_control
    from drivers.sim.disturb import Disturbances
    from drivers.sim.gige import SimCameraSettings, SimGigECamera
    from drivers.sim.rig import RigConfig
    from drivers.sim.stepped import SteppedPart

    try:
        spec = Disturbances.from_dict(json.loads(args.disturbances)) if args.disturbances \
            else Disturbances()
    except (ValueError, TypeError, AttributeError) as err:
        return _fail(f"--disturbances: {err}")
    try:
        lathe = lathe_config(args.lathe, args.diameter) if args.lathe else None
    except ValueError as err:
        return _fail(f"--lathe: {err}")
    try:
        stepped = SteppedPart.from_json(args.stepped) if args.stepped else None
    except ValueError as err:
        return _fail(f"--stepped: {err}")
    settings = SimCameraSettings(
        serial=args.serial, address=args.address, diameter_mm=args.diameter,
        drift_um_per_min=args.drift_um_per_min, drift_period_min=args.drift_period_min,
        fps=args.fps, lost_ratio=args.lost_ratio,
        seed=args.seed, replay_frames=args.replay, rig=RigConfig(disturbances=spec),
        lathe=lathe, lathe_paced=args.lathe_paced, stepped=stepped)
    camera = SimGigECamera(settings)
    done = threading.Event()  # set: the simulator stops (and its CNC followers with it)
    try:
        camera.start()
    except (RuntimeError, ValueError) as err:
        return _fail(str(err))
    if args.cnc:
        if lathe is None and stepped is None:
            return _fail("--cnc: the CNC's totals move a virtual lathe or a stepped part: "
                         "give --lathe or --stepped too")
        from drivers.plc.client import CncTotalReader
        from drivers.plc.offset_map import PlcOffsetMap
        from drivers.plc.registers import WordOrder

        host, _, port = args.cnc.rpartition(":")
        if not host or not port.isdigit():
            return _fail(f"--cnc: write HOST:PORT, got {args.cnc!r}")
        offsets = PlcOffsetMap(total_address=args.cnc_total_address,
                               unit_id=args.cnc_unit_id,
                               word_order=WordOrder(args.cnc_word_order),
                               tool_stride=args.cnc_tool_stride)
        if camera.lathe is not None:
            camera.lathe.follow(CncTotalReader(host, int(port), offsets), done)
        elif camera.stepped is not None:  # each tool's own offset block (its T number)
            camera.stepped.follow({t: CncTotalReader(host, int(port), offsets.for_offset(t))
                                   for t in camera.stepped.part.tools}, done)
    if args.calibration_out:
        save_calibration(camera.renderer.calibration, args.calibration_out)
    server = serve_control(camera, args.control_port)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    print(json.dumps({"event": "ready", "device_id": camera.device_id,
                      "address": args.address, "control_port": server.server_address[1],
                      "calibration": args.calibration_out}), flush=True)
    done.wait()
    # A simulator must never outlive its welcome: if releasing Aravis hangs, leave anyway.
    watchdog = threading.Timer(5.0, lambda: os._exit(0))
    watchdog.daemon = True
    watchdog.start()
    server.shutdown()
    camera.stop()
    return EXIT_OK


def cmd_sim_plc(args: argparse.Namespace) -> int:
    """Serve a simulated CNC's offset registers until interrupted."""
    import asyncio
    import signal

    from drivers.plc.offset_map import PlcOffsetMap
    from drivers.plc.registers import WordOrder
    from drivers.plc.sim import SimPlc

    async def serve() -> int:
        try:
            plc = SimPlc(args.host, args.port,
                         PlcOffsetMap(args.offset_address, args.ack_address,
                                      args.total_address, args.unit_id,
                                      WordOrder(args.word_order), args.tool_stride),
                         ack_delay_s=args.ack_delay,
                         log_path=Path(args.log) if args.log else None,
                         state_path=Path(args.state) if args.state else None,
                         never_ack=args.never_ack, tools=args.tools)
        except ValueError as err:
            return _fail(str(err))
        try:
            port = await plc.start()
        except (OSError, RuntimeError) as err:
            return _fail(f"cannot listen on {args.host}:{args.port}: {err}")
        done = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, done.set)
        print(json.dumps({"event": "ready", "host": args.host, "port": port}), flush=True)
        await done.wait()
        await plc.stop()
        return EXIT_OK

    return asyncio.run(serve())


def cmd_calibrate(args: argparse.Namespace) -> int:
    """One calibration step on image files; writes JSON, prints a one-line summary."""
    from calib_store.model import save_calibration
    from service.calibrate import commands as c
    from service.calibrate.board import Board
    from service.calibrate.session import StepInputs, run_step

    try:
        if args.step == "render":
            from drivers.sim.board_shots import render_set

            print(json.dumps(render_set(args.output, args.seed, c.parse_board(args.board))))
            return EXIT_OK
        if args.step == "master":
            cal = load_calibration(args.calibration)
            masters = [(float(m[0]), m[1:]) for m in args.master]
            result = c.master_step(cal, masters)
            if args.output:
                c.write_json(args.output, result)
            print(json.dumps(result))
            return EXIT_OK
        if args.step == "build":
            inputs = StepInputs(Board(), intrinsics=args.intrinsics, plane=args.plane,
                                axis=args.axis)
        elif args.step == "intrinsics":
            inputs = StepInputs(c.parse_board(args.board), {"view": args.images},
                                detections=args.detections)
        elif args.step == "plane":
            if args.laser_on_only and args.pairs:
                return _fail("plane: give laser-off / laser-on pairs or --laser-on-only "
                             "images, not both")
            off, on = args.pairs[0::2], args.pairs[1::2]
            if args.laser_on_only:
                off, on = [], args.laser_on_only
            elif not args.pairs:
                return _fail("plane: give laser-off / laser-on pairs (OFF ON OFF ON ...) or "
                             "--laser-on-only IMAGE ...")
            inputs = StepInputs(Board(), {"plane_off": off, "plane_on": on},
                                intrinsics=args.intrinsics, detections=args.detections)
        else:
            inputs = StepInputs(Board(), {"axis": args.images}, intrinsics=args.intrinsics,
                                plane=args.plane, detections=args.detections)
        result = run_step(args.step, inputs)
        if args.step == "build":
            if args.report:
                c.write_json(args.report, result.report)
            print(json.dumps({"verdict": result.figures["verdict"],
                              "reasons": (result.report or {}).get("reasons", [])}))
            if result.calibration is None:
                return _fail("calibration refused: " + result.reason)
            save_calibration(result.calibration, args.output)
            return EXIT_OK
        c.write_json(args.output, result.figures)
        print(json.dumps({"step": result.step, "ok": result.ok, "reason": result.reason}))
        return EXIT_OK if result.ok else _fail(f"{args.step}: {result.reason}")
    except (c.StepError, CalibrationError, ValueError) as err:
        return _fail(str(err))


def cmd_check_host(args: argparse.Namespace) -> int:
    """Check the host settings a GigE camera needs; exit 1 when something needs changing."""
    from service.hostcheck import check_host

    checks = check_host(args.interface, args.rmem, args.mtu)
    for c in checks:
        print(f"{'ok  ' if c.ok else 'FIX '} {c.name} = {c.value}"
              + ("" if c.ok else f"\n      {c.fix}"))
    return 0 if all(c.ok for c in checks) else 1


def cmd_camera_list(args: argparse.Namespace) -> int:
    """One JSON line per camera Aravis sees."""
    from drivers.camera.aravis import enable_fake_interface, list_devices

    if args.fake:
        enable_fake_interface()
    for dev in list_devices():
        print(json.dumps(dev.__dict__))
    return EXIT_OK


def cmd_camera_grab(args: argparse.Namespace) -> int:
    """Save N frames as PNG, then print one JSON line with the counters."""
    from pathlib import Path

    import cv2

    from drivers.camera.aravis import AravisCamera, enable_fake_interface
    from drivers.camera.base import CameraConfig, CameraError

    if args.fake:
        enable_fake_interface()
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    try:
        # Change nothing the user did not ask for: any GigE Vision camera, as it is set up.
        config = CameraConfig(pixel_format=args.pixel_format, exposure_us=args.exposure_us,
                              packet_size=args.packet_size, queue_size=max(4, args.count))
    except CameraError as err:
        return _fail(str(err))
    camera = AravisCamera(args.device_id, config)
    saved, deadline = 0, None
    import time

    camera.start()
    try:
        deadline = time.monotonic() + args.timeout
        while saved < args.count and time.monotonic() < deadline:
            frame = camera.get_frame(timeout_s=0.5)
            if frame is None:
                continue
            cv2.imwrite(str(out / f"frame_{frame.frame_id:08d}.png"), frame.image)
            saved += 1
    finally:
        status = camera.status()
        camera.stop()
    print(json.dumps({"device_id": args.device_id, "saved": saved, "state": status.state.value,
                      "message": status.message, "counters": status.counters.__dict__}))
    if saved < args.count:
        return _fail(f"{args.device_id}: got {saved} of {args.count} frames in "
                     f"{args.timeout:g} s ({status.message})")
    return EXIT_OK


def _when(text: str) -> float:
    """An ISO 8601 time (no zone: UTC) as Unix seconds, for argparse."""
    import datetime as dt

    try:
        t = dt.datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an ISO 8601 time: {text!r}") from None
    return (t if t.tzinfo else t.replace(tzinfo=dt.UTC)).timestamp()


def cmd_api_key(args: argparse.Namespace) -> int:
    """API keys kept as hashes: add one (printed once), list them, remove one."""
    from calib_store import api_keys

    path = Path(args.key_file)
    try:
        if args.action == "add":
            entry, key = api_keys.add(path, args.role, args.note)
            print(json.dumps({"id": entry.id, "role": entry.role, "key": key,
                              "key_file": str(path), "note": "shown this once: keep it"}))
        elif args.action == "list":
            print(json.dumps([{"id": k.id, "role": k.role, "created": k.created,
                               "note": k.note} for k in api_keys.read(path)]))
        elif not api_keys.remove(path, args.id):
            return _fail(f"{path}: no key {args.id!r}")
        else:
            print(json.dumps({"removed": args.id}))
    except api_keys.KeyFileError as err:
        return _fail(str(err))
    return EXIT_OK


def cmd_store(args: argparse.Namespace) -> int:
    """The store's schema version, its migrations, a backup and a restore."""
    import sqlite3

    from calib_store import schema

    path = Path(args.store)
    source = Path(args.backup) if args.action == "restore" else path
    if not source.is_file():
        return _fail(f"{source}: no such store file")
    try:
        # Read-only unless migrating: nothing changes a file by looking at it.
        mode = "rw" if args.action == "migrate" and not args.dry_run else "ro"
        db = sqlite3.connect(f"file:{source}?mode={mode}", uri=True, isolation_level=None)
        check = db.execute("PRAGMA integrity_check").fetchone()[0]
        if check != "ok":
            return _fail(f"{source} is damaged (integrity check: {check})")
        todo = schema.pending(db, source)
        out: dict = {"store": str(source), "schema_version": schema.version_of(db),
                     "release_knows": schema.SCHEMA_VERSION,
                     "pending": [f"{m.version}: {m.what}" for m in todo]}
        if args.action == "migrate" and not args.dry_run:
            out["applied"] = [m.version for m in schema.migrate(db, path)]
            out["schema_version"] = schema.version_of(db)
        elif args.action == "backup":
            out["backup"] = str(schema.backup(db, args.output))
        elif args.action == "restore":
            if path.exists():
                with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as current:
                    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
                    out["kept"] = str(schema.backup(
                        current, path.with_name(f"{path.name}.before-restore-{stamp}.bak")))
            target = sqlite3.connect(str(path))
            try:
                db.backup(target)
            finally:
                target.close()
            out["restored"] = str(path)
        db.close()
    except schema.SchemaError as err:
        return _fail(str(err))
    except sqlite3.DatabaseError as err:
        return _fail(f"{source} cannot be used as a store: {err}")
    print(json.dumps(out))
    return EXIT_OK


def cmd_job(args: argparse.Namespace) -> int:
    """The job in force, or none: ``deactivate`` takes a stored job out of force (the
    service back on its settings' single feature), also while the service is stopped."""
    from calib_store.job_store import JobStore
    from calib_store.store import StoreError

    try:
        store = JobStore(args.store, create_if_missing=False)
    except StoreError as err:
        return _fail(str(err))
    try:
        active = store.active()
        if args.action == "deactivate" and active is not None:
            store.deactivate("cli")
    finally:
        store.close()
    print(json.dumps({"store": args.store, "active": None if active is None else {
        "id": active.id, "part_number": active.part_number, "version": active.version},
        "deactivated": args.action == "deactivate" and active is not None}))
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    """Write the store's archived measurements as a Q-DAS AQDEF transfer file."""
    from calib_store.compensation_log import CompensationLog
    from calib_store.store import StoreError
    from service.plant.aqdef import (
        archive_part,
        archive_values,
        as_text,
        encoded,
        header_lines,
        value_lines,
    )

    if args.start is not None and args.end is not None and args.start > args.end:
        return _fail("--from is after --to")
    try:
        log_ = CompensationLog(args.store, create_if_missing=False)
    except StoreError as err:
        return _fail(str(err))
    out = Path(args.output)
    try:
        # A page of rows at a time, as the API streams it: a year of archive fits in memory.
        summary = log_.measurement_summary(args.start, args.end, 2**62)
        part = archive_part(summary, args.gauge_id, args.part, args.characteristic,
                            None if args.max_tir_um is None else args.max_tir_um / 1000.0)
        rows = 0
        with out.open("wb") as f:
            f.write(encoded(as_text(header_lines(part))))
            for page in log_.measurement_pages(args.start, args.end, 2**62,
                                               last_seq=summary["last_seq"]):
                rows += len(page)
                f.write(encoded(as_text(value_lines(part, archive_values(part, page)))))
    except OSError as err:
        return _fail(f"{out}: cannot write ({err.strerror})")
    finally:
        log_.close()
    print(json.dumps({"output": str(out), "values": summary["good"], "rows": rows}))
    return EXIT_OK


class _Version(argparse.Action):
    """``--version``: worked out only when asked (it may run git)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        print(describe())
        parser.exit()


def _detections_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--detections", metavar="DIR", help="keep the board's detections in DIR: "
                   "a later step or run given the same images reads them there instead of "
                   "detecting again (half a second an image)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(
        prog="shaftgauge", description="Lathe-side shaft diameter measurement.")
    parser.add_argument("--version", action=_Version,
                        help="the package's version and the commit it was built from")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    methods = [m.value for m in Method]

    p = sub.add_parser("measure", help="measure stripe images offline, one JSON line each")
    p.add_argument("--calibration", required=True, metavar="CAL.json",
                   help="calibration file (shaftgauge.calibration/1)")
    p.add_argument("--method", choices=methods, default=DEFAULT_METHOD.value,
                   help=f"fitting method (default: {DEFAULT_METHOD.value}, the most accurate)")
    p.add_argument("--fuse", action="store_true",
                   help="combine all images into one robust diameter (one JSON line)")
    p.add_argument("--part-temp", type=float, metavar="C",
                   help="part temperature: adds the diameter at 20 C")
    p.add_argument("--alpha", type=float, default=11.5e-6, metavar="PER_K",
                   help="linear expansion coefficient (default steel, 11.5e-6 1/K)")
    p.add_argument("--correction", metavar="MASTER.json",
                   help="the master correction (`calibrate master --output`), applied as the "
                   "service applies it")
    p.add_argument("--max-uncertainty-um", type=float,
                   default=MAX_UNCERTAINTY_MM * 1000.0, metavar="UM",
                   help="refuse a diameter more uncertain than this (status `uncertain`; "
                   "default %(default)g um; `inf` reports every fit)")
    p.add_argument("--fps", type=float, default=10.0, metavar="HZ",
                   help="the frame rate the images were taken at, for the reflection check's "
                   "cadence (default %(default)g)")
    p.add_argument("--reflection-check-hz", type=float, default=5.0, metavar="HZ",
                   help="images a second of that rate looked at for a reflection beside the "
                   "stripe, as the service does (default %(default)g; every image while one "
                   "is seen, and every lopsided stripe); `inf` checks every image")
    p.add_argument("--spindle-deg", metavar="A1,A2,...",
                   help="each image's spindle angle, degrees, right-handed about the "
                   "calibration's axis direction: the frames are measured about the "
                   "surface's own centre (its run-out from all of them); `estimate`: the "
                   "images in the order taken at a steady frame rate and spindle speed, "
                   "the spindle's turn per frame told from the frames themselves")
    p.add_argument("--form", action="store_true",
                   help="with --spindle-deg: one JSON line of the diameter, the run-out "
                   "(eccentricity, phase, TIR) and the roundness (RONt, harmonics)")
    p.add_argument("--upr", type=int, choices=(15, 50), default=50,
                   help="the roundness filter, undulations per revolution (default 50)")
    p.add_argument("images", nargs="+", metavar="IMAGE", help="8- or 16-bit grey image files")
    p.set_defaults(func=cmd_measure)

    p = sub.add_parser("render", help="render simulated stripe images and their calibration")
    p.add_argument("--diameter", type=float, action="append", required=True, metavar="MM",
                   help="shaft diameter in mm (repeat for several)")
    p.add_argument("--count", type=int, default=1, help="frames per diameter")
    p.add_argument("--seed", type=int, default=0, help="speckle and noise seed")
    p.add_argument("--output", required=True, metavar="DIR", help="folder to write into")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("serve", help="run the measuring service (REST, dashboard, Modbus)")
    p.add_argument("--config", metavar="FILE", help="TOML settings (default: the embedded "
                   "default, a simulated camera and PLC on loopback)")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("sim-camera", help="serve a simulated GigE Vision camera (Aravis fake "
                       "camera streaming the simulated rig)")
    p.add_argument("--serial", default="SIM001", help="serial number (device id "
                   "Aravis-Fake-SERIAL)")
    p.add_argument("--address", default="127.0.0.1", help="IPv4 address to serve on")
    p.add_argument("--diameter", type=float, required=True, metavar="MM")
    p.add_argument("--fps", type=float, default=10.0)
    p.add_argument("--drift-um-per-min", type=float, default=0.0,
                   help="tool wear: diameter change in um per minute")
    p.add_argument("--drift-period-min", type=float, default=0.0, metavar="MIN",
                   help="the drift starts again this often, as after a new insert (0: never)")
    p.add_argument("--lost-ratio", type=float, default=0.0, help="GVSP packet loss (0-1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--replay", type=int, default=0, metavar="N",
                   help="render a ring of N frames at start and only send them afterwards "
                   "(re-rendered in the background when the diameter changes); 0 renders "
                   "every frame")
    p.add_argument("--disturbances", metavar="JSON",
                   help="the shop floor's disturbances, e.g. '{\"glints\": {\"count\": 8}, "
                   "\"ghost\": {\"gain\": 0.3}}' (drivers/sim/disturb.py; the control "
                   "port's {\"set\": {\"disturbances\": ...}} changes them live)")
    p.add_argument("--control-port", type=int, default=0,
                   help="loopback TCP port of the JSON-lines control (0: any free port)")
    p.add_argument("--calibration-out", metavar="FILE",
                   help="write the simulated rig's exact calibration here")
    p.add_argument("--lathe", metavar="JSON",
                   help="a virtual lathe decides the diameter shown (continuous turning, "
                   "drivers/sim/lathe.py), e.g. '{\"wear_per_min_mm\": 0.03, "
                   "\"laser_distance_mm\": 2, \"feed_mm_per_min\": 60}'; the CNC's total "
                   "offset comes from --cnc or the control port's cnc_total_mm")
    p.add_argument("--lathe-paced", action="store_true",
                   help="the lathe's time stands until the control port's advance_lathe "
                   "moves it (a test in step with the gauge); without: the wall clock")
    p.add_argument("--stepped", metavar="JSON",
                   help="a stepped shaft, part after part, its segments in turn "
                   "(drivers/sim/stepped.py), e.g. '{\"segments\": [{\"diameter_mm\": 30, "
                   "\"tool\": 1}, {\"diameter_mm\": 25, \"tool\": 2}], \"dwell_s\": 3, "
                   "\"wear_um_per_min\": {\"1\": 0.4, \"2\": 0.8}}'")
    p.add_argument("--cnc", metavar="HOST:PORT",
                   help="with --lathe: the push CNC (sim-plc) whose applied total the lathe "
                   "follows, read over Modbus TCP; with --stepped: each tool's total "
                   "(its T number's block), a part cut with those in force as it starts")
    p.add_argument("--cnc-total-address", type=int, default=106)
    p.add_argument("--cnc-tool-stride", type=int, default=0,
                   help="registers between the CNC's offset blocks (sim-plc --tool-stride)")
    p.add_argument("--cnc-unit-id", type=int, default=1)
    p.add_argument("--cnc-word-order", choices=("big", "little"), default="big")
    p.set_defaults(func=cmd_sim_camera)

    p = sub.add_parser("sim-plc", help="serve a simulated CNC's offset registers over "
                       "Modbus TCP")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=5021)
    p.add_argument("--unit-id", type=int, default=1)
    p.add_argument("--offset-address", type=int, default=100)
    p.add_argument("--ack-address", type=int, default=104)
    p.add_argument("--total-address", type=int, default=106)
    p.add_argument("--word-order", choices=["big", "little"], default="big")
    p.add_argument("--ack-delay", type=float, default=0.0, metavar="S",
                   help="seconds between receiving and acknowledging an offset")
    p.add_argument("--log", metavar="FILE", help="JSON-lines log of writes and applications")
    p.add_argument("--state", metavar="FILE", help="keep the applied total across restarts")
    p.add_argument("--tools", type=int, default=0, metavar="N",
                   help="keep a block for each of tools 1..N too (--tool-stride apart)")
    p.add_argument("--tool-stride", type=int, default=10, metavar="REGISTERS",
                   help="registers from one tool's block to the next")
    p.add_argument("--never-ack", action="store_true",
                   help="keep every offset request, apply and acknowledge none")
    p.set_defaults(func=cmd_sim_plc)

    cal = sub.add_parser("calibrate", help="calibrate from image files, step by step")
    steps = cal.add_subparsers(dest="step", required=True, metavar="STEP")
    p = steps.add_parser("render", help="write a simulated calibration image set")
    p.add_argument("--output", required=True, metavar="DIR")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--board", default="11x8x8", help="the target (as for intrinsics)")
    p = steps.add_parser("intrinsics", help="camera matrix and distortion from board views")
    p.add_argument("--board", default="11x8x8", help="the target: COLSxROWSxMM (a "
                   "chessboard's inner corners, square), chess:..., circles:COLSxROWSxPITCH, "
                   "acircles:COLSxROWSxPITCH (docs/calibrating.md)")
    p.add_argument("--output", required=True, metavar="FILE")
    _detections_option(p)
    p.add_argument("images", nargs="+", metavar="IMAGE")
    p = steps.add_parser("plane", help="light plane from laser-off / laser-on pairs, or "
                         "laser-on images alone")
    p.add_argument("--intrinsics", required=True, metavar="FILE")
    p.add_argument("--output", required=True, metavar="FILE")
    p.add_argument("--laser-on-only", nargs="+", metavar="IMAGE", default=[],
                   help="laser-on images with no laser-off twin (the line found by its "
                   "colour, or above the board's pattern)")
    _detections_option(p)
    p.add_argument("pairs", nargs="*", metavar="IMAGE", help="OFF ON OFF ON ...")
    p = steps.add_parser("axis", help="spindle axis from the board turned between centres")
    p.add_argument("--intrinsics", required=True, metavar="FILE")
    p.add_argument("--plane", metavar="FILE", help="to place the axis point on the plane")
    p.add_argument("--output", required=True, metavar="FILE")
    _detections_option(p)
    p.add_argument("images", nargs="+", metavar="IMAGE")
    p = steps.add_parser("build", help="assemble and grade the calibration document")
    p.add_argument("--intrinsics", required=True, metavar="FILE")
    p.add_argument("--plane", required=True, metavar="FILE")
    p.add_argument("--axis", required=True, metavar="FILE")
    p.add_argument("--output", required=True, metavar="CAL.json")
    p.add_argument("--report", metavar="FILE", help="write the quality report here")
    p = steps.add_parser("master", help="diameter correction from one or two masters")
    p.add_argument("--calibration", required=True, metavar="CAL.json")
    p.add_argument("--master", nargs="+", action="append", required=True,
                   metavar="MM_THEN_IMAGES", help="certified diameter, then its images")
    p.add_argument("--output", metavar="FILE")
    cal.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("check-host", help="check the host settings a GigE camera needs")
    p.add_argument("--interface", help="the network interface the camera is on")
    p.add_argument("--rmem", type=int, default=8 * 1024 * 1024,
                   help="socket receive buffer wanted, bytes")
    p.add_argument("--mtu", type=int, default=9000, help="MTU wanted (jumbo frames)")
    p.set_defaults(func=cmd_check_host)

    cam = sub.add_parser("camera", help="GigE Vision cameras (any that Aravis sees)")
    cam_sub = cam.add_subparsers(dest="camera_command", required=True, metavar="ACTION")
    p = cam_sub.add_parser("list", help="one JSON line per camera found")
    p.add_argument("--fake", action="store_true", help="include Aravis's in-process fake")
    p.set_defaults(func=cmd_camera_list)
    p = cam_sub.add_parser("grab", help="save N frames as PNG, then print the counters")
    p.add_argument("device_id")
    p.add_argument("--count", type=int, default=1)
    p.add_argument("--output", required=True, metavar="DIR")
    p.add_argument("--pixel-format", choices=["Mono8", "Mono12", "Mono16"],
                   help="default: leave the camera's own")
    p.add_argument("--exposure-us", type=float)
    p.add_argument("--packet-size", type=int, help="bytes (default: negotiate)")
    p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for frames")
    p.add_argument("--fake", action="store_true", help="enable Aravis's in-process fake")
    p.set_defaults(func=cmd_camera_grab)

    p = sub.add_parser("study", help="a type-1 gauge study (Cg, Cgk) on images of a master")
    p.add_argument("--calibration", required=True, metavar="CAL.json")
    p.add_argument("--master", required=True, type=float, metavar="MM",
                   help="the master's certified diameter, mm")
    p.add_argument("--tolerance-mm", required=True, type=float, metavar="T",
                   help="the feature's tolerance USL - LSL, mm")
    p.add_argument("--frames-per-value", type=int, default=1, metavar="N",
                   help="consecutive images fused into one value: 1, or 3 and more (the "
                   "service uses measurement.fuse_frames)")
    p.add_argument("--correction", metavar="MASTER.json", help="`calibrate master` output")
    p.add_argument("--method", choices=methods, default=DEFAULT_METHOD.value)
    p.add_argument("--resolution-mm", type=float, default=0.0001)
    p.add_argument("--min-index", type=float, default=1.33)
    p.add_argument("images", nargs="+", metavar="IMAGE")
    p.set_defaults(func=cmd_study)

    ak = sub.add_parser("api-key", help="API keys kept as hashes (api.key_file)")
    ak_sub = ak.add_subparsers(dest="action", required=True, metavar="ACTION")
    for name, text in (("add", "a new random key of a role, printed once"),
                       ("list", "the keys' ids and roles (never a key)"),
                       ("remove", "a key by its id")):
        p = ak_sub.add_parser(name, help=text)
        p.add_argument("--key-file", default="/etc/shaftgauge/api-keys.json", metavar="FILE",
                       help="api.key_file (default %(default)s)")
        if name == "add":
            p.add_argument("--role", required=True, choices=["operator", "technician",
                                                             "admin"])
            p.add_argument("--note", default="", help="who or what the key is for")
        if name == "remove":
            p.add_argument("id", metavar="ID")
        p.set_defaults(func=cmd_api_key)

    st = sub.add_parser("store", help="the store's schema version, migrations, backup and "
                        "restore")
    st_sub = st.add_subparsers(dest="action", required=True, metavar="ACTION")
    store_help = "the service's store (store.path; default %(default)s)"
    for name, text in (("version", "its schema version and what this release would migrate"),
                       ("migrate", "apply the pending migrations (backed up first)"),
                       ("backup", "a consistent copy, also while the service runs"),
                       ("restore", "the store replaced by a backup (stop the service first; "
                        "the store it replaces is kept beside it)")):
        p = st_sub.add_parser(name, help=text)
        p.add_argument("--store", default="shaftgauge-data/shaftgauge.db", metavar="DB",
                       help=store_help)
        if name == "migrate":
            p.add_argument("--dry-run", action="store_true", help="say what, change nothing")
        if name == "backup":
            p.add_argument("output", metavar="BACKUP.db", help="a new file")
        if name == "restore":
            p.add_argument("backup", metavar="BACKUP.db")
        p.set_defaults(func=cmd_store)

    jb = sub.add_parser("job", help="the stored job in force")
    jb_sub = jb.add_subparsers(dest="action", required=True, metavar="ACTION")
    for name, text in (("show", "which stored job is in force (JSON)"),
                       ("deactivate", "take the stored job out of force: the settings' single "
                        "feature, at the service's next start or at once over REST")):
        p = jb_sub.add_parser(name, help=text)
        p.add_argument("--store", default="shaftgauge-data/shaftgauge.db", metavar="DB",
                       help=store_help)
        p.set_defaults(func=cmd_job)

    exp = sub.add_parser("export", help="export the store's measurements")
    exp_sub = exp.add_subparsers(dest="format", required=True, metavar="FORMAT")
    p = exp_sub.add_parser("aqdef", help="as a Q-DAS ASCII transfer file (K-fields)")
    p.add_argument("--store", default="shaftgauge-data/shaftgauge.db", metavar="DB",
                   help="the service's store (store.path; default %(default)s)")
    p.add_argument("--from", dest="start", type=_when, metavar="TIME",
                   help="ISO 8601, no zone = UTC (default: the first kept)")
    p.add_argument("--to", dest="end", type=_when, metavar="TIME",
                   help="ISO 8601 (default: the last kept)")
    p.add_argument("--output", required=True, metavar="FILE.dfq")
    p.add_argument("--gauge-id", default=socket.gethostname(), help="K0012 (default: host)")
    p.add_argument("--part", default="shaft", help="K1001 part number")
    p.add_argument("--characteristic", default="diameter", help="K2002")
    p.add_argument("--max-tir-um", type=float, default=None, metavar="UM",
                   help="the run-out characteristic's upper limit (spindle.max_tir_mm), where "
                        "the archive has run-out")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("demo", help="offline demo: render the paper's shafts and measure them")
    p.add_argument("--method", choices=methods, default=DEFAULT_METHOD.value)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``shaftgauge`` console script."""
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
