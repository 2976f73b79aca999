"""The HTTP edge: bodies bounded before they are read or the key is checked, PNG headers
checked before decoding, caps on calibration sessions, images and live streams, and the
runtime settings that survive a restart."""

from __future__ import annotations

import re
import struct
import time
import zlib

import cv2
import numpy as np
import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.image_body import JPEG_SOI, image_size, jpeg_size
from service.api.limits import PNG_SIGNATURE, png_size
from service.serve import Children, build
from tests.unit.service.conftest import TECHNICIAN, make_settings

H = "X-API-Key"


def png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` and carries almost nothing."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return (PNG_SIGNATURE + struct.pack(">I", len(ihdr)) + chunk
            + struct.pack(">I", zlib.crc32(chunk)) + b"\0" * 64)


def latest_seq(c: TestClient, timeout_s: float = 20.0) -> int:
    """The latest measurement's sequence number, once there is one."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        r = c.get("/api/v1/measurements/latest")
        if r.status_code == 200:
            return r.json()["seq"]
        time.sleep(0.05)
    raise AssertionError("no measurement")


def test_png_size_reads_the_header_only() -> None:
    assert png_size(png_header(1376, 1024)) == (1376, 1024)
    ok, enc = cv2.imencode(".png", np.zeros((7, 11), np.uint8))
    assert ok and png_size(enc.tobytes()) == (11, 7)


def test_a_declared_oversized_body_is_refused_before_the_key(client) -> None:
    big = {"content-length": str(5 << 30), "content-type": "application/json"}
    for path in ("/api/v1/feature", "/api/v1/compensation/shadow"):
        r = client.put(path, headers=big, content=b"{}")  # no key at all
        assert r.status_code == 413, (path, r.status_code, r.text)
        assert "larger than" in r.json()["detail"]


def test_a_streamed_body_is_cut_off_at_the_limit(client) -> None:
    sent = 0

    def chunks():
        nonlocal sent
        for _ in range(64):  # 64 MiB offered, chunked, no Content-Length
            sent += 1 << 20
            yield b" " * (1 << 20)

    r = client.put("/api/v1/feature", content=chunks(), headers={H: TECHNICIAN})
    assert r.status_code == 413, r.text
    assert client.get("/healthz").status_code == 200


def test_uploads_are_checked_before_decoding(client) -> None:
    sid = client.post("/api/v1/calibration-sessions", headers={H: TECHNICIAN},
                      json={}).json()["id"]
    url = f"/api/v1/calibration-sessions/{sid}/images/view"
    r = client.post(url, headers={H: TECHNICIAN}, content=b"GIF89a" + b"\0" * 100)
    assert r.status_code == 415 and "PNG nor a JPEG" in r.json()["detail"]
    r = client.post(url, headers={H: TECHNICIAN}, content=png_header(100_000, 100_000))
    assert r.status_code == 422 and "100000x100000" in r.json()["detail"], r.text
    r = client.post(url, headers={H: TECHNICIAN}, content=png_header(640, 480))
    assert r.status_code == 422 and "1376x1024" in r.json()["detail"], r.text
    r = client.post(url, headers={H: TECHNICIAN}, content=png_header(1376, 1024))
    assert r.status_code == 422 and "decoded" in r.json()["detail"]  # header fine, data not
    big = {H: TECHNICIAN, "content-length": str(33 << 20)}
    assert client.post(url, headers=big, content=b"x").status_code == 413
    assert client.get(f"/api/v1/calibration-sessions/{sid}").json()["images"]["view"] == 0


def test_jpeg_size_reads_the_header_only() -> None:
    ok, enc = cv2.imencode(".jpg", np.zeros((7, 11, 3), np.uint8))
    assert ok and jpeg_size(enc.tobytes()) == (11, 7)
    assert image_size(enc.tobytes()) == (11, 7)
    with pytest.raises(HTTPException) as err:
        jpeg_size(JPEG_SOI + b"\xff\xe0\x00\x10" + b"\0" * 14 + b"\xff\xda\x00\x02")
    assert err.value.status_code == 422 and "no frame header" in err.value.detail


def test_a_progressive_jpeg_of_too_many_scans_is_refused_before_it_is_decoded() -> None:
    """The second outside probe's "scan bomb": a header of 1376x1024, scans of 12 bytes each,
    49 s to decode. An ordinary progressive JPEG is taken; one of hundreds of scans is not."""
    image = np.random.default_rng(1).integers(0, 255, (1024, 1376), np.uint8)
    ok, enc = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    data = enc.tobytes()
    assert ok and 2 <= data.count(b"\xff\xda") <= 12
    assert image_size(data) == (1376, 1024)
    last = data.rindex(b"\xff\xda")
    bomb = data[:-2] + data[last:-2] * 500 + data[-2:]  # its last scan again and again
    with pytest.raises(HTTPException) as err:
        image_size(bomb)
    assert err.value.status_code == 422 and "scans" in err.value.detail


def test_a_colour_jpeg_upload_is_kept_in_colour(client) -> None:
    """A phone's photograph: JPEG, colour; its declared size checked before decoding, the
    colour kept for the steps (a red laser line is found by its colour)."""
    sid = client.post("/api/v1/calibration-sessions", headers={H: TECHNICIAN},
                      json={}).json()["id"]
    url = f"/api/v1/calibration-sessions/{sid}/images/plane_on"
    _, small = cv2.imencode(".jpg", np.zeros((480, 640, 3), np.uint8))
    r = client.post(url, headers={H: TECHNICIAN, "content-type": "image/jpeg"},
                    content=small.tobytes())
    assert r.status_code == 422 and "640x480" in r.json()["detail"], r.text
    image = np.zeros((1024, 1376, 3), np.uint8)
    image[500:504, :, 2] = 250  # a red line
    _, enc = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    r = client.post(url, headers={H: TECHNICIAN, "content-type": "image/jpeg"},
                    content=enc.tobytes())
    assert r.status_code == 201, r.text
    stored = client.gauge.sessions.get(sid).images["plane_on"][0]
    kept = cv2.imread(stored, cv2.IMREAD_UNCHANGED)
    assert kept.shape == (1024, 1376, 3) and kept[502, 700, 2] > 200 > kept[502, 700, 1]


def test_sessions_and_images_are_capped(tmp_path) -> None:
    s = make_settings(tmp_path, api={"max_calibration_sessions": 2, "max_session_images": 2})
    gauge, _ = build(s, Children())
    _, enc = cv2.imencode(".png", np.zeros((1024, 1376), np.uint8))
    with TestClient(create_app(gauge)) as c:
        sids = [c.post("/api/v1/calibration-sessions", headers={H: TECHNICIAN},
                       json={}).json()["id"] for _ in range(2)]
        r = c.post("/api/v1/calibration-sessions", headers={H: TECHNICIAN}, json={})
        assert r.status_code == 409 and "max_calibration_sessions" in r.json()["detail"]
        url = f"/api/v1/calibration-sessions/{sids[0]}/images/view"
        for _ in range(2):
            assert c.post(url, headers={H: TECHNICIAN}, content=enc.tobytes()
                          ).status_code == 201
        r = c.post(url, headers={H: TECHNICIAN}, content=enc.tobytes())
        assert r.status_code == 409 and "max_session_images" in r.json()["detail"]


def test_sessions_expire_with_their_images(tmp_path) -> None:
    s = make_settings(tmp_path, api={"max_calibration_sessions": 1,
                                     "session_expiry_h": 1e-4})  # 0.36 s
    gauge, _ = build(s, Children())
    with TestClient(create_app(gauge)) as c:
        sid = c.post("/api/v1/calibration-sessions", headers={H: TECHNICIAN},
                     json={}).json()["id"]
        folder = tmp_path / "data" / "calibration-sessions" / sid
        assert folder.is_dir()
        time.sleep(0.5)
        r = c.post("/api/v1/calibration-sessions", headers={H: TECHNICIAN}, json={})
        assert r.status_code == 201  # the expired one made room
        assert not folder.exists()
        assert c.get(f"/api/v1/calibration-sessions/{sid}").status_code == 404


def test_live_streams_are_capped(tmp_path) -> None:
    gauge, _ = build(make_settings(tmp_path, api={"max_streams": 1}), Children())
    with TestClient(create_app(gauge)) as c, c.stream("GET", "/api/v1/stream") as first:
        assert first.status_code == 200
        second = c.get("/api/v1/stream")
        assert second.status_code == 503 and "max_streams" in second.json()["detail"]


def test_runtime_settings_survive_a_restart_and_are_audited(tmp_path) -> None:
    s = make_settings(tmp_path)
    gauge, _ = build(s, Children())
    with TestClient(create_app(gauge)) as c:
        assert c.put("/api/v1/compensation/shadow", headers={H: TECHNICIAN},
                     json={"shadow": True}).status_code == 200
        assert c.put("/api/v1/feature", headers={H: TECHNICIAN}, json={
            "nominal_mm": 25.0, "tol_upper_mm": 0.01, "tol_lower_mm": -0.01}).status_code == 200
        assert c.put("/api/v1/temperature", headers={H: TECHNICIAN},
                     json={"part_temp_c": 31.5}).status_code == 200
        seq_before = latest_seq(c)
        log = c.get("/api/v1/compensation/log", params={"kinds": "settings"}).json()["items"]
        assert len(log) == 3 and all(
            re.fullmatch(r"api:technician \(key api\.keys#\d, testclient\)", r["who"])
            for r in log)
        assert "nominal_mm=25.0" in log[1]["reason"]
    again, _ = build(s, Children())  # a power cycle: same config file, same store
    with TestClient(create_app(again)) as c:
        comp = c.get("/api/v1/compensation").json()
        assert comp["settings"]["shadow"] is True and comp["settings"]["nominal_mm"] == 25.0
        assert c.get("/api/v1/temperature").json()["part_temp_c"] == 31.5
        assert latest_seq(c) > seq_before  # the sequence goes on, never back
    # An edited config file wins over the changes made at run time (and says so in the log).
    edited = make_settings(tmp_path, compensation={"nominal_mm": 40.0})
    third, _ = build(edited, Children())
    with TestClient(create_app(third)) as c:
        comp = c.get("/api/v1/compensation").json()
        assert comp["settings"]["nominal_mm"] == 40.0 and comp["settings"]["shadow"] is True


def test_an_unknown_kind_in_the_log_query_is_a_422(client) -> None:
    r = client.get("/api/v1/compensation/log", params={"kinds": "write,banana"})
    assert r.status_code == 422 and "banana" in r.json()["detail"]


def test_host_names_served_are_addresses_this_machine_and_the_trusted() -> None:
    import socket

    from service.api.edge import SecurityHeaders

    edge = SecurityHeaders(None, trusted_hosts=["gauge-7.plant.example"])
    for ok in ("127.0.0.1", "10.1.2.3", "[::1]", "localhost", "gauge-7.plant.example",
               socket.gethostname().lower()):
        assert edge.allowed(ok), ok
    for bad in ("evil.example", "", "127.0.0.1.evil.example", "gauge-7.plant.example.evil"):
        assert not edge.allowed(bad), bad


def test_wrong_keys_are_counted_per_address_in_a_sliding_window() -> None:
    from service.api.attempts import KeyAttempts

    a = KeyAttempts(max_failures=3, window_s=10.0)
    for t in (0.0, 1.0, 2.0):
        assert a.retry_after("10.0.0.9", t) == 0.0
        a.failed("10.0.0.9", t)
    assert a.retry_after("10.0.0.9", 2.5) == pytest.approx(7.5)
    assert a.retry_after("10.0.0.8", 2.5) == 0.0  # another address is not held
    assert a.retry_after("10.0.0.9", 10.5) == 0.0  # the first has aged out
    assert a.refused == 3


def test_twenty_wrong_keys_in_a_row_get_429_and_the_log_names_the_address(tmp_path,
                                                                          caplog) -> None:
    from service.api.attempts import MAX_FAILURES

    settings = make_settings(tmp_path)
    gauge, _ = build(settings, Children())
    with TestClient(create_app(gauge)) as c:
        wrong = "not-the-key-0123456789"
        for _ in range(MAX_FAILURES):
            r = c.put("/api/v1/compensation/shadow", json={"shadow": True}, headers={H: wrong})
            assert r.status_code == 401
        r = c.put("/api/v1/compensation/shadow", json={"shadow": True},
                  headers={H: TECHNICIAN})
        assert r.status_code == 429, r.text
        assert int(r.headers["Retry-After"]) > 0 and "testclient" in r.json()["detail"]
        assert c.get("/api/v1/status").json()["api"]["wrong_keys"] == MAX_FAILURES
        assert f"shaftgauge_api_wrong_keys_total {MAX_FAILURES:.1f}" in c.get("/metrics").text
    lines = [rec.getMessage() for rec in caplog.records if rec.name == "shaftgauge.api"]
    assert len(lines) == MAX_FAILURES and all("testclient" in line for line in lines)
    assert not any(wrong in line for line in lines)
