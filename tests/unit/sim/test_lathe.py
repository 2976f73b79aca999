"""The virtual lathe (drivers/sim/lathe.py): the diameter cut follows wear, inserts, chips,
warm-up and the CNC's offset, never the gauge."""

from __future__ import annotations

import pytest

from drivers.sim.lathe import LaserView, LatheConfig, VirtualLathe


def test_wear_inserts_and_offsets_part_to_part() -> None:
    lathe = VirtualLathe(LatheConfig(nominal_mm=30.0, wear_per_part_mm=0.001,
                                     insert_changes=(5,), part_sigma_mm=0.0))
    cut = [lathe.cut_part(0.0).diameter_mm for _ in range(7)]
    assert cut[:5] == pytest.approx([30.0, 30.001, 30.002, 30.003, 30.004])
    assert cut[5:] == pytest.approx([30.0, 30.001])  # a new insert
    assert lathe.cut_part(-0.002).diameter_mm == pytest.approx(30.0)  # the CNC's offset
    assert [p.index for p in lathe.log] == list(range(8))


def test_warm_up_chips_and_scatter_are_seeded() -> None:
    config = LatheConfig(thermal_mm=0.015, thermal_tau_min=20.0, chip_probability=0.5,
                         part_sigma_mm=0.002, cycle_min=2.0)
    a = [VirtualLathe(config, seed=3).cut_part(0.0) for _ in range(1)]
    lathe, again = VirtualLathe(config, seed=3), VirtualLathe(config, seed=3)
    first = [lathe.cut_part(0.0).diameter_mm for _ in range(50)]
    assert first == [again.cut_part(0.0).diameter_mm for _ in range(50)]
    assert a[0].thermal_mm == 0.0
    assert lathe.log[-1].thermal_mm == pytest.approx(0.015 * (1 - 2.718281828 ** (-98 / 20)),
                                                     rel=1e-6)
    assert lathe.log[-1].wear_mm > 0.0  # chips, no wear rate


def test_continuous_work_has_its_dead_time_from_distance_and_feed() -> None:
    config = LatheConfig(wear_per_min_mm=0.001, insert_changes=(10,), part_sigma_mm=0.0,
                         feed_mm_per_min=200.0, laser_distance_mm=50.0)
    assert config.dead_time_min == pytest.approx(0.25)
    lathe = VirtualLathe(config)
    assert lathe.cut_at(4.5, 0.0).diameter_mm == pytest.approx(30.0045)
    assert lathe.cut_at(10.5, 0.0).diameter_mm == pytest.approx(30.0005)  # new insert at 10


def test_the_laser_sees_an_offset_one_dead_time_after_the_cnc_applied_it() -> None:
    """The surface under the laser was cut a dead time ago (laser distance / feed) with the
    total the CNC held then: an offset changes what the camera sees only that much later."""
    config = LatheConfig(nominal_mm=30.0, wear_per_min_mm=0.006, part_sigma_mm=0.0,
                         feed_mm_per_min=60.0, laser_distance_mm=2.0)  # 2 s dead time
    view = LaserView(VirtualLathe(config), sample_s=0.5)
    assert view.dead_time_s == pytest.approx(2.0)
    assert view.diameter_mm(0.0) == pytest.approx(30.0)
    assert view.diameter_mm(0.2) == view.diameter_mm(0.0)  # one sample per 0.5 s
    assert view.diameter_mm(12.0) == pytest.approx(30.0 + 0.006 * 10.0 / 60.0)
    view.cnc_total(12.0, -0.001)
    assert view.diameter_mm(13.5) == pytest.approx(30.0 + 0.006 * 11.5 / 60.0)  # in flight
    assert view.diameter_mm(14.0) == pytest.approx(30.0 + 0.006 * 12.0 / 60.0 - 0.001)
    assert view.total_at(11.9) == 0.0 and view.total_at(12.0) == -0.001
    assert [p.offset_mm for p in view.lathe.log][-1] == -0.001


def test_an_insert_every_so_many_parts_or_minutes() -> None:
    parts = VirtualLathe(LatheConfig(wear_per_part_mm=0.001, insert_every=3, part_sigma_mm=0.0))
    assert [round((parts.cut_part(0.0).diameter_mm - 30.0) * 1e3, 6) for _ in range(7)] == \
        [0.0, 1.0, 2.0, 0.0, 1.0, 2.0, 0.0]
    minutes = VirtualLathe(LatheConfig(wear_per_min_mm=0.001, insert_every=10,
                                       part_sigma_mm=0.0))
    assert minutes.cut_at(9.5, 0.0).diameter_mm == pytest.approx(30.0095)
    assert minutes.cut_at(12.0, 0.0).diameter_mm == pytest.approx(30.002)
    assert minutes.cut_at(25.0, 0.0).diameter_mm == pytest.approx(30.005)


def test_break_in_then_linear_then_faster_toward_the_end_of_life() -> None:
    config = LatheConfig(wear_per_part_mm=0.001, break_in_mm=0.004, break_in_parts=2.0,
                         wear_knee_parts=10, wear_acceleration=1.0, part_sigma_mm=0.0)
    lathe = VirtualLathe(config)
    wear = [lathe.cut_part(0.0).wear_mm for _ in range(30)]
    assert wear[3] - wear[0] > 3 * 0.001 + 0.003  # the break-in comes fast
    assert wear[9] - wear[8] == pytest.approx(0.001, rel=0.05)  # then the base rate (+ 3 %)
    assert wear[29] - wear[28] == pytest.approx(0.001 * (1 + 18.5 / 10), rel=0.01)
    assert config.wear_after(20, 0.001) == pytest.approx(0.020 + 0.004 * (1 - 2.718281828
                                                                          ** -10) + 0.005)


def test_a_stop_cools_the_machine_and_it_warms_again() -> None:
    lathe = VirtualLathe(LatheConfig(thermal_mm=0.020, thermal_tau_min=10.0, cool_tau_min=30.0,
                                     stops=((60, 60.0),), part_sigma_mm=0.0))
    cut = [lathe.cut_part(0.0) for _ in range(120)]
    warm = cut[59].thermal_mm
    assert warm == pytest.approx(0.020 * (1 - 2.718281828 ** -5.9), rel=1e-6)
    assert cut[60].thermal_mm < 0.5 * warm  # an hour standing
    assert cut[60].time_min == pytest.approx(120.0)
    assert cut[119].thermal_mm > 0.99 * 0.020  # warm again


def test_an_insert_changed_by_hand_in_continuous_work() -> None:
    lathe = VirtualLathe(LatheConfig(wear_per_min_mm=0.001, part_sigma_mm=0.0))
    assert lathe.cut_at(5.0, 0.0).wear_mm == pytest.approx(0.005)
    lathe.change_insert_at(5.5)
    assert lathe.cut_at(6.0, 0.0).wear_mm == pytest.approx(0.0005)


def test_a_paced_lathe_stands_until_it_is_moved() -> None:
    import time

    from drivers.sim.gige import CameraLathe

    config = LatheConfig(nominal_mm=30.0, wear_per_min_mm=60.0, feed_mm_per_min=100.0,
                         laser_distance_mm=1.0)
    paced, wall = CameraLathe(config, paced=True), CameraLathe(config)
    time.sleep(0.05)
    assert paced.stats()["time_s"] == 0.0 and paced.stats()["wear_mm"] == 0.0
    assert wall.stats()["time_s"] > 0.0
    assert paced.advance(2.5) == 2.5
    time.sleep(0.05)
    assert paced.stats()["time_s"] == 2.5
    assert paced.stats()["wear_mm"] > 1.0   # 1 mm a second, seen a dead time (0.6 s) later
