"""A calibration session at the machine: images collected by kind, the steps run on them in
order (intrinsics, light plane, axis, build), each with a typed result, kept on disk so that
a restart of the service loses no open session. The API and the CLI are thin wrappers: the
step dispatch lives here (``run_step``), once."""

from __future__ import annotations

import json
import shutil
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args

import cv2
import numpy as np

from calib_store.model import Calibration, CalibrationError, load_calibration, save_calibration
from service.calibrate import commands
from service.calibrate.board import Board
from service.calibrate.worker import StepStoppedError, run_in_worker

ImageKind = Literal["view", "plane_off", "plane_on", "axis"]
Step = Literal["intrinsics", "plane", "axis", "build"]
STEPS: tuple[str, ...] = get_args(Step)
SESSION_FILE = "session.json"


class SessionLimitError(RuntimeError):
    """Too many sessions or images; the message names the setting."""


@dataclass(frozen=True)
class StepInputs:
    """What a step reads: images by kind, the board, and the earlier steps' result files."""

    board: Board
    images: dict[str, list[str]] = field(default_factory=dict)
    intrinsics: str = ""
    plane: str | None = None
    axis: str = ""
    detections: str | None = None
    """Where the board's detections are kept for the next step (``kept_detections``)."""


@dataclass(frozen=True)
class StepResult:
    """One step's outcome: ``ok`` and why not, the figures written to its JSON file, and for
    ``build`` the calibration (None when refused) and its quality report."""

    step: str
    ok: bool
    reason: str
    figures: dict[str, Any]
    calibration: Calibration | None = None
    report: dict[str, Any] | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready, without the calibration itself."""
        return {"step": self.step, "ok": self.ok, "reason": self.reason,
                **{k: v for k, v in self.figures.items() if k not in ("step", "ok", "reason",
                                                                      "report")}}


def run_step(step: Step, inputs: StepInputs) -> StepResult:
    """Run one calibration step (``commands.StepError`` for unusable inputs)."""
    imgs = inputs.images
    kept = Path(inputs.detections) if inputs.detections else None
    if step == "intrinsics":
        # Every image with the board in it constrains the intrinsics (the principal point
        # most of all: tests/bench/principal_point.py), not only the views.
        figures, _ = commands.intrinsics_step(
            imgs.get("view", []) + imgs.get("plane_off", []) + imgs.get("axis", []),
            inputs.board, kept)
    elif step == "plane":
        off, on = imgs.get("plane_off", []), imgs.get("plane_on", [])
        if not off and on:  # no laser-off twins: the laser-on images alone
            figures, _ = commands.plane_step(inputs.intrinsics, [], on, kept)
        elif len(off) != len(on):
            raise commands.StepError("plane images come two by two: laser off, then laser "
                                     "on (as many of each), or laser-on images alone")
        else:
            figures, _ = commands.plane_step(
                inputs.intrinsics, [p for pair in zip(off, on, strict=True) for p in pair],
                detections=kept)
    elif step == "axis":
        figures, _ = commands.axis_step(inputs.intrinsics, inputs.plane, imgs.get("axis", []),
                                        kept)
    else:
        cal, report = commands.build_step(inputs.intrinsics, str(inputs.plane), inputs.axis)
        return StepResult("build", cal is not None, "; ".join(report.reasons),
                          {"verdict": report.verdict}, cal, report.as_dict())
    return StepResult(step, bool(figures.get("ok")), figures.get("reason") or "", figures)


@dataclass
class CalibrationSession:
    """One session's images, progress and results, in its own folder."""

    id: str
    board: str
    note: str
    by: str
    dir: Path
    created: float = field(default_factory=time.time)
    touched: float = field(default_factory=time.time)
    images: dict[str, list[str]] = field(default_factory=lambda: {k: [] for k in
                                                                   get_args(ImageKind)})
    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    progress: dict[str, Any] = field(default_factory=lambda: {
        "step": None, "state": "idle", "message": ""})
    report: dict[str, Any] | None = None
    activated_id: int | None = None

    @property
    def counts(self) -> bool:
        """Whether the session holds one of the open places: not once its result is in use
        or its last step failed (the technician may still add images and run it again)."""
        return self.activated_id is None and self.progress.get("state") != "failed"

    @property
    def built(self) -> Path:
        """Where the built calibration is kept."""
        return self.dir / "calibration.json"

    def calibration(self) -> Calibration | None:
        """The built calibration, or None (not built, or refused)."""
        try:
            return load_calibration(self.built) if self.built.exists() else None
        except CalibrationError:
            return None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready view."""
        return {"id": self.id, "board": self.board, "note": self.note, "by": self.by,
                "created": self.created,
                "images": {k: len(v) for k, v in self.images.items()},
                "results": self.results, "progress": self.progress, "report": self.report,
                "built": self.built.exists(), "activated_id": self.activated_id,
                "counts": self.counts, "touched": self.touched}

    def save(self) -> None:
        """Write the session's state next to its images (atomically)."""
        doc = {k: v for k, v in asdict(self).items() if k != "dir"}
        tmp = self.dir / (SESSION_FILE + ".tmp")
        tmp.write_text(json.dumps(doc))
        tmp.replace(self.dir / SESSION_FILE)

    @classmethod
    def load(cls, folder: Path) -> CalibrationSession:
        """A session saved in ``folder``; one that was running is marked interrupted."""
        doc = json.loads((folder / SESSION_FILE).read_text())
        s = cls(dir=folder, **doc)
        if s.progress.get("state") == "running":
            s.progress = {**s.progress, "state": "failed",
                          "message": f"{s.progress.get('step')}: interrupted by a restart; "
                                     "run it again"}
        return s

    def inputs(self) -> StepInputs:
        """What the next step reads."""
        plane = self.dir / "plane.json"
        return StepInputs(commands.parse_board(self.board), self.images,
                          str(self.dir / "intrinsics.json"),
                          str(plane) if plane.exists() else None, str(self.dir / "axis.json"),
                          str(self.dir / "detections"))

    def add_image(self, kind: ImageKind, image: np.ndarray, max_images: int) -> dict[str, Any]:
        """Store an image of ``kind`` (SessionLimitError past ``max_images``; OSError when it
        cannot be written)."""
        held = sum(len(v) for v in self.images.values())
        if held >= max_images:
            raise SessionLimitError(f"session {self.id} holds {held} images, the most one "
                                    "session may (api.max_session_images)")
        path = self.dir / f"{kind}_{len(self.images[kind]):03d}.png"
        if not cv2.imwrite(str(path), image):
            raise OSError(f"could not write {path} (is the disk full?)")
        self.images[kind].append(str(path))
        self.touched = time.time()
        self.save()
        h, w = image.shape[:2]
        return {"kind": kind, "index": len(self.images[kind]) - 1, "size": [w, h]}

    def run(self, step: Step,
            runner: Callable[[Step, StepInputs], StepResult] = run_step) -> StepResult:
        """Run a step on the session's images (by ``runner``), record its result (and the
        calibration, when built); ``commands.StepError`` for unusable inputs, a failure or a
        step past its budget is recorded too, then raised."""
        self.touched = time.time()
        self.progress = {"step": step, "state": "running", "message": f"{step}: working",
                         "started": self.touched}
        self.save()
        try:
            result = runner(step, self.inputs())
        except commands.StepError as err:
            self.progress = {"step": step, "state": "failed", "message": str(err)}
            self.save()
            raise
        if step == "build":
            self.report = result.report
            if result.calibration is not None:
                save_calibration(result.calibration, self.built)
        else:
            commands.write_json(str(self.dir / f"{step}.json"), result.figures)
        self.results[step] = result.summary()
        self.progress = {"step": step, "state": "done" if result.ok else "failed",
                         "message": result.reason or f"{step}: done",
                         "finished": time.time()}
        self.save()
        return result


class CalibrationSessions:
    """The open sessions under one folder: created, found, capped, expired, and loaded again
    after a restart.

    Parameters
    ----------
    root : Path
        One sub-folder per session.
    max_open : int
        Sessions open at once.
    max_images : int
        Images per session.
    expiry_h : float
        A session untouched this long is deleted with its images. Reads do not touch it;
        images, steps and activation do.
    step_budget_s : float
        A step that runs longer is stopped (``run``: each in a worker process of its own).

    Only sessions that ``count`` (neither activated nor failed) fill the ``max_open`` places;
    at most ``max_open`` finished ones are kept besides, the oldest deleted first.
    """

    def __init__(self, root: Path, max_open: int, max_images: int, expiry_h: float,
                 step_budget_s: float = 600.0) -> None:
        self.root, self.max_open, self.max_images = root, max_open, max_images
        self.expiry_s = expiry_h * 3600.0
        self.step_budget_s = step_budget_s
        self._open: dict[str, CalibrationSession] = {}
        self._stops: dict[str, threading.Event] = {}   # by session, while a step runs
        self._lock = threading.Lock()   # steps run in threads; ending one is a request
        if root.is_dir():
            for folder in sorted(root.iterdir()):
                if (folder / SESSION_FILE).exists():
                    try:
                        s = CalibrationSession.load(folder)
                    except (OSError, ValueError, TypeError):
                        continue  # a damaged session file: leave it, do not serve it
                    self._open[s.id] = s

    def expire(self) -> None:
        """Delete sessions untouched for the expiry time (not while a step runs)."""
        now = time.time()
        for sid, s in list(self._open.items()):
            if now - s.touched > self.expiry_s and s.progress.get("state") != "running":
                self._delete(sid)

    def _delete(self, sid: str) -> None:
        s = self._open.pop(sid)
        shutil.rmtree(s.dir, ignore_errors=True)

    def listing(self) -> list[CalibrationSession]:
        """The kept sessions, newest first."""
        self.expire()
        return sorted(self._open.values(), key=lambda s: s.created, reverse=True)

    def create(self, board: str, note: str, by: str) -> CalibrationSession:
        """A new session (``commands.StepError`` for a bad board, SessionLimitError past
        ``max_open``)."""
        commands.parse_board(board)
        self.expire()
        counting = [s for s in self._open.values() if s.counts]
        if len(counting) >= self.max_open:
            raise SessionLimitError(
                f"{len(counting)} calibration sessions are open "
                f"({', '.join(sorted(s.id for s in counting))}), the most allowed "
                "(api.max_calibration_sessions): end one (DELETE "
                "/api/v1/calibration-sessions/{id}, or End on the calibration page), or wait "
                f"for it to expire {self.expiry_s / 3600.0:g} h after its last change")
        finished = sorted((s for s in self._open.values() if not s.counts),
                          key=lambda s: s.touched)
        for s in finished[:max(0, len(finished) - self.max_open + 1)]:
            self._delete(s.id)
        sid = uuid.uuid4().hex[:12]
        folder = self.root / sid
        folder.mkdir(parents=True, exist_ok=True)
        s = CalibrationSession(sid, board, note, by, folder)
        s.save()
        self._open[sid] = s
        return s

    def get(self, sid: str) -> CalibrationSession:
        """A kept session (KeyError when there is none of that id); reading it does not
        renew it."""
        self.expire()
        return self._open[sid]

    def run(self, s: CalibrationSession, step: Step) -> StepResult:
        """Run a step of a kept session in a worker process within the step budget (as
        ``CalibrationSession.run``); ``StepStoppedError`` when the session is ended meanwhile
        (its folder is deleted once the worker is gone)."""
        with self._lock:
            if s.id not in self._open:
                raise StepStoppedError(f"{step}: session {s.id} was ended")
            stop = self._stops.setdefault(s.id, threading.Event())
        try:
            return s.run(step, lambda step_, inputs: run_in_worker(
                step_, run_step, (step_, inputs), self.step_budget_s, stop))
        finally:
            with self._lock:
                self._stops.pop(s.id, None)
            if stop.is_set():
                shutil.rmtree(s.dir, ignore_errors=True)

    def end(self, sid: str) -> None:
        """End a session and delete its images (KeyError when there is none of that id); a
        step running on it is stopped, and its folder goes once the step's worker is."""
        self.get(sid)
        with self._lock:
            stop = self._stops.get(sid)
            if stop is None:
                self._delete(sid)
            else:
                stop.set()
                self._open.pop(sid)
