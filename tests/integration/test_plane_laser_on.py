"""The light plane from laser-on images alone (no laser-off twins): on rendered chessboard and
ChArUco poses, grey and colour (a red laser: its light in the red channel),
within 1.5 times the error of the same poses' pairs; and through the command line from colour
JPEGs."""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.sim.board_shots import BoardRenderer, session_shots
from drivers.sim.rig import RigConfig, ShaftRenderer
from service.calibrate import commands
from service.calibrate.board import parse_board
from service.calibrate.kept_detections import detect_kept
from service.calibrate.plane import PlaneResult, calibrate_plane, calibrate_plane_laser_on
from service.calibrate.session import StepInputs, run_step
from service.measure.geometry import geometry_of

SHAFTGAUGE = str(Path(sys.executable).with_name("shaftgauge"))
RIG = ShaftRenderer(RigConfig(), seed=3)


@functools.lru_cache(maxsize=2)
def rendered(target: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The session's four plane poses of another target than the chessboard: laser off,
    laser on."""
    br = BoardRenderer(RIG, parse_board(target))
    shots = [s for s in session_shots() if s.kind in ("plane_off", "plane_on")]
    image = {s.name: br.render(s.pose(br), laser=s.laser, frame_index=s.frame_index)
             for s in shots}
    return ([image[s.name] for s in shots if s.kind == "plane_off"],
            [image[s.name] for s in shots if s.kind == "plane_on"])


@pytest.fixture(scope="module")
def poses(calibration_images, detections):
    """The plane poses, laser off and on, of a target: the chessboard's from the rendered
    session every test reads (``calibration_images``, their detections kept for the run),
    the others' rendered here."""
    def of(target: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
        if target != "11x8x8":
            off, on = rendered(target)
            detect_kept(off + on, parse_board(target), detections)
            return off, on
        read = [cv2.imread(str(calibration_images / "plane" / f"pose{i}_{kind}.png"),
                           cv2.IMREAD_GRAYSCALE) for kind in ("off", "on") for i in range(4)]
        detect_kept(read, parse_board(target), detections)
        return read[:4], read[4:]
    return of


def red_laser(off: np.ndarray, on: np.ndarray) -> np.ndarray:
    """A colour photograph of the pose with a red laser: the board grey in every channel, the
    line's light in the red one alone."""
    return cv2.merge([off, off, on])


def error_mm(plane: PlaneResult) -> float:
    """The recovered plane's largest distance from the true one where shafts are measured (a
    square of 40 mm of the true plane around the spindle axis)."""
    geo = geometry_of(RIG.calibration)
    n, d = geo.plane_normal, geo.plane_d
    a0 = geo.axis_point - (geo.axis_point @ n - d) * n
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    grid = [a0 + s * e1 + t * e2 for s in (-20, 20) for t in (-20, 20)]
    return max(abs(float(p @ plane.normal) - plane.d) for p in grid)


@pytest.mark.parametrize("target", ["11x8x8", "charuco:14x10x8x6"])
def test_laser_on_images_alone_are_within_one_and_a_half_times_the_pairs(target: str, poses
                                                                         ) -> None:
    off, on = poses(target)
    K, dist = RIG.config.camera_matrix(), np.array(RIG.config.dist_coeffs)
    board = parse_board(target)
    pairs = calibrate_plane(list(zip(off, on, strict=True)), board, K, dist)
    grey = calibrate_plane_laser_on(on, board, K, dist)
    colour = calibrate_plane_laser_on([red_laser(a, b) for a, b in zip(off, on, strict=True)],
                                      board, K, dist)
    assert pairs and grey and colour, (pairs.reason, grey.reason, colour.reason)
    print(f"\n{target}: plane error pairs {error_mm(pairs) * 1000:.1f} um, laser on alone "
          f"grey {error_mm(grey) * 1000:.1f} um, colour {error_mm(colour) * 1000:.1f} um")
    # A colour photograph (the laser's colour tells its light from the board's) is within 1.5
    # times the pairs; a grey one, with nothing but the board's pattern to go by, within 2.5.
    assert error_mm(colour) <= 1.5 * error_mm(pairs), (error_mm(colour), error_mm(pairs))
    assert error_mm(grey) <= 2.5 * error_mm(pairs), (error_mm(grey), error_mm(pairs))
    for alone in (grey, colour):
        assert min(alone.per_pose_points) >= 200
    assert set(grey.how.values()) == {"laser on only: grey, above the board's own pattern"}
    assert set(colour.how.values()) == {
        "laser on only: the red channel less the board the others show"}
    assert set(pairs.how.values()) == {"the difference of the laser-off and laser-on images"}


def test_laser_on_images_with_no_line_are_refused_per_image(poses) -> None:
    off, _ = poses("11x8x8")
    K, dist = RIG.config.camera_matrix(), np.array(RIG.config.dist_coeffs)
    res = calibrate_plane_laser_on(off, parse_board("11x8x8"), K, dist)
    assert not res and "turn the laser on" in res.reason
    assert len(res.rejected) == 4 and all(
        "laser line missing" in why and "grey" in why for why in res.rejected.values())


def test_the_command_line_takes_colour_jpegs_with_the_laser_on_alone(tmp_path,
                                                                      calibration_images,
                                                                      poses, detections
                                                                      ) -> None:
    """Views and laser-on poses as a phone writes them (colour JPEG): the intrinsics say
    what became of the colour, the plane which channel held the line."""
    views, on_only = [], []
    # Every other view (7 of 14: the intrinsics' precision is test_recover_rig's; here the
    # colour JPEGs' way through the command line, and the plane they give).
    for png in sorted((calibration_images / "views").glob("*.png"))[::2]:
        path = tmp_path / f"{png.stem}.jpg"
        cv2.imwrite(str(path), cv2.merge([cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)] * 3),
                    [cv2.IMWRITE_JPEG_QUALITY, 95])
        views.append(str(path))
    for i, (off, on) in enumerate(zip(*poses("11x8x8"), strict=True)):
        path = tmp_path / f"pose{i}_on.jpg"
        cv2.imwrite(str(path), red_laser(off, on), [cv2.IMWRITE_JPEG_QUALITY, 95])
        on_only.append(str(path))
    intr, plane = tmp_path / "i.json", tmp_path / "p.json"
    r = subprocess.run([SHAFTGAUGE, "calibrate", "intrinsics", "--board", "chess:11x8x8",
                        "--output", str(intr), "--detections", str(detections), *views],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    i = json.loads(intr.read_text())
    assert i["board"] == "chess:11x8x8" and i["read"]["colour_images"] == len(views)
    assert "converted to grey" in i["read"]["conversion"]
    r = subprocess.run([SHAFTGAUGE, "calibrate", "plane", "--intrinsics", str(intr),
                        "--output", str(plane), "--laser-on-only", *on_only],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    p = json.loads(plane.read_text())
    assert p["ok"] and set(p["how"].values()) == {
        "laser on only: the red channel less the board the others show"}
    geo = geometry_of(RIG.calibration)
    angle = math.degrees(math.acos(min(1.0, abs(float(np.array(p["normal"]) @
                                                      geo.plane_normal)))))
    assert angle < 0.05 and abs(p["d"] - geo.plane_d) < 0.1, (angle, p["d"] - geo.plane_d)
    r = subprocess.run([SHAFTGAUGE, "calibrate", "plane", "--intrinsics", str(intr),
                        "--output", str(plane)], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "--laser-on-only" in r.stderr


def test_the_sessions_laser_on_slot_alone_runs_the_plane_step(tmp_path, poses) -> None:
    """The wizard's "laser on" slot filled and its "laser off" slot left empty: the session
    runs the plane step on the laser-on images alone; a slot of another count is refused."""
    _, on = poses("11x8x8")
    K, dist = RIG.config.camera_matrix(), np.array(RIG.config.dist_coeffs)
    intr = tmp_path / "i.json"
    intr.write_text(json.dumps({"step": "intrinsics", "ok": True, "board": "11x8x8",
                                "camera_matrix": K.tolist(), "dist_coeffs": dist.tolist()}))
    paths = []
    for i, im in enumerate(on):
        paths.append(str(tmp_path / f"on{i}.png"))
        cv2.imwrite(paths[-1], im)
    board = parse_board("11x8x8")
    result = run_step("plane", StepInputs(board, {"plane_off": [], "plane_on": paths},
                                          intrinsics=str(intr)))
    assert result.ok and result.figures["how"]["0"].startswith("laser on only"), result
    with pytest.raises(commands.StepError, match="laser-on images alone"):
        run_step("plane", StepInputs(board, {"plane_off": paths[:1], "plane_on": paths},
                                     intrinsics=str(intr)))
