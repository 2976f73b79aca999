"""The simulated camera's replay ring, region cut and sensor readout time."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.sim.replay import FrameRing, crop, min_frame_period_us
from drivers.sim.rig import RigConfig, ShaftRenderer


def test_the_ring_sends_its_frames_in_turn_and_renders_again_only_on_a_new_diameter() -> None:
    diameter = [30.0]
    ring = FrameRing(ShaftRenderer(RigConfig(image_size=(320, 240)), seed=1), 3,
                     lambda: diameter[0])
    ring.fill()
    first = [ring.take() for _ in range(3)]
    assert [slot for _, slot in first] == [0, 1, 2]
    assert ring.take()[1] == 0
    # Fresh speckle in every frame of the ring.
    assert not np.array_equal(first[0][0], first[1][0])
    stop = threading.Event()
    assert ring.refresh(stop) == 0            # nothing changed: nothing rendered
    diameter[0] = 30.5
    assert ring.refresh(stop) == 3            # every frame shows the old diameter
    assert ring.rerendered == 3
    assert not np.array_equal(ring.take()[0], first[1][0])


def test_after_a_jump_no_frame_shows_the_part_before() -> None:
    """A master put in: the frames sent next show it before the ring is rendered again (a
    frame of the part before would be measured as the master); an offset's few micrometres
    do not hold the frames up."""
    diameter = [30.0]
    renderer = ShaftRenderer(RigConfig(image_size=(320, 240)), seed=1)
    shown: list[float] = []
    real = renderer.render
    renderer.render = lambda d, i=0: shown.append(d) or real(d, i)  # type: ignore[method-assign]
    ring = FrameRing(renderer, 4, lambda: diameter[0])
    ring.fill()
    diameter[0] = 30.004  # an offset applied: rendered again in the background
    shown.clear()
    [ring.take() for _ in range(4)]
    assert shown == []
    diameter[0] = 26.0
    [ring.take() for _ in range(2)]
    assert shown == [26.0, 26.0]
    assert ring.refresh(threading.Event()) == 2  # the other two, in the background


def test_crop_and_readout_time() -> None:
    image = np.arange(100 * 80, dtype=np.uint32).reshape(100, 80)
    part = crop(image, 10, 20, 30, 40)
    assert part.shape == (40, 30) and part[0, 0] == image[20, 10] and part.flags.c_contiguous
    assert crop(image, 70, 90, 30, 40).shape == (10, 10)   # clipped to the sensor
    # Fewer rows, a shorter frame period: a higher frame rate.
    assert min_frame_period_us(1024) > 2 * min_frame_period_us(400)
    assert 1e6 / min_frame_period_us(1024) < 170


def test_a_new_renderer_renders_the_whole_ring_again() -> None:
    ring = FrameRing(ShaftRenderer(RigConfig(image_size=(320, 240)), seed=1), 3, lambda: 30.0)
    ring.fill()
    stop = threading.Event()
    assert ring.refresh(stop) == 0
    ring.set_renderer(ShaftRenderer(RigConfig(image_size=(320, 240), ambient_dn=40.0), seed=1))
    assert ring.refresh(stop) == 3


def test_a_slow_drift_renders_the_ring_once_a_step() -> None:
    """The diameter shown moves in steps of the ring's: a drift within a step renders
    nothing, a step renders each frame once, all at the same diameter."""
    diameter = [30.0]
    renderer = ShaftRenderer(RigConfig(image_size=(320, 240)), seed=1)
    shown: list[float] = []
    real = renderer.render
    renderer.render = lambda d, i=0: shown.append(d) or real(d, i)  # type: ignore[method-assign]
    ring = FrameRing(renderer, 4, lambda: diameter[0], step_mm=2.5e-4)
    ring.fill()
    stop = threading.Event()
    for d in (30.00005, 30.0001, 29.99988):
        diameter[0] = d
        assert ring.refresh(stop) == 0, d
    diameter[0] = 30.00013
    assert ring.refresh(stop) == 4
    assert shown[-4:] == [30.00025] * 4
    assert ring.refresh(stop) == 0


def test_a_drifts_step_rests_between_frames_and_a_jump_does_not() -> None:
    diameter = [30.0]
    ring = FrameRing(ShaftRenderer(RigConfig(image_size=(320, 240)), seed=1), 3,
                     lambda: diameter[0])
    ring.fill()
    stop = threading.Event()
    rests: list[float] = []
    stop.wait = lambda s=None: rests.append(s) or False  # type: ignore[method-assign]
    diameter[0] = 30.00025  # a drift's step
    assert ring.refresh(stop) == 3 and len(rests) == 3 and min(rests) > 0
    rests.clear()
    diameter[0] = 30.5  # a jump
    assert ring.refresh(stop) == 3 and rests == []


def test_a_turning_ring_renders_each_slot_at_its_own_spindle_angle() -> None:
    """Frame n of the ring shows the spindle at n times its step however often the ring was
    rendered again (so a ring of whole revolutions is what an encoder-triggered camera sees)."""
    angles: list[tuple[int, float]] = []

    class Renderer:
        def render(self, diameter_mm: float, frame_index: int, spindle_deg: float = 0.0):
            angles.append((frame_index, spindle_deg))
            return np.zeros((4, 4), np.uint8)

    diameter = [30.0]
    ring = FrameRing(Renderer(), 4, lambda: diameter[0])  # type: ignore[arg-type]
    ring.spindle_step_deg = 90.0
    ring.fill()
    diameter[0] = 30.5
    ring.take()  # a jump: slot 0 is rendered as it is sent, the others from slot 2 on
    ring.refresh(threading.Event())
    assert [a for _, a in angles] == [0.0, 90.0, 180.0, 270.0, 0.0, 180.0, 270.0, 90.0]
    assert len({i for i, _ in angles}) == 8  # fresh speckle every time


def test_a_turning_ring_must_hold_whole_revolutions() -> None:
    ring = FrameRing(ShaftRenderer(RigConfig(image_size=(320, 240)), seed=1), 8, lambda: 30.0)
    ring.check_revolutions(45.0)
    ring.check_revolutions(90.0)
    with pytest.raises(ValueError, match="a multiple of 45 degrees a frame"):
        ring.check_revolutions(37.0)
