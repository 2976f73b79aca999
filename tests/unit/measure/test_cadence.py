"""When the pipeline checks a frame for a reflection (``service.measure.cadence``)."""

from __future__ import annotations

from service.measure.cadence import ReflectionWatch


def checks(watch: ReflectionWatch, times: list[float], found_at: set[float] = frozenset()
           ) -> list[float]:
    out = []
    for t in times:
        checked = watch.due(t)
        if checked:
            out.append(t)
        watch.seen(checked, t in found_at and checked)
    return out


def test_a_few_frames_a_second_are_checked_while_there_is_no_reflection() -> None:
    frames = [i / 100 for i in range(200)]  # 100 frames a second for 2 s
    assert checks(ReflectionWatch(5.0), frames) == [0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.4,
                                                    1.6, 1.8]


def test_every_frame_is_checked_while_a_reflection_is_there() -> None:
    frames = [i / 100 for i in range(100)]
    watch = ReflectionWatch(5.0)
    # Found at 0.2 s and on every checked frame until 0.5 s; none after.
    got = checks(watch, frames, {t for t in frames if 0.2 <= t < 0.5})
    assert [t for t in got if t < 0.6] == [0.0] + [t for t in frames if 0.2 <= t <= 0.5]
    assert [t for t in got if t > 0.5] == [0.7, 0.9]  # back to five a second


def test_a_lopsided_frame_found_between_checks_starts_the_checks() -> None:
    watch = ReflectionWatch(5.0)
    assert watch.due(0.0)
    watch.seen(False, False)
    assert not watch.due(0.05)
    watch.seen(False, True)  # the measurement checked a lopsided stripe on its own
    assert watch.due(0.06) and watch.present


def test_the_extremes() -> None:
    always, never = ReflectionWatch(float("inf")), ReflectionWatch(0.0)
    assert all(always.due(t / 1000) for t in range(50))
    assert always.due(0.049)  # the same instant again (inf * 0 is not a number)
    assert not any(never.due(t) for t in range(1, 50))
