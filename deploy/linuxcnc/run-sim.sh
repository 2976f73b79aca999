#!/usr/bin/env bash
# Start LinuxCNC's simulated lathe headless with the shaftgauge link, in RUN_DIR (made if
# missing; its tool table is kept across starts, as a machine's is):
#
#     deploy/linuxcnc/run-sim.sh RUN_DIR [GAUGE_HOST [GAUGE_PORT]]
#
# Needs Debian's linuxcnc-uspace (deploy/bootstrap.sh installs it). LinuxCNC's realtime part
# refuses to run as root without a user to fall back to: as root this runs it as the system
# user shaftgauge-cnc (made if missing). One LinuxCNC per machine.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
run=${1:?usage: run-sim.sh RUN_DIR [GAUGE_HOST [GAUGE_PORT]]}
host=${2:-127.0.0.1}
port=${3:-5020}
mkdir -p "$run/nc"
run=$(cd "$run" && pwd)
cp "$here/sim/shaftgauge-sim.ini" "$here/sim/headless-display" "$here/sim/toplevel.py" \
   "$here/sim/remap.py" "$here/shaftgauge.hal" "$here/shaftgauge-nets.hal" \
   "$here/shaftgauge_link.py" "$run/"
cp "$here"/nc/*.ngc "$run/nc/"
[ -f "$run/lathe.tbl" ] || cp "$here/sim/lathe.tbl" "$run/"
sed -e "s/^TCP_IP=.*/TCP_IP=$host/" -e "s/^TCP_PORT=.*/TCP_PORT=$port/" \
    "$here/shaftgauge-mb2hal.ini" > "$run/shaftgauge-mb2hal.ini"
# The realtime part's socket, where its user can reach it (RUN_DIR may lie below a folder
# only root can enter); one place, as one LinuxCNC runs on a machine.
fifo_dir=/tmp/shaftgauge-rtapi
mkdir -p "$fifo_dir"
if [ "$(id -u)" -eq 0 ]; then
  id -u shaftgauge-cnc >/dev/null 2>&1 || \
    useradd --system --no-create-home --shell /usr/sbin/nologin shaftgauge-cnc
  export RTAPI_UID
  RTAPI_UID=$(id -u shaftgauge-cnc)
  chown -R shaftgauge-cnc "$run" "$fifo_dir"
fi
export RTAPI_FIFO_PATH="$fifo_dir/rtapi_fifo"
export HOME="$run"   # LinuxCNC shares its tool table through $HOME/.tool.mmap
export RUNTESTS=1    # its output on stdout, not in a terminal window
cd "$run"
exec linuxcnc shaftgauge-sim.ini
