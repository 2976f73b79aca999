#!/usr/bin/env bash
# The LinuxCNC demo (`make linuxcnc-demo`): the gauge on its embedded default (simulated
# camera, its tool wearing 6 um a minute) with its offsets posted for LinuxCNC (plc.source = "pull", shadow
# mode off), LinuxCNC's simulated lathe polling it with mb2hal and running the sample part
# program part after part; each part prints what the subroutine did and the tool's offset.
# The dashboard is at http://127.0.0.1:8000/ui/. Ctrl-C ends it all.
#
# The simulated camera does not see LinuxCNC's offsets: it shows the gauge's wear drift
# whatever the tool does, so the offsets add up until the cumulative limit holds them.
set -euo pipefail
cd "$(dirname "$0")/../.."
run=${SHAFTGAUGE_DEMO_DIR:-/tmp/shaftgauge-linuxcnc-demo}
mkdir -p "$run"
pids=()
stop() { kill "${pids[@]}" 2>/dev/null || true; wait 2>/dev/null || true; }
trap stop EXIT INT TERM

SHAFTGAUGE_PLC__SOURCE=pull SHAFTGAUGE_COMPENSATION__SHADOW=false SHAFTGAUGE_CAMERA__SIM_DRIFT_UM_PER_MIN=6 \
  .venv/bin/shaftgauge serve > "$run/gauge.log" 2>&1 &
pids+=($!)
for _ in $(seq 120); do
  (echo > /dev/tcp/127.0.0.1/5020) 2>/dev/null && break
  sleep 1
done
echo "demo: the gauge serves Modbus on 127.0.0.1:5020 (log: $run/gauge.log)"

deploy/linuxcnc/run-sim.sh "$run/linuxcnc" 127.0.0.1 5020 > "$run/linuxcnc.log" 2>&1 &
pids+=($!)
part=$run/linuxcnc/nc/shaftgauge_part.ngc
for _ in $(seq 60); do  # LinuxCNC answers once its task runs
  if echo '{"do": "ready"}' | HOME="$run/linuxcnc" /usr/bin/python3 deploy/linuxcnc/drive.py \
      2>/dev/null | grep -q '"ok": true'; then
    break
  fi
  sleep 1
done
echo "demo: LinuxCNC's simulated lathe is on (log: $run/linuxcnc.log); parts follow"
HOME="$run/linuxcnc" /usr/bin/python3 deploy/linuxcnc/drive.py --demo "$part"
