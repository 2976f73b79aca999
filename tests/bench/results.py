"""Where a bench's report goes: ``bench-results/<name>[_held_out].json`` unless told, with
the machine, the commit and the date it was measured on (``run``)."""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def machine() -> dict[str, object]:
    """Where and when: the machine, the commit (and whether the tree differed from it), the
    date."""

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], capture_output=True, text=True, cwd=ROOT,
                                  timeout=10).stdout.strip()
        except OSError:
            return ""

    return {"machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.platform()}",
            "python": platform.python_version(), "numpy": np.__version__,
            "commit": git("rev-parse", "--short", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}


def save_report(report: dict, name: str, held_out: bool = False,
                path: str | None = None) -> Path:
    """Write ``report`` as JSON with the run's ``machine()`` and say where (with the seconds
    it took, when it has them)."""
    out = Path(path or f"bench-results/{name}{'_held_out' if held_out else ''}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({**report, "run": machine()}, indent=2) + "\n")
    took = f" ({report['seconds']:.0f} s)" if "seconds" in report else ""
    print(f"\nWritten {out}{took}")
    return out
