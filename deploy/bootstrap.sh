#!/usr/bin/env bash
# Install what shaftgauge needs on Debian 12, idempotently: apt packages, then a .venv with the
# package and its test extras. Safe to run again; does nothing that is already done.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PACKAGES=(
  gir1.2-aravis-0.8 libaravis-0.8-0 aravis-tools-cli   # GigE Vision (camera and simulation)
  libgirepository1.0-dev libcairo2-dev pkg-config      # to build PyGObject from PyPI
  python3-venv python3-dev gcc                          # a venv and compiled wheels
  mbpoll                                                # independent Modbus client for tests
  faketime                                              # wall-clock jumps in the fault suite
  chromium                                              # browser tests (never downloaded)
  mosquitto mosquitto-clients                           # the plant's MQTT broker in tests
  linuxcnc-uspace                                       # a real CNC (simulated lathe, mb2hal)
  systemd                                               # systemd-analyze rates the unit
)

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "bootstrap: installing apt packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

PYTHON="${PYTHON:-python3}"
"$PYTHON" - <<'PY'
import sys
if sys.version_info < (3, 11):
    sys.exit(f"bootstrap: Python >= 3.11 is needed, {sys.executable} is {sys.version.split()[0]}")
PY

stamp=.venv/.shaftgauge-installed
if [ ! -x .venv/bin/python ]; then
  echo "bootstrap: creating .venv with $PYTHON"
  "$PYTHON" -m venv .venv
fi
lock=deploy/requirements-test.lock
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ "$lock" -nt "$stamp" ]; then
  # The exact versions (and hashes) of the lock, then the package itself over them: every
  # install is the same ("make lock" renews the lock).
  echo "bootstrap: installing shaftgauge and its test tools into .venv from $lock"
  # --no-compile: Python compiles what is imported when it is first imported; compiling
  # every module of every package at install took half of the install's 33 s.
  .venv/bin/python -m pip install -q --no-compile --require-hashes -r "$lock"
  .venv/bin/python -m pip install -q --no-compile --no-deps -e .
  touch "$stamp"
fi
