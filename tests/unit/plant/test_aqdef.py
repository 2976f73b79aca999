"""The AQDEF transfer file, read back by a reader written here from the format's description
(a K-field line is ``K<4 digits>[/<index>] <value>``; value lines start with K0001 and the
K00xx lines after one belong to it), not by the writer's code."""

from __future__ import annotations

import math
import re
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from service.plant.aqdef import (
    AqdefPart,
    AqdefValue,
    aqdef_text,
    encoded,
    from_archive,
    from_parts,
)

K_LINE = re.compile(r"^K(\d{4})(?:/(\d+))? (.*)$")


def read_aqdef(text: str) -> tuple[dict[str, str], list[dict[str, str]]]:
    """(header fields by K number, values as dicts of K number -> text), one value a part:
    the first characteristic's fields by K number, characteristic i's as ``K/i``."""
    header: dict[str, str] = {}
    values: list[dict[str, str]] = []
    assert text.endswith("\r\n")
    for line in text.split("\r\n")[:-1]:
        m = K_LINE.match(line)
        assert m, f"not a K-field line: {line!r}"
        key, index, value = m.groups()
        name = key if index in (None, "1") else f"{key}/{index}"
        if key.startswith("00") and key != "0100":
            if key == "0001" and (not values or name in values[-1]):
                values.append({})  # the next value (a characteristic's comes with the part's)
            assert values, f"{line!r} before any K0001"
            assert name not in values[-1], f"{line!r}: twice for one part"
            values[-1][name] = value
        else:
            header[name] = value
    if "0100" in header:
        n = int(header["0100"])
        assert all(f"2001/{i}" in header for i in range(2, n + 1)), header
    return header, values


def part(**kw) -> AqdefPart:
    return AqdefPart(**{"part_number": "4711-A", "part_description": "drive shaft",
                        "characteristic_number": "1", "characteristic_description": "diameter",
                        "nominal_mm": 30.0, "lower_limit_mm": 29.98, "upper_limit_mm": 30.02,
                        "gauge_id": "lathe-7", **kw})


def test_header_and_value_fields() -> None:
    t = time.mktime((2026, 11, 29, 14, 5, 9, 0, 0, -1))
    header, values = read_aqdef(aqdef_text(part(), [AqdefValue(30.00123, t, "812", "cal3")]))
    assert header == {"0100": "1", "1001": "4711-A", "1002": "drive shaft", "2001": "1",
                      "2002": "diameter", "2022": "4", "2101": "30.0000", "2110": "29.9800",
                      "2111": "30.0200", "2142": "mm",
                      "4090": "1", "4092": "the gauge (unattended)",  # the catalogues
                      "4070": "1", "4072": "lathe-7"}
    assert values == [{"0001": "30.0012", "0004": "29.11.2026/14:05:09", "0005": "0",
                       "0006": "cal3", "0008": "1", "0012": "1", "0014": "812"}]
    text = aqdef_text(part(), [])
    assert "K1001/1 4711-A\r\n" in text and "K1002/1 drive shaft\r\n" in text  # indexed


def test_no_nominal_leaves_the_limits_out_and_nan_values_out() -> None:
    header, values = read_aqdef(aqdef_text(
        part(nominal_mm=None, lower_limit_mm=None, upper_limit_mm=None),
        [AqdefValue(math.nan, 0.0, "1"), AqdefValue(30.0, 0.0, "2")]))
    assert not {"2101", "2110", "2111"} & set(header)
    assert [v["0014"] for v in values] == ["2"]


def test_text_fields_stay_on_one_line() -> None:
    header, _ = read_aqdef(aqdef_text(part(part_description="a\r\nb\tc"), []))
    assert header["1002"] == "a b c"


@given(st.lists(st.floats(1.0, 500.0, allow_nan=False), min_size=1, max_size=50),
       st.floats(0.0, 2e9))
def test_values_round_trip_to_the_written_resolution(diameters: list[float],
                                                     t0: float) -> None:
    vals = [AqdefValue(d, t0 + i, str(i)) for i, d in enumerate(diameters)]
    _, read = read_aqdef(aqdef_text(part(), vals))
    assert len(read) == len(diameters)
    for v, d in zip(read, diameters, strict=True):  # 4 decimals: within half of 0.1 um
        assert abs(float(v["0001"]) - d) <= 0.5e-4 + 1e-9
    assert [v["0014"] for v in read] == [str(i) for i in range(len(diameters))]


def row(seq: int, status: str = "ok", fused: float | None = 30.001,
        nominal: float | None = 30.0, tir: float | None = None,
        ront: float | None = None) -> dict:
    return {"seq": seq, "wall_time": 1.7e9 + seq, "status": status, "diameter_mm": 30.002,
            "uncertainty_mm": 0.002, "fused_diameter_mm": fused, "deviation_mm": 0.001,
            "in_tolerance": 1, "calibration_id": 2, "nominal_mm": nominal,
            "tol_lower_mm": -0.02, "tol_upper_mm": 0.03, "tir_mm": tir, "ront_mm": ront}


def test_from_archive_takes_good_rows_fused_first_and_the_latest_feature() -> None:
    rows = [row(1), row(2, status="no_stripe"), row(3, fused=None), row(4, nominal=31.0)]
    header, values = read_aqdef(from_archive(rows, "g", "P-1", "bearing seat"))
    assert header["1001"] == "P-1" and header["2002"] == "bearing seat"
    assert (header["2101"], header["2110"], header["2111"]) == ("31.0000", "30.9800",
                                                                "31.0300")
    assert [(v["0014"], v["0001"], v["0006"]) for v in values] == [
        ("1", "30.0010", "cal2"), ("3", "30.0020", "cal2"), ("4", "30.0010", "cal2")]


def test_run_out_and_roundness_are_characteristics_2_and_3_where_known() -> None:
    rows = [row(1), row(2, tir=0.0123), row(3, tir=0.0121, ront=0.0041)]
    header, values = read_aqdef(from_archive(rows, "g", max_tir_mm=0.02))
    assert header["0100"] == "3"
    assert (header["2002/2"], header["2101/2"], header["2111/2"], header["2142/2"]) == (
        "run-out TIR", "0.0000", "0.0200", "mm")
    assert header["2002/3"] == "roundness RONt" and "2111/3" not in header
    assert [v.get("0001/2") for v in values] == [None, "0.0123", "0.0121"]
    assert [v.get("0001/3") for v in values] == [None, None, "0.0041"]
    assert values[2]["0014/3"] == "3" and values[2]["0006/2"] == "cal2"


def test_without_run_out_the_file_has_the_diameter_alone() -> None:
    header, values = read_aqdef(from_archive([row(1), row(2)], "g", max_tir_mm=0.02))
    assert header["0100"] == "1" and not [k for k in header if "/" in k]
    assert all("0001/2" not in v for v in values)
    # roundness alone known: it is characteristic 2
    header, values = read_aqdef(from_archive([row(1, ront=0.002)], "g"))
    assert header["0100"] == "2" and header["2002/2"] == "roundness RONt"
    assert values[0]["0001/2"] == "0.0020"


def test_ten_parts_of_four_features_parse_back_per_characteristic_and_part() -> None:
    job = {"part_number": "SH-4711", "name": "stepped shaft", "features": [
        {"number": n, "name": name, "nominal_mm": nom, "tol_upper_mm": 0.02,
         "tol_lower_mm": -0.01, "tool": 1 + (n > 2)}
        for n, name, nom in ((1, "journal", 30.0), (2, "seat", 25.0), (3, "collar", 40.0),
                             (4, "slender end", 18.0))]}
    parts = [{"serial": f"SH-4711-{100 + k}", "time": 1.8e9 + 60 * k, "verdict": "ok",
              "features": [{"feature": f["number"], "diameter_mm": f["nominal_mm"] + k / 1e4}
                           for f in job["features"] if not (k == 7 and f["number"] == 3)]}
             for k in range(10)]
    text = from_parts(parts, job, "lathe-7")
    header, _ = read_aqdef(text)
    assert header["0100"] == "4" and header["1001"] == "SH-4711"
    for i, f in enumerate(job["features"], 1):
        key = "" if i == 1 else f"/{i}"
        assert header[f"2001{key}"] == str(f["number"]) and header[f"2002{key}"] == f["name"]
        assert float(header[f"2101{key}"]) == f["nominal_mm"]
        assert float(header[f"2110{key}"]) == pytest.approx(f["nominal_mm"] - 0.01)
        assert float(header[f"2111{key}"]) == pytest.approx(f["nominal_mm"] + 0.02)
    # Every value line by characteristic and part (K0014), as a reader who trusts no order.
    values: dict[tuple[str, str], float] = {}
    lines = text.split("\r\n")
    for j, line in enumerate(lines):
        m = K_LINE.match(line)
        if m and m.group(1) == "0001":
            i = m.group(2)
            ident = next(x for x in lines[j:] if x.startswith(f"K0014/{i} "))
            values[(i, ident.split(" ", 1)[1])] = float(m.group(3))
    assert len(values) == 10 * 4 - 1  # part 107 went by without its collar
    for k in range(10):
        for i, f in enumerate(job["features"], 1):
            got = values.get((str(i), f"SH-4711-{100 + k}"))
            if k == 7 and i == 3:
                assert got is None
            else:
                assert got == pytest.approx(f["nominal_mm"] + k / 1e4, abs=1e-9)


def test_text_is_cut_to_its_fields_lengths_and_written_in_cp1252_naming_the_rest() -> None:
    text = aqdef_text(part(part_number="P" * 47,
                           part_description="Welle Ø30 \u2013 \u7b2c\u4e00"), [])
    header, _ = read_aqdef(text)
    assert header["1001"] == "P" * 30  # K1001: 30 characters
    data = encoded(text)
    back = data.decode("cp1252")
    assert "Welle Ø30 \u2013 " in back  # what cp1252 holds, as it is
    assert "\\N{CJK UNIFIED IDEOGRAPH-7B2C}" in back and "?" not in back  # the rest named


def feature_row(seq: int, feature: int | None, diameter: float, nominal: float | None,
                tol: float = 0.012) -> dict:
    return {**row(seq, fused=diameter, nominal=nominal), "feature": feature,
            "tol_lower_mm": -tol, "tol_upper_mm": tol}


STEPPED = [(1, 30.0, 0.020), (2, 26.0, 0.012), (3, 34.0, 0.025), (4, 28.0, 0.015)]


def test_an_archive_of_a_stepped_shaft_has_a_characteristic_a_feature_with_its_limits() -> None:
    rows = [feature_row(10 * k + n, n, nominal + 0.001 * (k % 3), nominal, tol)
            for k in range(6) for n, nominal, tol in STEPPED]
    header, values = read_aqdef(from_archive(rows, "g", "DEMO-4"))
    assert header["0100"] == "4"
    for i, (n, nominal, tol) in enumerate(STEPPED, 1):
        key = "" if i == 1 else f"/{i}"
        assert header[f"2002{key}"] == f"diameter feature {n}"
        assert (float(header[f"2110{key}"]), float(header[f"2111{key}"])) == \
            pytest.approx((nominal - tol, nominal + tol))
    inside = 0
    for v in values:
        for k, x in v.items():
            if k.startswith("0001"):
                i = 1 if k == "0001" else int(k.split("/")[1])
                key = "" if i == 1 else f"/{i}"
                assert float(header[f"2110{key}"]) <= float(x) <= float(header[f"2111{key}"])
                inside += 1
    assert inside == len(rows)  # every row a value of its own feature, none out


def test_rows_of_no_feature_keep_the_one_characteristic_they_always_had() -> None:
    rows = [feature_row(1, None, 30.001, 30.0), feature_row(2, 2, 26.001, 26.0)]
    header, values = read_aqdef(from_archive(rows, "g"))
    assert header["0100"] == "2" and header["2002"] == "diameter"
    assert header["2002/2"] == "diameter feature 2" and header["2101/2"] == "26.0000"
    assert [v.get("0001") for v in values] == ["30.0010"]
    assert values[0]["0001/2"] == "26.0010"


def test_one_feature_alone_keeps_the_characteristics_name() -> None:
    rows = [feature_row(1, 1, 30.001, 30.0), feature_row(2, 1, 30.002, 30.0)]
    header, values = read_aqdef(from_archive(rows, "g", characteristic="bearing seat"))
    assert (header["0100"], header["2002"]) == ("1", "bearing seat")
    assert [v["0001"] for v in values] == ["30.0010", "30.0020"]
