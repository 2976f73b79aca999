"""Frame numbers from GigE Vision block ids (drivers/camera/base.BlockIds): counted on across
the 16-bit wrap (65535 to 1), taken as they come when the camera starts again."""

from __future__ import annotations

from drivers.camera.base import BlockIds


def test_the_16_bit_wrap_is_counted_on() -> None:
    ids = BlockIds()
    got = [ids.count(i) for i in (65533, 65534, 65535, 1, 2, 4)]
    assert got == [65533, 65534, 65535, 65536, 65537, 65539]  # a lost frame stays a gap
    assert [ids.count(i) for i in (65535, 1)] == [65535 * 2, 65535 * 2 + 1]


def test_a_camera_started_again_goes_back() -> None:
    ids = BlockIds()
    assert [ids.count(i) for i in (100, 101, 1, 2)] == [100, 101, 1, 2]


def test_extended_ids_are_taken_as_they_come() -> None:
    ids = BlockIds()
    assert [ids.count(i) for i in (1 << 40, (1 << 40) + 1)] == [1 << 40, (1 << 40) + 1]
