"""The vectorised RINEX signal reader against the line-by-line one (issue 29 item 4): the same table,
to the bit, on every real observation file of the shared data, and the same errors on bad records."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from _rinex_edit import edited_copy as _edited
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import rinex_signals as rs
from cdgps_cli.io._fixed_width import Unsupported, decimal_fields, flag_digits

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
OBS_FILES = sorted(p for p in SHARED.rglob("*") if p.is_file() and p.name.lower().endswith(("o", ".obs", ".crx")))
GLO_K = {f"R{i:02d}": 0 for i in range(1, 33)}


def _fast_only(path, names):
    """The vectorised reader's table, without the fallback (raises Unsupported if it would fall back)."""
    lines, hdr, end, data = rs._observation_header(path)
    return rs._fast_table(lines, end + 1, hdr, rs._columns(hdr, list(names), path), path, data, GLO_K)


def _both(path, names):
    out = []
    for fast in (False, True):
        rs.FAST_PARSE = fast
        try:
            out.append(rs.read_rinex_signals(path, names, glonass_k=GLO_K))
        finally:
            rs.FAST_PARSE = True
    return out


def test_every_shared_file_is_found():
    assert len(OBS_FILES) >= 10, OBS_FILES


@pytest.mark.parametrize("path", OBS_FILES, ids=lambda p: p.name)
def test_identical_tables_on_real_files(path):
    (h_old, old), (h_new, new) = _both(path, rs.signals_in_file(path))
    assert h_old == h_new
    pd.testing.assert_frame_equal(old, new, check_exact=True)
    assert np.array_equal(np.signbit(old["phase_cycles"]), np.signbit(new["phase_cycles"]))
    assert len(new) > 0
    assert len(_fast_only(path, rs.signals_in_file(path))) == len(new)      # no silent fallback


def _fields(strings, width=14):
    return np.frombuffer("".join(s.ljust(width)[:width] for s in strings).encode("latin-1"),
                         dtype=np.uint8).reshape(len(strings), width).copy()


def test_decimal_fields_match_python_float():
    rng = np.random.default_rng(3)
    vals = np.concatenate([rng.uniform(-3e9, 3e9, 4000), rng.uniform(-10, 10, 2000), [0.0, -0.0]])
    strings = [f"{v:14.3f}" for v in vals] + [f"{v:.5f}".rjust(14) for v in vals[:500]]
    strings += ["  1.", "   .5", "-.25", "+7", "      00012.500", "-0.000", "12345678901234", " "]
    got = decimal_fields(_fields(strings))
    want = np.array([float(s[:14]) if s[:14].strip() else math.nan for s in strings])
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(want))


def test_f14_3_layout_matches_python_float():
    """Fields all in RINEX's F14.3 layout take the place-value path (the general one is tested above)."""
    from cdgps_cli.io._fixed_width import _f14_3

    rng = np.random.default_rng(5)
    vals = np.concatenate([rng.uniform(-9.99e8, 9.99e9, 5000), rng.uniform(-1, 1, 1000), [0.0, -0.0, 9999999999.999]])
    strings = [f"{v:14.3f}" for v in vals] + [" " * 9 + "-.123", " " * 9 + "+.500", " " * 14, "0000000001.001"]
    f = _fields(strings)
    got = _f14_3(f)
    assert got is not None
    want = np.array([float(s) if s.strip() else math.nan for s in strings])
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(want))
    assert _f14_3(_fields(["  12345.67890 "])) is None and _f14_3(_fields(["    1 2345.678"])) is None


@pytest.mark.parametrize("bad", ["1.2D+03", "1 2", "1.2.3", "-", ".", "5-", "+-3", "nan", "1_0", "\t5", "1e5"])
def test_decimal_fields_refuse_what_they_do_not_read_exactly(bad):
    with pytest.raises(Unsupported):
        decimal_fields(_fields([bad]))


def test_flag_digits():
    assert flag_digits(np.frombuffer(b" 0 9x\x1c", dtype=np.uint8)).tolist() == [0, 0, 0, 9, 0, 0]
    with pytest.raises(Unsupported):
        flag_digits(np.frombuffer("\xb2".encode("latin-1"), dtype=np.uint8))


def _phase_col(line, k=0):
    return 3 + 16 * k


@pytest.mark.parametrize("what", ["exponent", "garbage", "truncated", "blank record"])
def test_bad_records_same_outcome_as_line_by_line(tmp_path, what):
    src = SHARED / "rinex-ge" / "Base-static_MO_Spirent.obs"

    def edit(lines, end):
        rec = end + 2                                  # the first satellite record of the first epoch
        c = 3
        if what == "exponent":
            lines[rec] = lines[rec][:c] + f"{float(lines[rec][c:c + 14]):14.6E}".replace("E", "D") + lines[rec][c + 14:]
        elif what == "garbage":
            lines[rec] = lines[rec][:c] + "   12x45.67890" + lines[rec][c + 14:]
        elif what == "truncated":
            del lines[-3:]
        else:
            lines[rec] = ""

    path = _edited(tmp_path, src, edit)
    names = ["G:L1", "E:E1"]
    outcomes = []
    for fast in (False, True):
        rs.FAST_PARSE = fast
        try:
            outcomes.append(rs.read_rinex_signals(path, names)[1])
        except CdgpsError as exc:
            outcomes.append(str(exc))
        finally:
            rs.FAST_PARSE = True
    if isinstance(outcomes[0], str):
        assert outcomes[0] == outcomes[1]
        assert str(path) in outcomes[0]
    else:
        pd.testing.assert_frame_equal(outcomes[0], outcomes[1], check_exact=True)


@pytest.mark.parametrize("variant", ["crlf", "bom", "no final newline"])
def test_line_endings_and_bom(tmp_path, variant):
    src = SHARED / "real-pairs" / "geonet-car" / "3034265G.21O"
    data = src.read_bytes()
    if variant == "crlf":
        data = data.replace(b"\n", b"\r\n")
    elif variant == "bom":
        data = b"\xef\xbb\xbf" + data
    else:
        data = data.rstrip(b"\n")
    path = tmp_path / src.name
    path.write_bytes(data)
    (_, old), (_, new) = _both(path, ["G:L1", "G:L2", "E:E1"])
    pd.testing.assert_frame_equal(old, new, check_exact=True)
    (_, ref), _ = _both(src, ["G:L1", "G:L2", "E:E1"])
    pd.testing.assert_frame_equal(ref, new, check_exact=True)
    assert len(_fast_only(path, ["G:L1", "G:L2", "E:E1"])) == len(new)


@pytest.mark.parametrize("variant", ["swapped", "duplicated"])
def test_epochs_out_of_order_sort_as_before(tmp_path, variant):
    """Rows sort by (time, signal, satellite), stable over the file's order, as the pandas sort did."""
    src = SHARED / "real-pairs" / "mosaic-static" / "rover.obs"
    lines = src.read_text(encoding="latin-1").split("\n")
    ep = [i for i, ln in enumerate(lines) if ln.startswith(">")]
    a, b, c = ep[3], ep[4], ep[5]
    if variant == "swapped":
        lines = lines[:a] + lines[b:c] + lines[a:b] + lines[c:]
    else:
        lines = lines[:c] + lines[a:b] + lines[c:]
    path = tmp_path / "rover.obs"
    path.write_text("\n".join(lines), encoding="latin-1")
    names = ["G:L1", "R:G1", "E:E1", "C:B1I"]
    (_, old), (_, new) = _both(path, names)
    pd.testing.assert_frame_equal(old, new, check_exact=True)
    assert len(_fast_only(path, names)) == len(new)


def test_row_chunks_keep_file_order_and_dtypes():
    """Scalar rows (record by record) and bulk chunks interleave in the order they were added."""
    from cdgps_cli.io import rinex

    rows = rinex._new_rows()
    scalar = {"t": 1.0, "sat": "G01", "phase": 1.5, "lli": 1, "ssi": 7, "code": 2.5, "snr": 40.0, "clk": 0.0, "flag": 0}
    for k, v in scalar.items():
        rows[k].append(v)
    rinex._flush_rows(rows)
    rows["_chunks"].append({"t": np.array([2.0, 2.0]), "sat": np.array(["G02", "G03"], dtype=object),
                            "phase": np.array([3.0, np.nan]), "lli": np.array([0, 2]), "ssi": np.array([5, 0]),
                            "code": np.array([np.nan, 4.0]), "snr": np.array([41.0, 42.0]),
                            "clk": np.array([0.1, 0.1]), "flag": np.array([0, 0])})
    for k, v in scalar.items():
        rows[k].append(v + 2 if k == "t" else v)
    out = rinex._rows_arrays(rows)
    assert out["t"].tolist() == [1.0, 2.0, 2.0, 3.0]
    assert out["sat"].tolist() == ["G01", "G02", "G03", "G01"]
    assert out["sat"].dtype == object and out["lli"].dtype == np.int64 and out["t"].dtype == np.float64
    empty = rinex._rows_arrays(rinex._new_rows())
    assert all(len(v) == 0 for v in empty.values()) and empty["flag"].dtype == np.int64
