"""Which shaftgauge this is: the package's version and the commit it was built from.

The commit comes from the checkout when the package runs from one (``git``), else from the
``BUILD_COMMIT`` file that ``make wheel`` puts in the wheel; "unknown" when neither is there.
"""

from __future__ import annotations

import functools
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

_HERE = Path(__file__).resolve().parent


def package_version() -> str:
    """The installed package's version ("unknown" when it is not installed)."""
    try:
        return version("shaftgauge")
    except PackageNotFoundError:
        return "unknown"


@functools.lru_cache(maxsize=1)
def build_commit() -> str:
    """The commit this code is (short hash, "+changes" when the checkout has changes)."""
    if (_HERE.parent / ".git").exists():
        try:
            run = functools.partial(subprocess.run, cwd=_HERE.parent, capture_output=True,
                                    text=True, timeout=5, check=True)
            commit = run(["git", "rev-parse", "--short=12", "HEAD"]).stdout.strip()
            dirty = run(["git", "status", "--porcelain", "--untracked-files=no"]).stdout
            return commit + ("+changes" if dirty.strip() else "")
        except (OSError, subprocess.SubprocessError):
            pass
    stamp = _HERE / "BUILD_COMMIT"
    if stamp.is_file():
        return stamp.read_text().strip() or "unknown"
    return "unknown"


def describe() -> str:
    """``shaftgauge VERSION (commit COMMIT)``."""
    return f"shaftgauge {package_version()} (commit {build_commit()})"
