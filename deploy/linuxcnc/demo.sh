#!/usr/bin/env bash
# The LinuxCNC demo (`make linuxcnc-demo`): the gauge on its embedded default with its offsets
# posted for LinuxCNC (plc.source = "pull", shadow mode off), LinuxCNC's simulated lathe
# polling it with mb2hal and running the sample part program part after part; each part
# prints what the subroutine did and the tool's offset. The simulated camera shows what a
# virtual lathe cuts (camera.sim_lathe): its tool wears 6 um a minute and LinuxCNC's tool
# offset, told to it after each part, moves the diameter back.
# The dashboard is at http://127.0.0.1:8000/ui/. Ctrl-C ends it all.
set -euo pipefail
cd "$(dirname "$0")/../.."
run=${SHAFTGAUGE_DEMO_DIR:-/tmp/shaftgauge-linuxcnc-demo}
mkdir -p "$run"
pids=()
# LinuxCNC runs in a session of its own: all of it ends with the demo, however it is ended.
stop() {
  [ -n "${cnc:-}" ] && kill -TERM -- "-$cnc" 2>/dev/null
  kill "${pids[@]}" 2>/dev/null || true
  wait 2>/dev/null || true
}
trap stop EXIT INT TERM

# The compensation's dead time is the demo's own, from an offset applied to a measurement that
# shows it: LinuxCNC applies it as a part starts, the part's program runs about 6 s before
# the camera's lathe is told the tool's offset, the cut reaches the laser 1.2 s later and the
# camera's ring of 8 frames shows it within 0.8 s more. Its store is its own: `make run`'s
# puts a job of two tools in force (its stepped shaft), where the demo's lathe cuts one.
SHAFTGAUGE_STORE__PATH="$run/data/gauge.db" \
  SHAFTGAUGE_PLC__SOURCE=pull SHAFTGAUGE_COMPENSATION__SHADOW=false \
  SHAFTGAUGE_CAMERA__SIM_DRIFT_UM_PER_MIN=6 SHAFTGAUGE_CAMERA__SIM_LATHE=true \
  SHAFTGAUGE_CAMERA__SIM_REPLAY_FRAMES=8 SHAFTGAUGE_COMPENSATION__DEAD_TIME_S=8.0 \
  .venv/bin/shaftgauge serve > "$run/gauge.out" 2> "$run/gauge.log" &
pids+=($!)
for _ in $(seq 120); do  # its ready line comes once the API and Modbus serve
  grep -q '"event": "ready"' "$run/gauge.out" 2>/dev/null && break
  sleep 1
done
camera_port=$(sed -n 's/.*"sim_camera_control_port": *\([0-9]*\).*/\1/p' "$run/gauge.out" | head -n 1)
echo "demo: the gauge serves Modbus on 127.0.0.1:5020 (log: $run/gauge.log)"

setsid deploy/linuxcnc/run-sim.sh "$run/linuxcnc" 127.0.0.1 5020 > "$run/linuxcnc.log" 2>&1 &
cnc=$!
part=$run/linuxcnc/nc/shaftgauge_part.ngc
for _ in $(seq 60); do  # LinuxCNC answers once its task runs
  if echo '{"do": "ready"}' | HOME="$run/linuxcnc" /usr/bin/python3 deploy/linuxcnc/drive.py \
      2>/dev/null | grep -q '"ok": true'; then
    break
  fi
  sleep 1
done
echo "demo: LinuxCNC's simulated lathe is on (log: $run/linuxcnc.log); parts follow"
# In the background and waited for: a signal to this script then ends everything at once.
HOME="$run/linuxcnc" /usr/bin/python3 deploy/linuxcnc/drive.py --demo "$part" $camera_port &
pids+=($!)
wait "$!"
