"""The light plane's own verdict: a plane its points contradict is refused with the figure,
never answered good (a green line found beside the pattern gave points 32 mm RMS from their
plane, answered ``"ok": true``); the poses it rests on and the rest said."""

from __future__ import annotations

import numpy as np

from service.calibrate.intrinsics import IntrinsicsResult
from service.calibrate.plane import MAX_PLANE_RMS_MM, plane_of_poses
from service.calibrate.report import assess

NORMAL = np.array([0.0, -0.6, 0.8])  # the sheet, tilted toward the camera
D = 240.0


def pose_line(rng: np.random.Generator, tilt: float, off_mm: float = 0.0,
              noise_mm: float = 0.02) -> np.ndarray:
    """60 points where the sheet meets a board tilted by ``tilt`` (a line in the plane),
    ``off_mm`` off it, with measuring noise."""
    u = np.cross(NORMAL, [np.cos(tilt), np.sin(tilt), 0.0])
    u /= np.linalg.norm(u)
    base = NORMAL * D + np.cross(NORMAL, u) * 20.0 * tilt
    s = np.linspace(-40.0, 40.0, 60)
    return base + s[:, None] * u + NORMAL * (off_mm + rng.normal(0.0, noise_mm, (60, 1)))


def test_points_on_one_plane_give_it_with_their_residual() -> None:
    rng = np.random.default_rng(1)
    pts = [pose_line(rng, t) for t in (0.0, 0.5, 1.0, 1.5)]
    res = plane_of_poses(pts, [60] * 4, {4: "board not found"}, {}, 3)
    assert res and abs(abs(float(res.normal @ NORMAL)) - 1.0) < 1e-5
    assert res.rms_mm < 0.05 and res.per_pose_points == [60] * 4


def test_a_plane_its_own_points_contradict_is_refused_with_the_figure() -> None:
    rng = np.random.default_rng(2)
    pts = [pose_line(rng, 0.0), pose_line(rng, 0.5), pose_line(rng, 1.0, off_mm=40.0),
           pose_line(rng, 1.5, off_mm=-25.0)]  # two poses' lines on something else
    res = plane_of_poses(pts, [60] * 4, {}, {}, 3)
    assert not res and res.normal is None
    assert res.rms_mm > MAX_PLANE_RMS_MM
    assert f"{res.rms_mm:.1f} mm RMS" in res.reason and "do not lie on one plane" in \
        res.reason
    report = assess(IntrinsicsResult(np.eye(3), np.zeros(5), 0.2, [0.2] * 12, 0.5, 0.6, 30.0,
                                     list(range(12))), res)
    assert report.verdict == "refused"
    figures = report.figures["light_plane"]
    assert figures["poses_used"] == 4 and figures["rms_mm"] == res.rms_mm
    assert any("do not lie on one plane" in r for r in report.reasons)


def test_the_report_says_what_became_of_the_poses_left_out() -> None:
    rng = np.random.default_rng(3)
    res = plane_of_poses([pose_line(rng, t) for t in (0.0, 0.7, 1.4)], [60] * 3,
                         {1: "laser line missing or too short (4 points)"}, {}, 3)
    figures = assess(IntrinsicsResult(np.eye(3), np.zeros(5), 0.2, [0.2] * 12, 0.5, 0.6,
                                      30.0, list(range(12))), res).figures["light_plane"]
    assert figures["poses_used"] == 3
    assert figures["rejected"] == {"1": "laser line missing or too short (4 points)"}


def test_the_planes_uncertainty_grows_with_its_poses_scatter_and_covers_the_truth() -> None:
    got = {}
    for noise_mm in (0.02, 0.2):
        rng = np.random.default_rng(4)
        pts = [pose_line(rng, t, noise_mm=noise_mm) for t in (0.0, 0.4, 0.8, 1.2, 1.6)]
        res = plane_of_poses(pts, [60] * 5, {}, {}, 3)
        assert res, res.reason
        err_deg = np.degrees(np.arccos(min(1.0, abs(float(res.normal @ NORMAL)))))
        assert err_deg < 3.0 * res.normal_u_deg, (err_deg, res.normal_u_deg)
        got[noise_mm] = (res.normal_u_deg, res.axis_u_mm)
    ratio = got[0.2][0] / got[0.02][0]
    assert 4.0 < ratio < 25.0, got  # about tenfold: the scatter's
    assert got[0.02][1] < 0.1 and got[0.2][1] > got[0.02][1], got
