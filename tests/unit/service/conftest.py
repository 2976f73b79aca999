"""A gauge on the simulated rig camera (no network), behind the real FastAPI app."""

from __future__ import annotations

import time

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.config import Settings
from service.serve import Children, build

KEYS = {"o" * 16 + "-operator": "operator", "t" * 16 + "-technician": "technician",
        "a" * 16 + "-admin": "admin"}
OPERATOR, TECHNICIAN, ADMIN = list(KEYS)


def make_settings(tmp_path, **sections) -> Settings:
    base = {
        "camera": {"source": "rig", "sim_diameter_mm": 30.0, "frame_rate_hz": 20.0},
        "plc": {"source": "none"},
        "modbus": {"port": 0},
        "api": {"keys": KEYS},
        "store": {"path": str(tmp_path / "data" / "gauge.db")},
        "compensation": {"nominal_mm": 30.0},
        # In-process tests measure in threads: a spawned worker takes seconds to start.
        "measurement": {"processes": False},
    }
    for k, v in sections.items():
        base[k] = {**base.get(k, {}), **v}
    return Settings(**base)


@pytest.fixture
def client(tmp_path):
    gauge, _ = build(make_settings(tmp_path), Children())
    with TestClient(create_app(gauge)) as c:
        c.gauge = gauge
        deadline = time.monotonic() + 20
        while gauge.feed.latest is None and time.monotonic() < deadline:
            time.sleep(0.05)
        yield c
