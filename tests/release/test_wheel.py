"""The package as it is installed, not the checkout: the wheel built from this tree, installed
in a clean venv from the lock file, says its version and commit and serves the embedded
default (simulated camera and PLC) with its dashboard and manual. ``make wheel-test`` runs
it (CI does, after ``make test``)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from packaging.utils import canonicalize_name

from tests.e2e.conftest import start_service, stop_service, wait_ready
from tests.unit.test_lock import _pins

pytestmark = pytest.mark.wheel

REPO = Path(__file__).resolve().parents[2]
SKIP = shutil.ignore_patterns(".venv", ".git", "build", "test-artifacts", "shaftgauge-data",
                              "__pycache__", "*.egg-info", ".pytest_cache", ".hypothesis")


def _run(*args: str, cwd: Path | None = None) -> str:
    out = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, f"{' '.join(args)}:\n{out.stdout[-2000:]}{out.stderr[-4000:]}"
    return out.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The ``shaftgauge`` of a clean venv holding the lock's versions and the built wheel."""
    assert (REPO / "service" / "web" / "manual" / "index.html").exists(), \
        "the manual is not built (make docs)"
    tmp = tmp_path_factory.mktemp("wheel")
    # A copy of the tree with its commit stamped, as make wheel builds it.
    src = tmp / "src"
    shutil.copytree(REPO, src, ignore=SKIP)
    commit = _run("git", "rev-parse", "--short=12", "HEAD", cwd=REPO).strip()
    (src / "service" / "BUILD_COMMIT").write_text(commit + "\n")
    _run(sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp / "dist"),
         str(src))
    wheel = next((tmp / "dist").glob("shaftgauge-*.whl"))
    venv = tmp / "venv"
    _run(sys.executable, "-m", "venv", str(venv))
    pip = str(venv / "bin" / "pip")
    _run(pip, "install", "-q", "--require-hashes", "-r", str(REPO / "deploy/requirements.lock"))
    _run(pip, "install", "-q", "--no-deps", str(wheel))
    _run(str(venv / "bin" / "python"), "-m", "service.measure.compiled")
    return venv / "bin" / "shaftgauge"


def test_the_installed_wheel_says_its_version_and_commit(installed: Path) -> None:
    commit = _run("git", "rev-parse", "--short=12", "HEAD", cwd=REPO).strip()
    version = _run(sys.executable, "-c",
                   "import tomllib; print(tomllib.load(open('pyproject.toml', 'rb'))"
                   "['project']['version'])", cwd=REPO).strip()
    assert _run(str(installed), "--version").strip() == \
        f"shaftgauge {version} (commit {commit})"


def test_the_installed_wheel_serves_the_embedded_default(installed: Path, tmp_path) -> None:
    # Nothing of the checkout on its path: the venv's own package, files and all.
    assert "site-packages" in _run(
        str(installed.with_name("python")), "-c", "import service; print(service.__file__)",
        cwd=tmp_path)
    svc = start_service(tmp_path, embedded=True, executable=str(installed))
    try:
        assert wait_ready(svc, 90), svc.stderr()[-3000:]
        status = svc.get("/api/v1/status").json()
        assert status["camera"]["state"] == "streaming", status["camera"]
        page = svc.get("/ui/")
        assert page.status_code == 200 and "shaftgauge" in page.text.lower()
        manual = svc.get("/ui/manual/")
        assert manual.status_code == 200 and "<html" in manual.text.lower()
        latest = httpx.get(svc.url + "/api/v1/measurements/latest", timeout=10)
        assert latest.status_code in (200, 404), latest.text
    finally:
        stop_service(svc)


def test_the_clean_install_holds_exactly_the_lock_s_versions(installed: Path) -> None:
    frozen = _run(str(installed.with_name("pip")), "freeze", "--all", "--exclude", "pip",
                  "--exclude", "shaftgauge")
    got = {}
    for line in frozen.splitlines():
        name, _, ver = line.partition("==")
        got[canonicalize_name(name)] = ver
    want = _pins("requirements.lock")
    got = {n: v for n, v in got.items() if n not in ("setuptools", "wheel") or n in want}
    assert got == want
