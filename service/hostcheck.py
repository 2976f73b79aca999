"""``shaftgauge check-host``: the host settings a GigE Vision camera needs, and what to change."""

from __future__ import annotations

import socket
from dataclasses import dataclass
from pathlib import Path

RMEM_WANT = 8 * 1024 * 1024
JUMBO_MTU = 9000


@dataclass(frozen=True)
class Check:
    """One host setting: its value, whether it is fine, and how to fix it."""

    name: str
    value: str
    ok: bool
    fix: str


def _read(path: str) -> str | None:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return None


def check_host(interface: str | None, want_rmem: int = RMEM_WANT,
               want_mtu: int = JUMBO_MTU) -> list[Check]:
    """Check ``net.core.rmem_max`` and the camera interface's MTU (and that it exists)."""
    checks = []
    rmem = _read("/proc/sys/net/core/rmem_max")
    value = int(rmem) if rmem and rmem.isdigit() else 0
    checks.append(Check(
        "net.core.rmem_max", str(rmem), value >= want_rmem,
        f"sudo sysctl -w net.core.rmem_max={want_rmem} && echo 'net.core.rmem_max="
        f"{want_rmem}' | sudo tee /etc/sysctl.d/60-shaftgauge.conf"))
    if interface:
        names = [n for _, n in socket.if_nameindex()]
        if interface not in names:
            checks.append(Check(f"interface {interface}", "missing", False,
                                f"no such interface; this host has {', '.join(names)}"))
        else:
            mtu = _read(f"/sys/class/net/{interface}/mtu") or "?"
            ok = mtu.isdigit() and int(mtu) >= want_mtu
            checks.append(Check(
                f"{interface} MTU", mtu, ok,
                f"sudo ip link set {interface} mtu {want_mtu} (and in the interface's "
                "configuration to keep it); or set camera.packet_size = 1400"))
    return checks
