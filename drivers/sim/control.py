"""A JSON-lines control port for a running simulated camera (loopback only).

Requests, one JSON object per line: ``{"set": {"diameter_mm": 30.0, "drift_um_per_min": 5,
"lost_ratio": 0.001, "fps": 10}}``, ``{"set": {"disturbances": {"ghost": {"gain": 0.3}}}}``
(the shop floor's disturbances, ``drivers.sim.disturb``; ``{}`` for none),
``{"set": {"turning": {"eccentricity_mm": 0.05, "spindle_deg_per_frame": 37}}}`` (a surface
off the spindle axis, ``lobes`` for one out of round: ``drivers.sim.rig.Turning``),
``{"set": {"cnc_total_mm": -0.004}}`` (a camera with a virtual lathe: the CNC's total wear
offset, which the lathe's cut follows), ``{"do": "new_insert"}`` (its tool gets a new
insert now), ``{"do": "advance_lathe", "s": 0.5}`` (the lathe's time driven: half a second
on from where it is, and no longer on the wall clock),
``{"get": "stats"}``, or ``{"show": ...}`` for what the camera looks at: ``"shaft"``, a shot
of the simulated calibration session by name (``{"show": {"shot": "view_00"}}``;
``{"get": "shots"}`` lists them), or a board set up by hand
(``{"show": {"tilt_x_deg": 20, "distance_mm": 380, "laser": true}}``, or ``"rotation_deg"`` for
the board between the centres), with ``"board": "11x8x8"`` optional. Every reply is one line:
``{"ok": true, "stats": {...}}`` or ``{"ok": false, "error": "..."}``.
"""

from __future__ import annotations

import json
import socket
import socketserver
import threading
from typing import Any

from drivers.sim.board_shots import Board, Shot, session_shots
from drivers.sim.disturb import Disturbances
from drivers.sim.gige import SimGigECamera
from drivers.sim.rig import Turning

_SETTERS = ("diameter_mm", "drift_um_per_min", "lost_ratio", "fps", "cnc_total_mm")
_SHOT_FIELDS = ("tilt_x_deg", "tilt_y_deg", "distance_mm", "shift_mm", "rotation_deg", "laser")


def parse_show(spec: Any) -> tuple[Shot | None, Board | None]:
    """A ``show`` request's board shot (None for the shaft); ValueError names what is wrong."""
    if spec == "shaft":
        return None, None
    if not isinstance(spec, dict):
        raise ValueError("'show' takes \"shaft\" or an object")
    spec = dict(spec)
    board = None
    if "board" in spec:
        try:
            cols, rows, sq = str(spec.pop("board")).split("x")
            board = Board(int(cols), int(rows), float(sq))
        except ValueError:
            raise ValueError("board: write COLSxROWSxMM, e.g. 11x8x8") from None
    if "shot" in spec:
        named = {s.name: s for s in session_shots()}
        name = spec.pop("shot")
        if name not in named:
            raise ValueError(f"no shot {name!r}; ask {{'get': 'shots'}} for the names")
        if spec:
            raise ValueError(f"'shot' takes no other fields, got {sorted(spec)}")
        return named[name], board
    unknown = set(spec) - set(_SHOT_FIELDS)
    if unknown:
        raise ValueError(f"unknown board fields {sorted(unknown)}; known: {_SHOT_FIELDS}")
    fields: dict[str, Any] = {k: float(v) for k, v in spec.items()
                              if k not in ("shift_mm", "laser")}
    if "shift_mm" in spec:
        fields["shift_mm"] = tuple(float(v) for v in spec["shift_mm"])[:2]
    fields["laser"] = bool(spec.get("laser", False))
    return Shot("custom", "custom", 900, **fields), board


def parse_turning(spec: Any) -> tuple[Turning, float]:
    """A ``turning`` request's surface and the spindle's turn per frame; ValueError names
    what is wrong."""
    if not isinstance(spec, dict):
        raise ValueError("'turning' takes an object, e.g. {\"eccentricity_mm\": 0.05, "
                         "\"spindle_deg_per_frame\": 37}; {} for a concentric round shaft")
    spec = dict(spec)
    step = float(spec.pop("spindle_deg_per_frame", 0.0))
    unknown = set(spec) - {"eccentricity_mm", "eccentricity_deg", "lobes"}
    if unknown:
        raise ValueError(f"unknown turning fields {sorted(unknown)}; known: eccentricity_mm, "
                         "eccentricity_deg, lobes, spindle_deg_per_frame")
    try:
        lobes = tuple((int(k), float(a), float(p)) for k, a, p in spec.get("lobes", ()))
    except (TypeError, ValueError):
        raise ValueError("lobes: a list of [order, amplitude_mm, phase_deg]") from None
    return Turning(float(spec.get("eccentricity_mm", 0.0)),
                   float(spec.get("eccentricity_deg", 0.0)), lobes), step


def apply_request(camera: SimGigECamera, request: Any) -> dict[str, Any]:
    """Carry out one control request; errors become an ``ok: false`` reply."""
    try:
        if not isinstance(request, dict):
            raise ValueError("a request is a JSON object")
        if "set" in request:
            changes = request["set"]
            if not isinstance(changes, dict) or not changes:
                raise ValueError("'set' takes an object of settings")
            unknown = set(changes) - set(_SETTERS) - {"disturbances", "turning"}
            if unknown:
                raise ValueError(f"unknown settings {sorted(unknown)}; known: "
                                 f"{(*_SETTERS, 'disturbances', 'turning')}")
            if "turning" in changes:
                camera.set_turning(*parse_turning(changes["turning"]))
            if "disturbances" in changes:
                spec = changes["disturbances"]
                if not isinstance(spec, dict):
                    raise ValueError("'disturbances' takes an object, e.g. "
                                     "{\"ghost\": {\"gain\": 0.3}}; {} for none")
                camera.set_disturbances(Disturbances.from_dict(spec))
            values = {k: float(v) for k, v in changes.items()
                      if k not in ("disturbances", "turning")}
            if "diameter_mm" in values or "drift_um_per_min" in values:
                camera.set_diameter(values.get("diameter_mm", camera.current_diameter()),
                                    values.get("drift_um_per_min"))
            if "cnc_total_mm" in values:
                camera.set_cnc_total(values["cnc_total_mm"])
            if "lost_ratio" in values:
                camera.set_lost_ratio(values["lost_ratio"])
            if "fps" in values:
                camera.set_fps(values["fps"])
        elif request.get("do") == "new_insert":
            if camera.lathe is None:
                raise ValueError("no virtual lathe: start the camera with one (--lathe) to "
                                 "change its insert")
            camera.lathe.new_insert()
        elif request.get("do") == "advance_lathe":
            if camera.lathe is None:
                raise ValueError("no virtual lathe to advance")
            camera.lathe.advance(float(request.get("s", 0.0)))
        elif "show" in request:
            camera.show_board(*parse_show(request["show"]))
        elif request.get("get") == "shots":
            return {"ok": True, "shots": [s.name for s in session_shots()]}
        elif request.get("get") != "stats":
            raise ValueError("use {'set': {...}}, {'show': ...}, {'do': 'new_insert'}, "
                             "{'do': 'advance_lathe', 's': S}, "
                             "{'get': 'stats'} or "
                             "{'get': 'shots'}")
        return {"ok": True, "stats": camera.stats()}
    except (ValueError, TypeError) as err:
        return {"ok": False, "error": str(err)}


def serve_control(camera: SimGigECamera, port: int = 0,
                  host: str = "127.0.0.1") -> socketserver.ThreadingTCPServer:
    """Serve the control port in a daemon thread; ``server.server_address[1]`` is the port."""

    class Handler(socketserver.StreamRequestHandler):
        def handle(self) -> None:
            for line in self.rfile:
                try:
                    reply = apply_request(camera, json.loads(line))
                except json.JSONDecodeError as err:
                    reply = {"ok": False, "error": f"not JSON: {err}"}
                self.wfile.write((json.dumps(reply) + "\n").encode())

    socketserver.ThreadingTCPServer.allow_reuse_address = True
    server = socketserver.ThreadingTCPServer((host, port), Handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, name="sim-control", daemon=True).start()
    return server


def control(port: int, request: dict[str, Any], host: str = "127.0.0.1",
            timeout_s: float = 5.0) -> dict[str, Any]:
    """Send one request to a simulated camera's control port and return its reply."""
    with socket.create_connection((host, port), timeout=timeout_s) as sock:
        sock.sendall((json.dumps(request) + "\n").encode())
        return json.loads(sock.makefile().readline())
