"""When a tool's features agree: pairwise differences of consecutive measurements, which
the tool's wear and offsets cancel from, against hand-made truth."""

from __future__ import annotations

import numpy as np
import pytest

from service.compensation.combine import PAIRS_NEEDED, FeatureAgreement


def measure(agree: FeatureAgreement, parts: int, bias_um: dict[int, float],
            wear_um_per_part: float, noise_um: float = 0.5, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    for k in range(parts):
        for feature, bias in bias_um.items():
            dev = (wear_um_per_part * k + bias + rng.normal(0.0, noise_um)) / 1000
            agree.add(feature, dev, noise_um / 1000)


@pytest.mark.parametrize("wear", [0.0, 5.0])  # however fast the tool wears
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
    agree.add(1, 0.0, 0.0005)
    agree.add(2, 0.020, 0.0005)  # one difference of +20 um
    agree.add(1, 0.0, 0.0005)  # two
    assert PAIRS_NEEDED == 3 and agree.disagreement(0.004) == ""
    agree.applied()  # an offset of +50 um reaches the parts between the two
    agree.add(2, 0.070, 0.0005)
    assert agree.disagreement(0.004) == ""  # that pair was not counted
    agree.add(1, 0.050, 0.0005)  # three
    assert "features 1 and 2 disagree by +20" in agree.disagreement(0.004)


def test_one_feature_alone_never_disagrees() -> None:
    agree = FeatureAgreement()
    measure(agree, 10, {3: 50.0}, 2.0)
    assert agree.disagreement(0.001) == ""
