"""`shaftgauge measure` as scripts use it: JSON lines on standard output, exit codes 0 and 2,
one line of error on standard error.

The script itself (``run``: a subprocess of the installed console script) for each way it
ends: lines for every image, a line that reports a frame without a stripe, a file it cannot
use, arguments it refuses. What each option does, through the same ``main`` in this process
(``call``): a subprocess costs 1.8 s of CPU to start (its imports and numba's kernels loaded
from their cache), and this file made forty of them."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.sim.frames import write_frames
from service.cli import main

SHAFTGAUGE = str(Path(sys.executable).with_name("shaftgauge"))
KEYS = {"image", "method", "status", "diameter_mm", "n_points", "arc_deg", "rms_residual_mm"}


def run(*args: str) -> subprocess.CompletedProcess:
    """The installed ``shaftgauge`` script in a process of its own."""
    return subprocess.run([SHAFTGAUGE, *args], capture_output=True, text=True, timeout=120)


def call(*args: str) -> subprocess.CompletedProcess:
    """The same command through the script's ``main`` in this process: its exit code (an
    argument error's ``SystemExit`` too), standard output and standard error."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> tuple[Path, list[Path]]:
    out = tmp_path_factory.mktemp("frames")
    paths = write_frames(out, [20.113, 47.062], count=1, seed=3)
    return out / "calibration.json", paths


def lines(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines()]


@pytest.mark.parametrize("method", ["ellipse", "circle", "paper", "geometric", "axis", None])
def test_measure_prints_one_json_line_per_image(frames, method) -> None:
    cal, paths = frames
    extra = ["--method", method] if method else []
    if method not in ("axis", None):  # these fits are more uncertain than the default limit
        refused = lines(call("measure", "--calibration", str(cal), *extra,
                            *map(str, paths)).stdout)
        assert all(r["status"] == "uncertain" and "uncertain by" in r["reason"]
                   for r in refused)
        extra += ["--max-uncertainty-um", "inf"]
    res = call("measure", "--calibration", str(cal), *extra, *map(str, paths))
    assert res.returncode == 0, res.stderr
    recs = lines(res.stdout)
    assert [r["image"] for r in recs] == [str(p) for p in paths]
    for rec, truth in zip(recs, [20.113, 47.062], strict=True):
        assert rec.keys() >= KEYS
        assert rec["status"] == "ok"
        assert rec["method"] == (method or "axis")
        bound = 2.0 if method == "ellipse" else 0.1
        assert abs(rec["diameter_mm"] - truth) < bound
        assert rec["n_points"] > 100 and 60 < rec["arc_deg"] < 140


def test_a_frame_without_stripe_is_reported_and_the_run_still_exits_0(frames, tmp_path) -> None:
    cal, paths = frames
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((1024, 1376), 5, np.uint8))
    res = run("measure", "--calibration", str(cal), str(blank), str(paths[0]))
    assert res.returncode == 0, res.stderr
    first, second = lines(res.stdout)
    assert first["status"] == "no_stripe" and first["diameter_mm"] is None
    assert second["status"] == "ok"


@pytest.mark.parametrize(("content", "says"), [
    ("{not json", "not JSON"),
    ('{"offset_mm": "0.1", "scale": 1}', "offset_mm must be a finite number"),
    ('{"offset_mm": 0.001}', "scale must be a finite number"),
    ('{"offset_mm": 0.001, "scale": 1.2}', "more than 1% from 1"),
    ("[1, 2]", "expected the JSON object"),
])
def test_a_bad_correction_file_is_refused_naming_what_is_wrong(frames, tmp_path, content,
                                                               says) -> None:
    cal, paths = frames
    bad = tmp_path / "master.json"
    bad.write_text(content)
    err = one_line_error(call("measure", "--calibration", str(cal), "--correction", str(bad),
                             str(paths[0])))
    assert says in err and "master.json" in err


def test_a_missing_correction_file_is_refused(frames, tmp_path) -> None:
    cal, paths = frames
    err = one_line_error(call("measure", "--calibration", str(cal), "--correction",
                             str(tmp_path / "none.json"), str(paths[0])))
    assert "none.json" in err and "cannot read" in err


def one_line_error(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 2
    assert res.stdout == ""
    err = res.stderr.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_bad_calibration_field_exits_2_naming_the_field(frames, tmp_path) -> None:
    cal, paths = frames
    doc = json.loads(cal.read_text())
    doc["light_plane"]["normal"] = [1.0, 0.1, 0.0]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    err = one_line_error(call("measure", "--calibration", str(bad), str(paths[0])))
    assert "light_plane.normal" in err and "unit vector" in err


@pytest.mark.parametrize("content", ["{not json", '{"schema": "other/9"}', ""])
def test_corrupt_calibration_exits_2(frames, tmp_path, content) -> None:
    _, paths = frames
    bad = tmp_path / "corrupt.json"
    bad.write_text(content)
    err = one_line_error(call("measure", "--calibration", str(bad), str(paths[0])))
    assert str(bad) in err


def test_missing_calibration_exits_2(frames, tmp_path) -> None:
    _, paths = frames
    err = one_line_error(run("measure", "--calibration", str(tmp_path / "x.json"),
                             str(paths[0])))
    assert "cannot read" in err


def test_non_image_file_exits_2_before_any_output(frames, tmp_path) -> None:
    cal, paths = frames
    txt = tmp_path / "notes.png"
    txt.write_text("this is not a picture")
    err = one_line_error(run("measure", "--calibration", str(cal), str(paths[0]), str(txt)))
    assert "notes.png" in err and "not an image" in err


def test_missing_image_exits_2(frames, tmp_path) -> None:
    cal, _ = frames
    err = one_line_error(call("measure", "--calibration", str(cal), str(tmp_path / "no.png")))
    assert "no such file" in err


def test_image_of_another_size_exits_2(frames, tmp_path) -> None:
    cal, _ = frames
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((480, 640), np.uint8))
    err = one_line_error(call("measure", "--calibration", str(cal), str(small)))
    assert "640x480" in err and "1376x1024" in err


@pytest.mark.parametrize("args", [["measure"], ["measure", "--calibration", "c.json"],
                                  ["measure", "--calibration", "c.json", "--method", "magic",
                                   "x.png"], ["frobnicate"]])
def test_bad_arguments_exit_2(args) -> None:
    res = run(*args)
    assert res.returncode == 2 and res.stderr and res.stdout == ""


def test_sixteen_bit_png_measures(frames, tmp_path) -> None:
    cal, paths = frames
    img = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED).astype(np.uint16) * 257
    p16 = tmp_path / "f16.png"
    cv2.imwrite(str(p16), img)
    res = call("measure", "--calibration", str(cal), str(p16))
    assert res.returncode == 0
    assert abs(lines(res.stdout)[0]["diameter_mm"] - 20.113) < 0.1


def test_render_writes_frames_and_calibration(tmp_path) -> None:
    res = run("render", "--diameter", "25", "--diameter", "30", "--count", "2",
              "--output", str(tmp_path))
    assert res.returncode == 0, res.stderr
    assert len(list(tmp_path.glob("*.png"))) == 4
    assert (tmp_path / "calibration.json").is_file()


def test_every_line_has_an_uncertainty_and_axis_is_the_default(frames) -> None:
    cal, paths = frames
    res = run("measure", "--calibration", str(cal), *map(str, paths))
    assert res.returncode == 0 and res.stderr == "", res.stderr
    recs = lines(res.stdout)
    assert [r["image"] for r in recs] == [str(p) for p in paths]
    for rec in recs:
        assert rec["status"] == "ok" and rec.keys() >= KEYS
        assert rec["method"] == "axis" and 0 < rec["uncertainty_mm"] < 0.05


def test_fuse_prints_one_line(frames, tmp_path) -> None:
    cal, _ = frames
    paths = write_frames(tmp_path, [31.473], count=5, seed=11)
    res = call("measure", "--calibration", str(cal), "--fuse", *map(str, paths))
    assert res.returncode == 0, res.stderr
    (rec,) = lines(res.stdout)
    assert rec["status"] == "ok" and rec["n_frames"] == 5 and rec["images"] == 5
    assert abs(rec["diameter_mm"] - 31.473) < 0.01 and rec["uncertainty_mm"] > 0


def test_part_temperature_adds_the_diameter_at_20c(frames) -> None:
    cal, paths = frames
    res = call("measure", "--calibration", str(cal), "--part-temp", "30", str(paths[1]))
    (rec,) = lines(res.stdout)
    assert rec["part_temp_c"] == 30
    shrink_um = (rec["diameter_mm"] - rec["diameter_20c_mm"]) * 1000
    assert shrink_um == pytest.approx(47.062 * 11.5e-6 * 10 * 1000, rel=0.01)
    bad = call("measure", "--calibration", str(cal), "--part-temp", "900", str(paths[1]))
    assert bad.returncode == 2 and "temperature" in bad.stderr


@pytest.mark.parametrize(("args", "named"), [(["--fps", "0"], "--fps"),
                                             (["--fps", "inf"], "--fps"),
                                             (["--reflection-check-hz", "-1"],
                                              "--reflection-check-hz")])
def test_a_bad_cadence_is_refused_by_name(frames, args, named) -> None:
    cal, paths = frames
    res = call("measure", "--calibration", str(cal), *args, str(paths[0]))
    assert res.returncode == 2 and named in res.stderr and not res.stdout, res.stderr


def test_every_image_checked_when_asked(frames) -> None:
    cal, paths = frames
    res = call("measure", "--calibration", str(cal), "--reflection-check-hz", "inf",
              *map(str, paths))
    assert res.returncode == 0 and all(r["status"] == "ok" for r in lines(res.stdout))


@pytest.fixture(scope="module")
def turning(tmp_path_factory) -> tuple[Path, list[Path], list[float]]:
    """Twelve frames of a 30 mm surface turned 40 um off the spindle axis, each at its angle."""
    from calib_store.model import save_calibration
    from drivers.sim.rig import RigConfig, ShaftRenderer, Turning

    out = tmp_path_factory.mktemp("turning")
    rig = ShaftRenderer(RigConfig(turning=Turning(0.04, 40.0)), seed=5)
    save_calibration(rig.calibration, out / "calibration.json")
    angles = [7.0 + 30.0 * i for i in range(12)]
    paths = []
    for i, a in enumerate(angles):
        paths.append(out / f"frame_{i:02d}.png")
        assert cv2.imwrite(str(paths[-1]), rig.render(30.0, i, spindle_deg=a))
    return out / "calibration.json", paths, angles


def test_measure_form_prints_the_run_out_and_the_roundness(turning) -> None:
    cal, paths, angles = turning
    spindle = ",".join(f"{a:g}" for a in angles)
    res = call("measure", "--calibration", str(cal), "--form", "--spindle-deg", spindle,
              *map(str, paths))
    assert res.returncode == 0, res.stderr
    (rec,) = lines(res.stdout)
    assert rec["images"] == 12 and rec["status"] == "ok"
    assert abs(rec["diameter_mm"] - 30.0) < 0.004 and rec["diameter_uncertainty_mm"] > 0
    assert abs(rec["tir_mm"] - 0.08) < 0.002 + 0.05 * 0.08
    assert rec["eccentricity_uncertainty_mm"] > 0 and rec["tir_uncertainty_mm"] > 0
    assert 0 <= rec["eccentricity_deg"] < 360
    assert rec["ront_mm"] is not None and rec["ront_uncertainty_mm"] > 0
    assert [h["order"] for h in rec["harmonics"]][:3] == [2, 3, 4]
    assert rec["harmonics"][0].keys() == {"order", "amplitude_mm", "phase_deg",
                                          "amplitude_uncertainty_mm"}
    # Without --form: each frame about the surface's own centre, one line each.
    res = call("measure", "--calibration", str(cal), "--spindle-deg", spindle,
              *map(str, paths))
    recs = lines(res.stdout)
    assert [r["image"] for r in recs] == [str(p) for p in paths]
    ok = [r for r in recs if r["status"] == "ok"]
    assert len(ok) >= 10 and all(abs(r["diameter_mm"] - 30.0) < 0.008 for r in ok)


def test_measure_form_estimates_the_turn_when_told_to(turning) -> None:
    """The same frames without their angles: the spindle's turn per frame (30 degrees) is
    told from the frames, and the record says so."""
    cal, paths, _ = turning
    res = call("measure", "--calibration", str(cal), "--form", "--spindle-deg", "estimate",
              *map(str, paths))
    assert res.returncode == 0, res.stderr
    (rec,) = lines(res.stdout)
    assert rec["spindle_angle_source"] == "estimated from the frames", rec
    assert abs(rec["spindle_deg_per_frame"] - 30.0) < 0.5, rec
    assert rec["status"] == "ok" and abs(rec["diameter_mm"] - 30.0) < 0.004
    assert abs(rec["tir_mm"] - 0.08) < 0.002 + 0.05 * 0.08


@pytest.mark.parametrize(("args", "message"), [
    (["--form"], "--form needs --spindle-deg"),
    (["--spindle-deg", "0,30"], "gives 2 angles for 12 images"),
    (["--spindle-deg", "0,north" + ",0" * 10], "angle 2 ('north') is not a number"),
    (["--spindle-deg", ",".join(["0"] * 12), "--method", "geometric"], "axis method"),
])
def test_measure_turning_bad_arguments_are_named(turning, args, message) -> None:
    cal, paths, _ = turning
    res = call("measure", "--calibration", str(cal), *args, *map(str, paths))
    assert res.returncode == 2 and message in res.stderr and not res.stdout
