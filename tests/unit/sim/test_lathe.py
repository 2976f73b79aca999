"""The virtual lathe (drivers/sim/lathe.py): the diameter cut follows wear, inserts, chips,
warm-up and the CNC's offset, never the gauge."""

from __future__ import annotations

import pytest

from drivers.sim.lathe import LatheConfig, VirtualLathe


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
