"""``shaftgauge --version``: the package's version and the commit of the checkout it runs
from (the installed wheel's is tested in tests/release)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from service import cli, version

REPO = Path(__file__).resolve().parents[2]


def test_version_names_the_package_version_and_the_checkout_s_commit(capsys) -> None:
    head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=REPO,
                          capture_output=True, text=True, check=True).stdout.strip()
    with pytest.raises(SystemExit) as done:
        cli.main(["--version"])
    assert done.value.code == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith(f"shaftgauge {version.package_version()} (commit {head}")
    assert version.package_version() != "unknown"


def test_without_a_checkout_the_built_in_commit_is_read(tmp_path, monkeypatch) -> None:
    (tmp_path / "BUILD_COMMIT").write_text("0123456789ab\n")
    monkeypatch.setattr(version, "_HERE", tmp_path)
    version.build_commit.cache_clear()
    try:
        assert version.build_commit() == "0123456789ab"
        (tmp_path / "BUILD_COMMIT").unlink()
        version.build_commit.cache_clear()
        assert version.build_commit() == "unknown"
    finally:
        version.build_commit.cache_clear()
