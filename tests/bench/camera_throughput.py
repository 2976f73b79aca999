"""Frames per second the Aravis driver receives from the simulated GigE camera at 1376x1024
Mono8 on loopback, and the CPU the receiving process uses: with Aravis's packet socket (as
root), and with the plain UDP socket (as an unprivileged service) whose receive buffer is
sized by Aravis (AUTO) or fixed at 4 MiB.

Run: ``.venv/bin/python -m tests.bench.camera_throughput [--seconds S] [--fps F]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from drivers.camera.aravis import AravisCamera
from drivers.camera.base import CameraConfig
from tests.bench.results import save_report
from tests.integration.conftest import sim_camera_process


def cpu_seconds() -> float:
    """User + system CPU time of this process (all threads, Aravis's included)."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def run_once(device_id: str, fps: float, seconds: float, packet_socket: bool,
             socket_buffer_bytes: int | None) -> dict:
    cam = AravisCamera(device_id, CameraConfig(packet_size=8192, frame_rate_hz=fps,
                                               packet_socket=packet_socket, queue_size=8,
                                               socket_buffer_bytes=socket_buffer_bytes))
    cam.start()
    deadline = time.monotonic() + 20
    while cam.get_frame(0.5) is None and time.monotonic() < deadline:
        pass
    n, c0, t0 = 0, cpu_seconds(), time.monotonic()
    end = t0 + seconds  # a rate: frames counted over a measured time, in a bench
    while time.monotonic() < end:
        if cam.get_frame(0.5) is not None:
            n += 1
    wall, cpu = time.monotonic() - t0, cpu_seconds() - c0
    st = cam.status()
    cam.stop()
    return {"fps": n / wall, "cpu_percent_of_one_core": 100.0 * cpu / wall,
            "failed": st.counters.failed, "dropped": st.counters.dropped}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fps", type=float, default=60.0, help="frame rate asked of the camera")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--json", default="bench-results/camera_throughput.json")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="shaftgauge-camera-bench-"))  # the camera's files
    sim = sim_camera_process(tmp, "BENCH1", fps=args.fps).start()
    report: dict = {"asked_fps": args.fps, "seconds": args.seconds, "runs": args.runs,
                    "root": os.geteuid() == 0}
    try:
        variants = (("packet_socket", True, None), ("udp_socket_auto", False, None),
                    ("udp_socket_4MiB", False, 4 << 20))
        for name, packet_socket, sock_buf in variants:
            runs = [run_once(sim.device_id, args.fps, args.seconds, packet_socket, sock_buf)
                    for _ in range(args.runs)]
            report[name] = {
                "fps_median": statistics.median(r["fps"] for r in runs),
                "cpu_percent_median": statistics.median(r["cpu_percent_of_one_core"]
                                                        for r in runs),
                "runs": runs,
            }
            print(f"{name:16s}: {report[name]['fps_median']:6.1f} frames/s received, "
                  f"{report[name]['cpu_percent_median']:5.1f} % of one core "
                  f"(median of {args.runs} runs of {args.seconds:g} s, camera asked for "
                  f"{args.fps:g} fps)")
    finally:
        sim.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    save_report(report, "camera_throughput", path=args.json)


if __name__ == "__main__":
    main()
