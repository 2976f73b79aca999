"""The speed guard (``tests.bench.guard``): the core's and the service's speed ratios, measured
now, held against the last committed ones (``bench-results/guard.json``, ``make bench``).

It times, so it runs alone and outside ``make test`` (marked ``timed``: ``make speed``; the suite
beside it slowed the core against the plain Steger to 0.69 of the baseline in one CI run, a
machine busy with other tests, not a change). Run it before closing a change to the core.

The margin: five runs of the quick core bench in a row on this machine gave each ratio
within 9-13 % of their median (the lowest run at 0.82 of it); a ratio below 0.7 of its
baseline is a change, not the machine (a core 1.45 times slower fails). The service must
keep measuring every frame it is sent (at least 0.9 of them, as the baseline did: 1.0).

A core ratio below the margin is measured once more, 10 s later, and fails only if it is below
again: a clean-clone run on 4 December read 0.69 and 0.67 of the baseline right after the
fleet test, the same tree 0.82-0.90 when run again (alone and after the same tests), while a
core made slower (``band_hessian`` eight times a frame) reads 0.55 and 0.42 every time.
"""

from __future__ import annotations

import json
import time

import pytest

from tests.bench import guard

MARGIN = 0.7
AGAIN_S = 10.0
pytestmark = pytest.mark.timed


@pytest.fixture(scope="module")
def baseline() -> dict:
    if not guard.BASELINE.exists():
        pytest.fail(f"no committed baseline at {guard.BASELINE}: run `make bench`")
    return json.loads(guard.BASELINE.read_text())


@pytest.fixture(scope="module")
def core_now() -> dict[str, float]:
    return guard.quick_core()


def report(name: str, then: dict, now: dict, keys: list[str]) -> str:
    rows = [f"{k}: baseline {then[k]:.3f}, now {now[k]:.3f} ({now[k] / then[k]:.2f}x)"
            for k in keys]
    return f"{name} (baseline of {then.get('run', {}).get('commit', '?')}): " + "; ".join(rows)


CORE = ["plain_over_core", "plain_over_wide", "checked_over_tracked"]


def test_the_core_is_as_fast_as_the_baseline(baseline, core_now) -> None:
    then = {**baseline["core"], "run": baseline.get("run", {})}
    print("\n" + report("core", then, core_now, CORE))
    slow = [k for k in CORE if core_now[k] < MARGIN * then[k]]
    if slow:  # a slow moment of the host passes, a slower core does not: measure again
        time.sleep(AGAIN_S)
        again = guard.quick_core()
        print(report("core, again", then, again, CORE))
        slow = [k for k in slow if again[k] < MARGIN * then[k]]
        assert not slow, (f"slower than the committed baseline beyond the machine's noise "
                          f"(below {MARGIN} of it, twice): {slow}; "
                          + report("core", then, core_now, CORE) + "; "
                          + report("again", then, again, CORE))


def test_the_service_keeps_up_as_the_baseline(baseline, core_now) -> None:
    then = {**baseline["service"], "run": baseline.get("run", {})}
    now = guard.quick_service(core_now["plain_ms"])
    keys = ["measured_over_frames", "plain_over_service_cpu"]
    print("\n" + report("service", then, now, keys) + f"; dropped {now['dropped_per_s']:.1f}/s")
    assert now["measured_over_frames"] >= min(0.9, then["measured_over_frames"] - 0.05), \
        report("service", then, now, keys)
    assert now["plain_over_service_cpu"] >= MARGIN * then["plain_over_service_cpu"], \
        report("service", then, now, keys)
