"""The solution writers of `cdgps rtk` (review findings): no ``-0.00`` in .pos files, NMEA GGA
sentences within the standard's 82 characters."""

from __future__ import annotations

import numpy as np

from cdgps_cli.io.solution_formats import Q_FIX, Q_FLOAT, nmea_gga_text, pos_text, read_pos

T0 = 1403252400.0


def test_pos_writes_no_negative_zero_ages_or_covariance_roots(tmp_path):
    n = 4
    age = np.array([-0.001, -0.004, 0.0, -0.5])           # rover − base: a base epoch a few ms later
    cov = np.tile(np.diag([1e-4, 1e-4, 4e-4]), (n, 1, 1))
    cov[:, 0, 1] = cov[:, 1, 0] = -1e-10                  # a covariance whose signed root rounds to zero
    text = pos_text(T0 + np.arange(n), np.tile([35.1, 136.9, 104.8], (n, 1)), np.full(n, Q_FIX), np.full(n, 9), cov,
                    age, np.full(n, 5.0), frame="llh", header=["program : test"])
    assert "-0.00 " not in text and " -0.0000" not in text
    p = tmp_path / "s.pos"
    p.write_text(text)
    np.testing.assert_array_equal(read_pos(p)["age_s"], [0.0, 0.0, 0.0, -0.5])


def _checksum_ok(sentence: str) -> bool:
    body, hh = sentence[1:].split("*")
    x = 0
    for ch in body.encode("ascii"):
        x ^= ch
    return f"{x:02X}" == hh


def test_gga_sentences_fit_82_characters_with_their_cr_lf():
    """NMEA 0183's 82 characters count the CR LF: at most 80 from ``$`` to the checksum.  Minutes keep RTKLIB's 7
    decimals where they fit (a two-digit longitude, a height under 100 m), else 6 (1.8 mm); the age is a magnitude
    (a real M8P run wrote 463 of 1201 sentences of 81 characters, the sign of a negative age among them)."""
    lat = np.array([35.134699044, -35.134699044, 0.5, 59.999999999999, 35.1])
    lon = np.array([136.977575471, -136.977575471, -0.5, 179.9999999999, 136.9])
    h = np.array([104.8607, -12.0, 0.0, 8848.1234, -1545.4])
    age = np.array([0.0, -0.01, 1.0, 30.0, 29.96])
    lines = nmea_gga_text(T0 + np.arange(5), lat, lon, h, np.array([Q_FIX, Q_FLOAT, Q_FIX, Q_FIX, Q_FLOAT]),
                          np.array([9, 12, 4, 120, 30]), age).split("\r\n")[:-1]
    assert len(lines) == 5
    for ln in lines:
        f = ln.split(",")
        assert len(ln) <= 80, (len(ln), ln)                 # NMEA 0183, $ to checksum (82 with CR LF)
        assert _checksum_ok(ln)
        assert 5 <= len(f[2].split(".")[1]) <= 7 and 5 <= len(f[4].split(".")[1]) <= 7   # 5 (18 mm): 8848 m, 30 s
        assert not f[13].startswith("-")                    # the age (the field before the station)
    f = lines[0].split(",")                                # a three-digit longitude and 104 m: 6 decimals
    assert f[2] == "3508.081943" and f[3] == "N" and f[4] == "13658.654528" and f[5] == "E" and f[6] == "4"
    assert lines[1].split(",")[13] == "0.0" and lines[2].split(",")[2] == "0030.0000000"   # 7 where they fit
    assert lines[1].split(",")[3] == "S" and lines[1].split(",")[5] == "W"
    deg = int(float(f[2]) // 100) + (float(f[2]) % 100) / 60
    assert abs(deg - lat[0]) < 0.5e-6 / 60                   # half the last decimal of 6 (1e-6 min)
    assert lines[3].split(",")[7] == "99"


def test_csv_text_is_pandas_to_csv_byte_for_byte():
    """The rtk CSV writer gives pandas' ``to_csv(index=False, float_format="%.4f")`` bytes: NaN empty,
    -0.0 and rounding to -0.0000, integers, booleans, large values, no rows; infinite values, string
    columns and one-column tables go to pandas itself (the same bytes by construction)."""
    import io

    import pandas as pd

    from cdgps_cli.io.solution_formats import csv_text

    rng = np.random.default_rng(3)
    x = rng.normal(0, 1e3, 50)
    x[[1, 7]] = np.nan
    x[[2, 3, 4]] = (-0.0, -0.00004, 0.00005)
    cases = [
        {"t": np.arange(50) * 0.1 + 1.4e9, "x": x, "n": rng.integers(-5, 40, 50), "b": rng.random(50) < 0.5,
         "f32": rng.normal(size=50).astype(np.float32), "big": rng.normal(0, 1e12, 50)},
        {"a": np.array([], float), "b": np.array([], np.int64)},
        {"a": np.array([1.0, np.inf]), "b": np.array([1, 2])},
        {"a": np.array([1.0, 2.0]), "s": np.array(["G01", "E02"], dtype=object)},
        {"a": np.array([np.nan, 2.0])},
    ]
    for cols in cases:
        buf = io.StringIO()
        pd.DataFrame(cols).to_csv(buf, index=False, float_format="%.4f")
        assert csv_text(cols, "%.4f") == buf.getvalue()
    assert csv_text({"a": np.array([np.nan, 1.0]), "b": np.array([1, 2])}) == "a,b\n,1\n1.0000,2\n"


def test_pos_time_of_day_out_of_range_names_the_line(tmp_path):
    # a last line at 00:59:61 was read as 01:00:01 (report rtk: exit 0)
    import pytest

    from cdgps_cli.core.errors import CdgpsError

    n = 3
    text = pos_text(T0 + np.arange(n), np.tile([35.1, 136.9, 104.8], (n, 1)), np.full(n, Q_FIX), np.full(n, 9),
                    np.tile(np.eye(3) * 1e-4, (n, 1, 1)), np.zeros(n), np.full(n, 5.0), frame="llh", header=["program : test"])
    lines = text.splitlines()
    last = len(lines) - 1
    lines[last] = lines[last][:17] + "61" + lines[last][19:]
    p = tmp_path / "s.pos"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(CdgpsError, match=rf"s\.pos, line {last + 1}: expected a time .* \(second must be in \[0, 61\), got 61"):
        read_pos(p)
