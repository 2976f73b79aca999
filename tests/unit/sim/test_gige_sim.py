"""The simulated GigE camera's pieces that need no network: stamps, drift, control requests."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.sim.control import apply_request
from drivers.sim.gige import SimCameraSettings, SimGigECamera, check_stamp, stamp_frame


def test_stamp_round_trip_and_detects_damage() -> None:
    img = np.random.default_rng(0).integers(0, 255, (64, 80)).astype(np.uint8)
    stamp_frame(img, 12345)
    assert check_stamp(img) == (12345, True)
    img[40, 3] ^= 0xFF  # one corrupted byte, as a lost packet would leave
    assert check_stamp(img) == (12345, False)


def test_wear_drift_moves_the_diameter() -> None:
    cam = SimGigECamera(SimCameraSettings(diameter_mm=30.0, drift_um_per_min=60_000.0))
    time.sleep(0.2)
    # 60 mm per minute = 1 mm/s: about 0.2 mm after 0.2 s
    assert 30.15 < cam.current_diameter() < 30.5
    cam.set_diameter(20.0, drift_um_per_min=0.0)
    assert cam.current_diameter() == pytest.approx(20.0)


def test_control_requests() -> None:
    cam = SimGigECamera(SimCameraSettings(diameter_mm=30.0))
    ok = apply_request(cam, {"set": {"diameter_mm": 22.5, "lost_ratio": 0.01, "fps": 5}})
    assert ok["ok"] and ok["stats"]["diameter_mm"] == pytest.approx(22.5)
    assert ok["stats"]["lost_ratio"] == 0.01 and ok["stats"]["fps"] == 5
    for bad, words in [({"set": {"lost_ratio": 2}}, "within"), ({"set": {"fps": 0}}, "fps"),
                       ({"set": {"zoom": 1}}, "unknown"), ({"set": {}}, "object"),
                       ({"do": "x"}, "use"), ([1], "object"),
                       ({"set": {"diameter_mm": "wide"}}, "could not convert")]:
        reply = apply_request(cam, bad)
        assert not reply["ok"] and words in reply["error"], (bad, reply)


def test_shows_a_calibration_board_instead_of_the_shaft() -> None:
    from drivers.sim.board_shots import Board
    from service.calibrate.intrinsics import find_corners

    cam = SimGigECamera(SimCameraSettings(diameter_mm=30.0))
    assert apply_request(cam, {"get": "shots"})["shots"][:2] == ["view_00", "view_02"]
    reply = apply_request(cam, {"show": {"shot": "view_04"}})
    assert reply["ok"] and reply["stats"]["scene"] == "view_04"
    image = cam._render_next()
    assert check_stamp(image)[1]
    assert find_corners(image, Board(11, 8, 8.0)).points is not None
    reply = apply_request(cam, {"show": {"rotation_deg": 20, "board": "9x6x10"}})
    assert reply["ok"] and reply["stats"]["scene"] == "custom"
    assert find_corners(cam._render_next(), Board(9, 6, 10.0)).points is not None
    assert apply_request(cam, {"show": "shaft"})["stats"]["scene"] == "shaft"
    assert find_corners(cam._render_next(), Board(11, 8, 8.0)).points is None
    for bad, words in [({"show": {"shot": "nope"}}, "no shot"), ({"show": 3}, "shaft"),
                       ({"show": {"zoom": 2}}, "unknown board fields"),
                       ({"show": {"board": "big"}}, "COLSxROWSxMM"),
                       ({"show": {"shot": "view_00", "laser": True}}, "no other fields")]:
        reply = apply_request(cam, bad)
        assert not reply["ok"] and words in reply["error"], (bad, reply)


def test_disturbances_are_set_live_and_named_when_wrong() -> None:
    cam = SimGigECamera(SimCameraSettings(diameter_mm=30.0, seed=3))
    clean = cam._render_next()
    reply = apply_request(cam, {"set": {"disturbances": {"glints": {"count": 12}}}})
    assert reply["ok"] and reply["stats"]["disturbances"] is True
    glinted = cam._render_next()
    assert (glinted == 255).sum() > (clean == 255).sum()
    assert apply_request(cam, {"set": {"disturbances": {}}})["stats"]["disturbances"] is False
    for bad, words in [({"set": {"disturbances": {"smoke": {}}}}, "unknown disturbance"),
                       ({"set": {"disturbances": {"glints": {"colour": 1}}}}, "unknown glints"),
                       ({"set": {"disturbances": 3}}, "takes an object")]:
        reply = apply_request(cam, bad)
        assert not reply["ok"] and words in reply["error"], (bad, reply)
