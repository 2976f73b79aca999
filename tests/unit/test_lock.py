"""The lock files hold what pyproject.toml asks for: every dependency (and test tool) pinned
to one version within its range, with hashes, and the installation's lock at the same
versions as the development one (``make lock`` renews both)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[2]
PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)((?:\s*\\\n\s*--hash=sha256:[0-9a-f]{64})+)",
                 re.MULTILINE)


def _pins(name: str) -> dict[str, str]:
    text = (REPO / "deploy" / name).read_text()
    pins = {canonicalize_name(m.group(1)): m.group(2) for m in PIN.finditer(text)}
    listed = [line for line in text.splitlines() if re.match(r"^[A-Za-z0-9]", line)]
    assert len(pins) == len(listed), "a requirement without an exact version and hashes"
    return pins


def _wanted(extra: bool) -> list[Requirement]:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    reqs = list(project["dependencies"])
    if extra:
        reqs += project["optional-dependencies"]["test"]
    return [Requirement(r) for r in reqs]


def test_every_dependency_is_pinned_within_its_range() -> None:
    for lock, extra in (("requirements.lock", False), ("requirements-test.lock", True)):
        pins = _pins(lock)
        for req in _wanted(extra):
            name = canonicalize_name(req.name)
            assert name in pins, f"{req.name} is not in deploy/{lock}: make lock"
            assert req.specifier.contains(pins[name], prereleases=True), \
                f"deploy/{lock} pins {req.name}=={pins[name]} outside {req.specifier}: make lock"


def test_an_installation_gets_the_versions_development_tests() -> None:
    run, dev = _pins("requirements.lock"), _pins("requirements-test.lock")
    assert {n: v for n, v in run.items() if dev.get(n) != v} == {}
