#!/usr/bin/python3
"""Keeps mb2hal's link to the shaftgauge: a LinuxCNC non-realtime HAL component.

mb2hal (LinuxCNC 2.9) does not reconnect once the server drops the connection (the gauge
restarted, or its network was away): its pins keep their last values and only its error count
grows. The NC subroutine then refuses to trust the gauge, so nothing wrong is applied, but no
offset would be taken again until mb2hal is loaded anew. This component does that: when
mb2hal has counted errors for ``--after`` seconds and the gauge accepts a TCP connection
again, it unloads mb2hal, loads it with the same configuration and connects its pins again
(``shaftgauge-nets.hal``). Its pin ``shaftgauge-link.reloads`` counts the reloads.

Loaded by shaftgauge.hal (``loadusr -Wn shaftgauge-link ./shaftgauge_link.py``); runs in
Debian's /usr/bin/python3, where LinuxCNC's ``hal`` module imports.
"""

import argparse
import configparser
import socket
import subprocess
import time

import hal


def gauge_address(config: str) -> tuple[str, int]:
    """The gauge's address in mb2hal's configuration (its first transaction's)."""
    ini = configparser.ConfigParser(strict=False, inline_comment_prefixes=("#",))
    ini.read(config)
    tx = ini["TRANSACTION_00"]
    return tx.get("TCP_IP", "127.0.0.1"), int(tx.get("TCP_PORT", "502"))


def reachable(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1.0):
            return True
    except OSError:
        return False


def reload_mb2hal(config: str, nets: str) -> None:
    subprocess.run(["halcmd", "unloadusr", "mb2hal"], check=False)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:  # until its pins are gone
        listed = subprocess.run(["halcmd", "list", "pin", "mb2hal"], capture_output=True,
                                text=True, check=False).stdout
        if not listed.strip():
            break
        time.sleep(0.1)
    subprocess.run(["halcmd", "loadusr", "-W", "mb2hal", f"config={config}"], check=True)
    subprocess.run(["halcmd", "-f", nets], check=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="shaftgauge-mb2hal.ini")
    ap.add_argument("--nets", default="shaftgauge-nets.hal")
    ap.add_argument("--after", type=float, default=2.0,
                    help="seconds of errors before mb2hal is loaded again")
    args = ap.parse_args()
    host, port = gauge_address(args.config)
    comp = hal.component("shaftgauge-link")
    comp.newpin("reloads", hal.HAL_U32, hal.HAL_OUT)
    comp.ready()
    last, failing_since = None, None
    try:
        while True:
            time.sleep(0.5)
            try:
                errors = hal.get_value("mb2hal.gauge.num_errors")
            except (RuntimeError, NameError):  # mb2hal is being loaded
                continue
            now = time.monotonic()
            if last is not None and errors > last:
                failing_since = failing_since if failing_since is not None else now
            else:
                failing_since = None
            last = errors
            if failing_since is not None and now - failing_since >= args.after \
                    and reachable(host, port):
                reload_mb2hal(args.config, args.nets)
                comp["reloads"] += 1
                last, failing_since = None, None
    except KeyboardInterrupt:  # LinuxCNC stops its components with SIGTERM or SIGINT
        pass


if __name__ == "__main__":
    main()
