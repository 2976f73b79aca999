"""deploy/: the example config validates, the host check says what to change."""

from __future__ import annotations

from pathlib import Path

from service import hostcheck
from service.config import load_settings

DEPLOY = Path(__file__).resolve().parents[3] / "deploy"


def test_example_config_validates() -> None:
    s = load_settings(DEPLOY / "shaftgauge.example.toml")
    assert s.camera.source == "gige" and s.modbus.port == 502 and s.compensation.shadow


def test_systemd_unit_runs_unprivileged_and_restarts() -> None:
    unit = (DEPLOY / "shaftgauge.service").read_text()
    assert "User=shaftgauge" in unit and "Restart=on-failure" in unit
    assert "--config /etc/shaftgauge/shaftgauge.toml" in unit


def test_host_check(monkeypatch) -> None:
    values = {"/proc/sys/net/core/rmem_max": "212992", "/sys/class/net/lo/mtu": "1500"}
    monkeypatch.setattr(hostcheck, "_read", lambda p: values.get(p))
    checks = {c.name: c for c in hostcheck.check_host("lo")}
    assert not checks["net.core.rmem_max"].ok and "sysctl" in checks["net.core.rmem_max"].fix
    assert not checks["lo MTU"].ok and "mtu 9000" in checks["lo MTU"].fix
    values.update({"/proc/sys/net/core/rmem_max": "16777216", "/sys/class/net/lo/mtu": "9000"})
    assert all(c.ok for c in hostcheck.check_host("lo"))
    missing = hostcheck.check_host("nonexistent0")
    assert any(c.name == "interface nonexistent0" and not c.ok for c in missing)
