"""The register map: encoding in both word orders, units, the bank, the write checks."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.plc.registers import (
    BY_NAME,
    NO_VALUE,
    REGISTERS,
    SIZE,
    RegisterBank,
    RegisterType,
    WordOrder,
    from_words,
    mm_to_units,
    to_words,
    units_to_mm,
)
from drivers.plc.server import check_write


@given(st.integers(-(1 << 31), (1 << 31) - 1), st.sampled_from(list(WordOrder)))
def test_int32_round_trip(value, order) -> None:
    words = to_words(value, RegisterType.I32, order)
    assert all(0 <= w <= 0xFFFF for w in words)
    assert from_words(words, RegisterType.I32, order) == value


def test_word_order_of_the_test_pattern() -> None:
    assert to_words(0x12345678, RegisterType.U32, WordOrder.BIG) == [0x1234, 0x5678]
    assert to_words(0x12345678, RegisterType.U32, WordOrder.LITTLE) == [0x5678, 0x1234]
    assert to_words(NO_VALUE, RegisterType.I32, WordOrder.BIG) == [0x8000, 0x0000]


@pytest.mark.parametrize(("kind", "value"), [(RegisterType.U16, 70000), (RegisterType.U16, -1),
                                             (RegisterType.I32, 1 << 31), (RegisterType.U32, -1)])
def test_out_of_range_values_are_refused(kind, value) -> None:
    with pytest.raises(ValueError, match="fit"):
        to_words(value, kind, WordOrder.BIG)


def test_units() -> None:
    assert mm_to_units(30.0) == 300_000
    assert mm_to_units(-0.0056) == -56
    for bad in (None, math.nan, math.inf, 1e9):
        assert mm_to_units(bad) == NO_VALUE
    assert units_to_mm(NO_VALUE) is None
    assert units_to_mm(300_001) == pytest.approx(30.0001)


def test_map_is_contiguous_and_bank_starts_sane() -> None:
    assert sum(r.kind.words for r in REGISTERS) == SIZE
    for order in WordOrder:
        bank = RegisterBank(order)
        assert bank.get("test_pattern") == 0x12345678
        assert bank.get("diameter") == NO_VALUE and bank.get("heartbeat") == 0
        bank.set_many({"diameter": 300_123, "measurement_seq": 7})
        assert bank.get("diameter") == 300_123 and bank.get("measurement_seq") == 7


@pytest.mark.parametrize(("address", "values", "reason"), [
    (4, [1], "read-only"),
    (15, [1], "whole entry"),
    (14, [0, 1, 0], "whole entry"),
    (20, [7], "command code"),
    (16, [0xFFFF, 0xFFFF], "tol_upper"),    # -1: an upper tolerance below nominal
    (18, [0, 5], "tol_lower"),              # +5: a lower tolerance above nominal
    (14, [0xFFFF, 0xFF00], "nominal"),      # negative nominal
])
def test_bad_writes_are_refused_with_reason(address, values, reason) -> None:
    entries, why = check_write(address, values, WordOrder.BIG)
    assert not entries and reason in why


def test_good_write_decodes_every_entry() -> None:
    entries, why = check_write(14, [0x0004, 0x93E0, 0, 200, 0xFFFF, 0xFF38, 2],
                               WordOrder.BIG)
    assert why == ""
    assert [(r.name, v) for r, v in entries] == [("nominal", 300_000), ("tol_upper", 200),
                                                  ("tol_lower", -200), ("command", 2)]
    assert all(BY_NAME[n].writable for n in ("nominal", "tol_upper", "tol_lower", "command"))
