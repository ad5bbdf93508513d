"""The readers' table builder (:func:`cdgps_cli.io.rinex._frame`) hands numeric and str columns to pandas
as its constructor would store them, skipping the constructor's per-column checks (issue 29 item 4):
the tables must be the constructor's to the bit — values, dtypes, column index, row index, block layout —
for str, float, int, bool and empty tables, for anything else (the checked path), and for every
reader's table of the shared and test data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.io import rinex, rinex_signals, ubx

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
TEST_DATA = Path(__file__).resolve().parents[1] / "data"
GLO_K = {f"R{i:02d}": 0 for i in range(1, 33)}
OBS_FILES = sorted(p for d in (SHARED, TEST_DATA) if d.exists() for p in d.rglob("*")
                   if p.is_file() and (p.name.lower().endswith(("o", ".obs", ".crx"))
                                       or p.suffix == ".rnx" and p.read_bytes()[20:21] == b"O"))
UBX_FILES = sorted(p for d in (SHARED, TEST_DATA) if d.exists() for p in d.rglob("*")
                   if p.is_file() and p.name.lower().endswith((".ubx", ".log")))


def _blocks(df: pd.DataFrame) -> list:
    """The frame's blocks: dtype and column positions of each (the layout the constructor chose)."""
    return [(str(b.dtype), b.mgr_locs.as_array.tolist()) for b in df._mgr.blocks]


def _same_table(got: pd.DataFrame, ref: pd.DataFrame, blocks: bool = True) -> None:
    """``got`` is ``ref``: values to the bit, dtypes, column and row index, element types and (``blocks``)
    block layout (the dict constructor without a copy leaves columns of one dtype in separate blocks:
    the layout is compared with ``_frame``'s checked path, not with the constructor)."""
    pd.testing.assert_frame_equal(got, ref, check_exact=True)
    assert list(got.dtypes) == list(ref.dtypes)
    assert got.columns.dtype == ref.columns.dtype and type(got.index) is type(ref.index)
    if blocks:
        assert _blocks(got) == _blocks(ref)
    for c in got.columns:                                   # element types of object / str columns too (a numeric
        if got[c].dtype == object:                          # column's dtype, compared above, fixes its elements' type)
            assert [type(v) for v in got[c].array] == [type(v) for v in ref[c].array], c


def _checked_frame(columns: dict, copy: bool = False) -> pd.DataFrame:
    """``_frame`` by pandas' checked path only (``verify_integrity=True``), as before the fast path."""
    real = rinex._stored_arrays
    rinex._stored_arrays = lambda arrays: None
    try:
        return rinex._frame(columns, copy=copy)
    finally:
        rinex._stored_arrays = real


def _obj(values) -> np.ndarray:
    a = np.empty(len(values), dtype=object)
    a[:] = values
    return a


TABLES = {
    "str_float_int": {"t": np.arange(5.0), "sat": _obj(["G01", "R02", "E11", "C30", "G01"]),
                      "lli": np.array([0, 1, 0, 2, 7], dtype=np.int64)},
    "float_only": {"a": np.array([np.nan, -0.0, 1e300]), "b": np.array([1.5, 2.0, np.inf], dtype=np.float32)},
    "int_bool_uint": {"i": np.array([-1, 2], dtype=np.int32), "u": np.array([0, 255], dtype=np.uint8),
                      "b": np.array([True, False])},
    "two_str": {"sat": _obj(["G05", "é\udcff"]), "signal": _obj(["G:L1", ""]), "x": np.zeros(2)},
    "one_row": {"sat": _obj(["G05"]), "x": np.ones(1)},
    "empty": {"t": np.zeros(0), "sat": _obj([]), "lli": np.zeros(0, dtype=np.int64)},
    "empty_numeric": {"t": np.zeros(0), "lli": np.zeros(0, dtype=np.int64)},
    # not taken by the fast path: the constructor's checks decide
    "str_and_none": {"sat": _obj(["G01", None]), "x": np.zeros(2)},
    "str_and_nan": {"sat": _obj(["G01", np.nan]), "x": np.zeros(2)},
    "mixed_objects": {"o": _obj([1, "a"]), "x": np.zeros(2)},
    "bytes_objects": {"o": _obj([b"G01", b"G02"])},
    "float_objects": {"o": _obj([1.0, 2.5])},
    "unicode_array": {"s": np.array(["G01", "G02"]), "x": np.zeros(2)},
    "unicode_wide": {"s": np.array(["G01", "é\udcff", ""]), "t": np.array(["a", "bb", "ccc"], dtype="<U7")},
    "unicode_empty": {"s": np.array([], dtype="<U3"), "x": np.zeros(0)},
    "big_endian": {"x": np.arange(3, dtype=">f8"), "i": np.arange(3, dtype=">i8")},
    "datetime": {"d": np.array(["2021-01-01", "2021-01-02"], dtype="datetime64[ns]")},
    "list_column": {"x": [1.0, 2.0], "y": np.zeros(2)},
    "str_subclass": {"s": _obj([np.str_("G01"), "G02"])},
}


@pytest.mark.parametrize("name", TABLES)
@pytest.mark.parametrize("copy", [False, True])
def test_frame_is_the_constructors_table(name, copy):
    cols = TABLES[name]
    got = rinex._frame(cols, copy=copy)
    _same_table(got, pd.DataFrame(cols, copy=copy), blocks=False)
    _same_table(got, _checked_frame(cols, copy=copy))


@pytest.mark.parametrize("name", TABLES)
def test_frame_as_given_is_the_constructors_table_without_copy(name):
    """_frame_as_given: ``pd.DataFrame(columns, copy=False)``'s table, block for block (one per column), and its
    blocks hold the numeric arrays given, as the constructor's do."""
    cols = TABLES[name]
    got, ref = rinex._frame_as_given(cols), pd.DataFrame(cols, copy=False)
    _same_table(got, ref)
    for c, v in cols.items():
        if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            assert np.shares_memory(got[c].to_numpy(), v) == np.shares_memory(ref[c].to_numpy(), v), c


def test_fast_path_taken_for_numbers_and_str_only():
    assert rinex._stored_arrays(list(TABLES["str_float_int"].values())) is not None
    assert rinex._stored_arrays(list(TABLES["int_bool_uint"].values())) is not None
    assert rinex._stored_arrays(list(TABLES["unicode_array"].values())) is not None
    for name in ("empty", "str_and_none", "mixed_objects", "bytes_objects", "big_endian", "list_column"):
        assert rinex._stored_arrays(list(TABLES[name].values())) is None, name


def test_frame_copy_owns_its_arrays_and_no_copy_keeps_them():
    cols = {"t": np.arange(3.0), "sat": _obj(["G01", "G02", "G03"])}
    owned = rinex._frame(cols, copy=True)
    cols["t"][0] = 99.0
    cols["sat"][0] = "X"
    assert owned["t"].iloc[0] == 0.0 and owned["sat"].iloc[0] == "G01"


def test_frame_refuses_mismatched_lengths_as_the_constructor():
    cols = {"a": np.arange(3.0), "b": np.arange(2.0)}
    with pytest.raises(ValueError) as ref:
        pd.DataFrame(cols)
    with pytest.raises(ValueError) as got:
        rinex._frame(cols)
    assert str(got.value) == str(ref.value)


@pytest.mark.parametrize("seed", range(4))
def test_random_tables(seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        n = int(rng.integers(0, 40))
        cols = {}
        for k in range(int(rng.integers(1, 8))):
            kind = rng.choice(["f8", "f4", "i8", "i4", "u1", "?", "str", "U3"])
            if kind == "str":
                cols[f"c{k}"] = _obj([f"G{int(v):02d}" for v in rng.integers(0, 40, n)])
            elif kind == "U3":
                cols[f"c{k}"] = np.array([f"R{int(v)}" for v in rng.integers(0, 40, n)], dtype="<U3")
            else:
                cols[f"c{k}"] = (rng.normal(size=n) * 100).astype(kind)
        got = rinex._frame(cols)
        _same_table(got, pd.DataFrame(cols), blocks=False)
        _same_table(got, _checked_frame(cols))
        _same_table(rinex._frame_as_given(cols), pd.DataFrame(cols, copy=False))


@pytest.mark.parametrize("path", OBS_FILES, ids=lambda p: p.parent.name + "/" + p.name)
def test_rinex_readers_tables_as_by_the_checked_path(path, monkeypatch):
    """Every RINEX observation file of the shared and test data: both readers' tables (fast and line-by-line
    bodies) are those pandas' checked construction gives."""
    got, ref = [], []
    for out, stored in ((got, rinex._stored_arrays), (ref, lambda arrays: None)):
        monkeypatch.setattr(rinex, "_stored_arrays", stored)
        for fast in (True, False):
            monkeypatch.setattr(rinex, "FAST_PARSE", fast)
            monkeypatch.setattr(rinex_signals, "FAST_PARSE", fast)
            try:
                out.append(rinex.read_rinex_obs(path, gps_l1_optional=True))
            except Exception as exc:                    # noqa: BLE001 (a file the reader refuses: the same error)
                out.append(repr(exc))
            try:
                names = rinex_signals.signals_in_file(path)
                out.append(rinex_signals.read_rinex_signals(path, names, glonass_k=GLO_K) if names else "no signals")
            except Exception as exc:                    # noqa: BLE001
                out.append(repr(exc))
    assert any(not isinstance(g, str) for g in got)
    for g, r in zip(got, ref, strict=True):
        if isinstance(r, str):
            assert g == r
            continue
        assert g[0] == r[0]
        _same_table(g[1], r[1])


@pytest.mark.parametrize("path", UBX_FILES, ids=lambda p: p.parent.name + "/" + p.name)
def test_ubx_reader_tables_as_by_the_checked_path(path, monkeypatch):
    """Every u-blox log of the shared and test data: the observation table (built by ``_frame_as_given``) and
    the ephemeris table (by ``_frame``) are those of pandas' checked construction, block layout included."""
    out = []
    for stored in (rinex._stored_arrays, lambda arrays: None):
        monkeypatch.setattr(rinex, "_stored_arrays", stored)
        ubx._LAST_DECODED.clear()
        try:
            out.append(ubx.read_ubx_log(path))
        except Exception as exc:                        # noqa: BLE001
            out.append(repr(exc))
    got, ref = out
    if isinstance(ref, str):
        assert got == ref
        return
    assert got[0] == ref[0]
    _same_table(got[1], ref[1])
    _same_table(got[2], ref[2])
