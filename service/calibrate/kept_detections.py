"""Board detections kept on disk, so that another process given the same pixels reads the
detection instead of running the detector again (about half a second an image).

A session's steps each run in a worker process of their own, and the command line's steps
are processes too: without this each step detected again the images an earlier one had (the
plane its laser-off images, the axis its rotations), and a step run again after one more
capture all of them. A detection is a small JSON file named by the pixels' digest, the board
and OpenCV's version (``intrinsics.detection_name``); one process at a time detects an image
(a lock file each), and a file that cannot be read is detected again and written anew.
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

import numpy as np

from service.calibrate.board import Board
from service.calibrate.intrinsics import Corners, detection_name, find_corners, keep_detection


def detect_kept(images: list[np.ndarray], board: Board, folder: Path | None) -> None:
    """Each grey image's detection of ``board`` made ready for ``find_corners``: read from
    ``folder`` when kept there, else detected and written there (nothing when ``folder`` is
    None)."""
    if folder is None:
        return
    folder.mkdir(parents=True, exist_ok=True)
    for image in images:
        name = detection_name(image, board)
        with open(folder / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # another process detecting it: wait, then read
            kept = _read(folder / f"{name}.json")
            if kept is not None:
                keep_detection(image, board, kept)
            else:
                _write(folder / f"{name}.json", find_corners(image, board))


def _read(path: Path) -> Corners | None:
    try:
        d = json.loads(path.read_text())
        points = None if d["points"] is None else np.array(d["points"], dtype=np.float64)
        ids = None if d["ids"] is None else np.array(d["ids"], dtype=np.int64)
        if points is not None and (points.ndim != 2 or points.shape[1] != 2 or
                                   (ids is not None and ids.shape != (len(points),))):
            return None
        return Corners(points, str(d["reason"]), ids)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _write(path: Path, found: Corners) -> None:
    doc = {"points": None if found.points is None else found.points.tolist(),
           "reason": found.reason, "ids": None if found.ids is None else found.ids.tolist()}
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(doc))
    tmp.replace(path)  # whole or not at all: a reader never sees half a file
