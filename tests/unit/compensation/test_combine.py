"""When a tool's features agree: pairwise differences of consecutive measurements, which
the tool's wear and offsets cancel from, against hand-made truth."""

from __future__ import annotations

import numpy as np
import pytest

from service.compensation.combine import PAIRS_NEEDED, FeatureAgreement, aim


def measure(agree: FeatureAgreement, parts: int, bias_um: dict[int, float],
            wear_um_per_part: float, noise_um: float = 0.5, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    for k in range(parts):  # a part a minute, its features a second apart
        for i, (feature, bias) in enumerate(bias_um.items()):
            dev = (wear_um_per_part * k + bias + rng.normal(0.0, noise_um)) / 1000
            agree.add(feature, dev, noise_um / 1000, 60.0 * k + i)


@pytest.mark.parametrize("wear", [0.0, 5.0, 30.0])  # however fast the tool wears
def test_a_constant_difference_beyond_the_bound_is_named(wear: float) -> None:
    agree = FeatureAgreement()
    measure(agree, 6, {1: 0.0, 2: 0.0, 4: 8.0}, wear)
    said = agree.disagreement(bound_mm=0.004)
    assert "features 2 and 4 disagree by +8" in said or "features 1 and 4" in said, said
    assert agree.disagreement(bound_mm=0.010) == ""


def test_features_that_agree_within_their_scatter_are_not_held() -> None:
    agree = FeatureAgreement()
    measure(agree, 20, {1: 0.0, 2: 1.0}, wear_um_per_part=3.0, noise_um=1.0)
    assert agree.disagreement(bound_mm=0.002) == ""


def test_too_few_differences_say_nothing_yet_and_an_offset_breaks_a_pair() -> None:
    agree = FeatureAgreement()
    agree.add(1, 0.0, 0.0005, 0.0)
    agree.add(2, 0.020, 0.0005, 1.0)  # one difference of +20 um
    agree.add(1, 0.0, 0.0005, 2.0)  # two
    assert PAIRS_NEEDED == 3 and agree.disagreement(0.004) == ""
    agree.applied()  # an offset of +50 um reaches the parts between the two
    agree.add(2, 0.070, 0.0005, 3.0)
    assert agree.disagreement(0.004) == ""  # that pair was not counted
    agree.add(1, 0.050, 0.0005, 4.0)  # three
    assert "features 1 and 2 disagree by +20" in agree.disagreement(0.004)


def test_one_feature_alone_never_disagrees() -> None:
    agree = FeatureAgreement()
    measure(agree, 10, {3: 50.0}, 2.0)
    assert agree.disagreement(0.001) == ""


def test_a_pairs_constant_difference_is_learnt_relative_to_the_first_feature() -> None:
    agree = FeatureAgreement()
    measure(agree, 12, {3: 0.0, 4: 6.0, 5: -2.0}, wear_um_per_part=2.0, noise_um=0.3)
    levels = agree.relative_levels()
    assert levels[3] == 0.0
    assert levels[4] == pytest.approx(0.006, abs=0.0005)
    assert levels[5] == pytest.approx(-0.002, abs=0.0005)


@pytest.mark.parametrize(("levels", "tolerances", "expected"), [
    # One feature: its own level, whatever its tolerance.
    ({1: 0.004}, {1: (-0.01, 0.01)}, 0.004),
    # A tight feature 6 um above a wide one: the tight one on its nominal (margins 12 and 14).
    ({3: 0.0, 4: 0.006}, {3: (-0.02, 0.02), 4: (-0.012, 0.012)}, 0.006),
    # Equal tolerances: half the difference each.
    ({1: 0.0, 2: 0.010}, {1: (-0.02, 0.02), 2: (-0.02, 0.02)}, 0.005),
    # An asymmetric tolerance: its centre, +5 um, is aimed at.
    ({1: 0.0}, {1: (0.0, 0.01)}, -0.005),
])
def test_the_aim_leaves_every_feature_the_most_margin(levels, tolerances, expected) -> None:
    assert aim(levels, tolerances) == pytest.approx(expected)


def test_coming_back_to_the_first_feature_of_the_next_part_is_no_difference() -> None:
    """30 um of wear a part: the differences across a part's end would read 30 um."""
    agree = FeatureAgreement()
    measure(agree, 12, {1: 0.0, 2: 0.0}, wear_um_per_part=30.0, noise_um=0.3)
    assert agree.disagreement(bound_mm=0.002) == ""
    assert agree.relative_levels()[2] == pytest.approx(0.0, abs=0.0005)
