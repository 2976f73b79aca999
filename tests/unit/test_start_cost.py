"""What a process pays to start: the simulators start with every service (dozens of times in
the suites, and with ``make run``), the command line with every ``shaftgauge`` call. numba
(0.2 s of CPU to import), scipy.optimize (0.4 s) and scipy.spatial (0.35 s) are imported by
what uses them, not by every process that imports a module beside it."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("numba", "scipy.optimize", "scipy.spatial")


def imported(modules: str) -> list[str]:
    code = (f"import sys, {modules}\n"
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)
    return out.stdout.split()


def test_the_simulators_start_without_the_kernels() -> None:
    """The simulated camera (its control port, the lathe it shows, the board it can show),
    the simulated PLC and the section's geometry the renderer uses."""
    assert imported("drivers.sim.control, drivers.sim.gige, drivers.sim.lathe, "
                    "drivers.plc.sim, service.measure.section") == []


@pytest.mark.parametrize("modules", ["service.offline", "service.serve"])
def test_measuring_does_not_import_the_paper_fit_or_the_patch_search(modules: str) -> None:
    """scipy.optimize serves the paper's method and the offline turn estimate, scipy.spatial
    a frame with a patch of light: a process that measures imports them when it gets there."""
    got = imported(modules)
    assert "scipy.optimize" not in got and "scipy.spatial" not in got, got
