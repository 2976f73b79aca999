"""Drives a running LinuxCNC (the tests, the demo): one JSON command a line on stdin, one JSON
answer a line on stdout. Runs in Debian's /usr/bin/python3 (the only interpreter its
``linuxcnc`` and ``hal`` modules import in), with LinuxCNC's HOME (its tool table is shared
through $HOME/.tool.mmap).

``drive.py --demo PROGRAM [CAMERA_PORT]`` runs PROGRAM part after part, a line each (the demo);
with the simulated camera's control port it tells the camera's virtual lathe the tool's offset
after each part (what the lathe cuts follows LinuxCNC's tool table).

Commands: {"do": "ready"} (estop reset, machine on, homed, MDI mode, tool 1 loaded with G43);
{"do": "mdi", "lines": [...]}; {"do": "run", "path": ...} (a program, to its end);
{"do": "call", "tool": 1, "entry": 0} (the shipped subroutine, answering
its #<_value>); {"do": "tool", "number": 1} (a tool-table entry's X offset);
{"do": "pin", "name": ...}.
"""

import json
import socket
import sys
import time

import hal
import linuxcnc

stat, command = linuxcnc.stat(), linuxcnc.command()
_component = hal.component("shaftgauge-test-driver")  # hal.get_value needs one
_component.ready()


def wait_until(check, timeout_s=10.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        stat.poll()
        if check():
            return True
        time.sleep(0.02)
    return False


def mdi(line, timeout_s=30.0):
    command.mode(linuxcnc.MODE_MDI)
    command.wait_complete()
    command.mdi(line)
    done = command.wait_complete(timeout_s)
    stat.poll()
    if done == -1 or stat.interp_state != linuxcnc.INTERP_IDLE:
        wait_until(lambda: stat.interp_state == linuxcnc.INTERP_IDLE, timeout_s)
    return done


def errors():
    out = []
    channel = linuxcnc.error_channel()
    while (e := channel.poll()) is not None:
        out.append(e[1])
    return out


def handle(req):
    what = req["do"]
    if what == "ready":
        command.state(linuxcnc.STATE_ESTOP_RESET)
        command.state(linuxcnc.STATE_ON)
        if not wait_until(lambda: stat.task_state == linuxcnc.STATE_ON):
            return {"ok": False, "error": "machine did not turn on"}
        command.home(-1)
        if not wait_until(lambda: all(stat.homed[:2])):
            return {"ok": False, "error": "not homed"}
        for line in ("T1 M6", "G43"):
            mdi(line)
        return {"ok": True, "errors": errors()}
    if what == "mdi":
        return {"ok": True, "done": [mdi(line) for line in req["lines"]], "errors": errors()}
    if what == "call":
        mdi(f"o<shaftgauge_comp> call [{req.get('tool', 1)}] [{req.get('entry', 0)}]")
        mdi("M68 E9 Q#<_value>")  # E0-E7 carry the report
        time.sleep(0.05)
        return {"ok": True, "value": hal.get_value("motion.analog-out-09"), "errors": errors()}
    if what == "run":  # a program to its end
        command.mode(linuxcnc.MODE_AUTO)
        command.wait_complete()
        command.program_open(req["path"])
        command.auto(linuxcnc.AUTO_RUN, 0)
        time.sleep(0.2)
        done = wait_until(lambda: stat.interp_state == linuxcnc.INTERP_IDLE,
                          req.get("timeout_s", 60.0))
        return {"ok": done, "errors": errors()}
    if what == "tool":
        stat.poll()
        entry = next(t for t in stat.tool_table if t.id == req.get("number", 1))
        return {"ok": True, "x": entry.xoffset}
    if what == "pin":
        return {"ok": True, "value": hal.get_value(req["name"])}
    return {"ok": False, "error": f"unknown command {what!r}"}


SAID = {1: "offset applied", 2: "offset refused (the tool's offset changed meanwhile)",
        0: "nothing to do", -1: "the gauge is not trusted now", -2: "T1 is not in the spindle"}


def tell_lathe(port, total_mm):
    """The simulated camera's virtual lathe: the CNC's total wear offset, mm of diameter."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall((json.dumps({"set": {"cnc_total_mm": total_mm}}) + "\n").encode())
        reply = json.loads(sock.makefile().readline())
    if not reply.get("ok"):
        print(f"the simulated camera did not take the offset: {reply.get('error')}",
              flush=True)


def demo(program, camera_port=None):
    """Part after part: the subroutine (as the program would call it), the program, a line;
    the tool's offset (a radius: twice on the diameter) to the camera's lathe."""
    handle({"do": "ready"})
    x0 = handle({"do": "tool", "number": 1})["x"]
    part = 0
    while True:
        part += 1
        value = round(handle({"do": "call", "tool": 1})["value"])
        done = handle({"do": "run", "path": program})
        x = handle({"do": "tool", "number": 1})["x"]
        if camera_port:
            tell_lathe(camera_port, 2.0 * (x - x0))
        print(f"part {part}: {SAID.get(value, value)}; T1's X offset {x * 1000:+.4f} um "
              f"(radius){'' if done['ok'] else '; the program did not finish'}", flush=True)
        time.sleep(1.0)


try:
    if len(sys.argv) in (3, 4) and sys.argv[1] == "--demo":
        demo(sys.argv[2], int(sys.argv[3]) if len(sys.argv) == 4 else None)
    for raw in sys.stdin:
        try:
            answer = handle(json.loads(raw))
        except Exception as err:  # the test reads the error; the driver goes on
            answer = {"ok": False, "error": f"{type(err).__name__}: {err}"}
        print(json.dumps(answer), flush=True)
except KeyboardInterrupt:
    pass
