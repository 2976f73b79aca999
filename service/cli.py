"""The ``shaftgauge`` command."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Sequence

from calib_store.model import CalibrationError, load_calibration
from service.measure.diameter import DEFAULT_METHOD
from service.measure.result import Method

# The shafts of the reference paper's Tables 3-6 (mm).
PAPER_DIAMETERS_MM = (47.062, 39.76, 34.924, 29.8,
                      24.753, 27.664, 31.473, 27.492, 24.621, 21.687, 20.113)

EXIT_OK, EXIT_USAGE = 0, 2


def _fail(message: str) -> int:
    print(f"shaftgauge: error: {message}", file=sys.stderr)
    return EXIT_USAGE


def cmd_measure(args: argparse.Namespace) -> int:
    """Print one JSON line per image; exit 2 on a bad calibration or image file."""
    from service.offline import ImageError, measure_files

    try:
        calibration = load_calibration(args.calibration)
        for record in measure_files(args.images, calibration, Method(args.method)):
            print(json.dumps(record), flush=True)
    except (CalibrationError, ImageError) as err:
        return _fail(str(err).replace("\n", " "))
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


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(
        prog="shaftgauge", description="Lathe-side shaft diameter measurement.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    methods = [m.value for m in Method]

    p = sub.add_parser("measure", help="measure stripe images offline, one JSON line each")
    p.add_argument("--calibration", required=True, metavar="CAL.json",
                   help="calibration file (shaftgauge.calibration/1)")
    p.add_argument("--method", choices=methods, default=DEFAULT_METHOD.value,
                   help=f"fitting method (default: {DEFAULT_METHOD.value}, the most accurate)")
    p.add_argument("images", nargs="+", metavar="IMAGE", help="8- or 16-bit grey image files")
    p.set_defaults(func=cmd_measure)

    p = sub.add_parser("render", help="render simulated stripe images and their calibration")
    p.add_argument("--diameter", type=float, action="append", required=True, metavar="MM",
                   help="shaft diameter in mm (repeat for several)")
    p.add_argument("--count", type=int, default=1, help="frames per diameter")
    p.add_argument("--seed", type=int, default=0, help="speckle and noise seed")
    p.add_argument("--output", required=True, metavar="DIR", help="folder to write into")
    p.set_defaults(func=cmd_render)

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
