"""How well board views fix the principal point of the simulated rig's camera (25 mm lens,
1376x1024 px of 6.45 um: a 20 degree field), and so how far the camera frame itself may turn.

The corners are the true projections of the session's board poses plus independent Gaussian
noise (``--sigma`` px, ideal detection): no renderer or detector error enters. For each view set
it calibrates ``--trials`` noise draws and reports the standard deviation of the principal point
and of the focal length, and what a principal point off by that much does at the spindle axis
(the whole camera frame turns by dc/f: the axis point moves by standoff * dc / f).

Run: ``.venv/bin/python -m tests.bench.principal_point [--trials N] [--sigma PX]``.
"""

from __future__ import annotations

import argparse
import itertools

import cv2
import numpy as np

from drivers.sim.board_shots import Board, BoardPose, BoardRenderer
from drivers.sim.rig import RigConfig, ShaftRenderer
from tests.bench.results import save_report

BOARD = Board(cols=11, rows=8, square_mm=8.0)


def view_poses(br: BoardRenderer, tilt_deg: float, every: int) -> list[BoardPose]:
    """The session's board views (tilts about x and y, three distances, three shifts)."""
    specs = [(tx, ty, d, sh)
             for (tx, ty), d in zip(itertools.product((-tilt_deg, 0, tilt_deg), repeat=2),
                                    itertools.cycle((380, 420, 400)))
             for sh in ((0, 0), (-20, -15), (20, 15))][::every]
    return [br.pose_facing_camera(*s) for s in specs]


def spread(poses: list[BoardPose], K: np.ndarray, dist: np.ndarray, sigma_px: float,
           trials: int, seed: int) -> dict[str, float]:
    """Std of cx, cy (px) and of f (relative) over noise draws of ideal corners."""
    rng = np.random.default_rng(seed)
    obj = BOARD.object_points()
    proj = [cv2.projectPoints(obj @ p.R.T + p.t, np.zeros(3), np.zeros(3), K, dist)[0]
            .reshape(-1, 2) for p in poses]
    errs = []
    for _ in range(trials):
        img = [(q + sigma_px * rng.standard_normal(q.shape)).astype(np.float32) for q in proj]
        _, K2, *_ = cv2.calibrateCamera([obj.astype(np.float32)] * len(poses), img,
                                        (1376, 1024), None, None, flags=cv2.CALIB_FIX_K3)
        errs.append([K2[0, 2] - K[0, 2], K2[1, 2] - K[1, 2], K2[0, 0] / K[0, 0] - 1])
    e = np.array(errs)
    return {"views": len(poses), "cx_std_px": float(e[:, 0].std()),
            "cy_std_px": float(e[:, 1].std()), "f_std_rel": float(e[:, 2].std())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--sigma", type=float, default=0.035,
                    help="corner noise, px (the detector on rendered views: 0.035)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default="bench-results/principal_point.json")
    args = ap.parse_args()
    rig = ShaftRenderer(RigConfig(), seed=0)
    br = BoardRenderer(rig, BOARD)
    K, dist = rig.config.camera_matrix(), np.array(rig.config.dist_coeffs)
    plane = [br.pose_facing_camera(tx, ty, d)
             for tx, ty, d in [(20, 0, 290), (-20, 0, 310), (0, 20, 300), (0, -20, 295)]]
    spindle = [br.pose_on_spindle(a) for a in (-45, -30, -15, 0, 15, 30, 45)]
    sets = {
        "14 views, tilts 25 deg": view_poses(br, 25, 2),
        "27 views, tilts 25 deg": view_poses(br, 25, 1),
        "14 views, tilts 40 deg": view_poses(br, 40, 2),
        "14 views + 4 plane + 7 spindle": view_poses(br, 25, 2) + plane + spindle,
        "27 views + 4 plane + 7 spindle": view_poses(br, 25, 1) + plane + spindle,
    }
    f_px, standoff = K[0, 0], rig.config.standoff_mm
    print(f"corner noise {args.sigma} px, {args.trials} draws each; f = {f_px:.0f} px, "
          f"axis at {standoff:.0f} mm\n")
    print(f"{'view set':>32} {'cx std px':>9} {'cy std px':>9} {'f std %':>8} "
          f"{'axis shift mm':>13}")
    out = {"sigma_px": args.sigma, "trials": args.trials, "sets": {}}
    for name, poses in sets.items():
        s = spread(poses, K, dist, args.sigma, args.trials, args.seed)
        s["axis_shift_mm"] = standoff * float(np.hypot(s["cx_std_px"], s["cy_std_px"])) / f_px
        out["sets"][name] = s
        print(f"{name:>32} {s['cx_std_px']:9.2f} {s['cy_std_px']:9.2f} "
              f"{100 * s['f_std_rel']:8.3f} {s['axis_shift_mm']:13.3f}")
    save_report(out, "principal_point", path=args.json)


if __name__ == "__main__":
    main()
