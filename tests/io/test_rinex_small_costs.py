"""The fixed costs cut for small RINEX files (issue 29 item 4): the epoch-line date fields read in one
integer conversion, few epochs' dates without ``np.unique``, and a RINEX 2 file read once by
``read_rinex_signals`` (the fast RINEX 3 reader declining it hands its bytes on); the same values and
refusals as before."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io import rinex, rinex_body, rinex_signals
from cdgps_cli.io._fixed_width import Unsupported

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
GLO_K = {f"R{i:02d}": 0 for i in range(1, 33)}


def _fields_one_by_one(g):
    return tuple(rinex_body._ints(g[:, a:b]) for a, b in rinex_body._DATE_FIELDS)


def _epoch_lines(rows: list[bytes]) -> np.ndarray:
    return np.frombuffer(b"".join(r.ljust(35)[:35] for r in rows), np.uint8).reshape(-1, 35).copy()


@pytest.mark.parametrize("n", [1, 3, 4, 40])                     # 5·n fields: Python's int and the numpy path
def test_date_fields_in_one_call_as_one_by_one(n):
    rng = np.random.default_rng(n)
    rows = [b"> %4d %2d %2d %2d %2d %10.7f  0 12" % (rng.integers(1980, 2100), rng.integers(1, 13),
                                                     rng.integers(1, 29), rng.integers(0, 24), rng.integers(0, 60),
                                                     rng.random() * 60) for _ in range(n)]
    rows[0] = b"> 2021 09 22 00 00 0.0000000  0 12"                 # zero-padded fields
    g = _epoch_lines(rows)
    got, ref = rinex_body._date_ints(g), _fields_one_by_one(g)
    assert all(a.dtype == np.int64 and np.array_equal(a, b) for a, b in zip(got, ref, strict=True))


@pytest.mark.parametrize("bad", [b"> 2021  9 2x  0  0  0.0000000  0 12", b"> 2021  9    0  0  0.0000000  0 12",
                                 b"> 2021 -9 22  0  0  0.0000000  0 12", b"> 20 1  9 22  0  0  0.0000000  0 12"])
@pytest.mark.parametrize("n", [1, 40])
def test_date_fields_refused_as_one_by_one(bad, n):
    g = _epoch_lines([b"> 2021  9 22  0  0  0.0000000  0 12"] * (n - 1) + [bad])
    with pytest.raises(Unsupported):
        _fields_one_by_one(g)
    with pytest.raises(Unsupported):
        rinex_body._date_ints(g)


@pytest.mark.parametrize("n", [1, 5, 64, 65, 300])              # the dict path (<= 64 epochs) and np.unique's
def test_gps_seconds_few_and_many_epochs(n):
    rng = np.random.default_rng(n)
    days = rng.integers(0, 4, n)                                    # repeated dates, out of order
    y, mo, d = np.full(n, 2020), np.full(n, 2), 27 + days
    mo = np.where(d > 29, 3, mo)
    d = np.where(d > 29, d - 29, d)
    h, mi, sec = rng.integers(0, 24, n), rng.integers(0, 60, n), rng.random(n) * 60
    got = rinex_body._gps_seconds(y, mo, d, h, mi, sec)
    ref = [gps_seconds(*map(int, v[:5]), float(v[5])) for v in zip(y, mo, d, h, mi, sec)]
    assert got.tolist() == ref
    with pytest.raises(Unsupported):
        rinex_body._gps_seconds(np.append(y, 2021), np.append(mo, 2), np.append(d, 29), np.append(h, 0),
                                np.append(mi, 0), np.append(sec, 0.0))


@pytest.mark.skipif(not (SHARED / "rinex" / "demo.10o").exists(), reason="../shared/data absent")
@pytest.mark.parametrize("name", ["demo.10o", "demo3.10o"])
def test_signals_file_read_once(monkeypatch, name):
    """A RINEX 2 file (the fast RINEX 3 reader declines it) and a RINEX 3 file are read from disk once,
    and give the line-by-line reader's table."""
    path = SHARED / "rinex" / name
    names = rinex_signals.signals_in_file(path)
    calls = []
    real = rinex._read_bytes
    monkeypatch.setattr(rinex_signals, "_read_bytes", lambda p: calls.append(p) or real(p))
    monkeypatch.setattr(rinex, "_read_bytes", lambda p: calls.append(p) or real(p))
    info, df = rinex_signals.read_rinex_signals(path, names, glonass_k=GLO_K)
    assert len(calls) == 1
    monkeypatch.setattr(rinex_signals, "FAST_PARSE", False)
    info_ref, ref = rinex_signals.read_rinex_signals(path, names, glonass_k=GLO_K)
    assert df.equals(ref) and list(df.dtypes) == list(ref.dtypes) and info == info_ref


def _epochs_or_refusal(lines, events):
    try:
        return rinex_body.epochs_v3(lines, events=events)
    except Unsupported:
        return None


@pytest.mark.parametrize("name", ["rinex/demo3.10o", "real-pairs/mosaic-static/base.obs", "real-pairs/geonet-car/SEPT265G.21O"])
def test_few_epoch_lines_read_one_by_one_as_the_arrays_read_them(name, monkeypatch):
    """RINEX 3 bodies of 1-8 epochs (the file's first ones, and copies with one byte changed: flags, counts,
    dates, blanks, '>' moved): the line-by-line reading of a few epoch lines gives the arrays, dtypes and
    refusals of the array reading."""
    path = SHARED / name
    if not path.exists():
        pytest.skip(f"{name} not available")
    data, _ = rinex._read_bytes(path)
    _, at = rinex._split_header(data)
    body = data[at:]
    starts = [i for i in range(min(len(body), 200_000)) if body[i] == 62 and (i == 0 or body[i - 1] == 10)][:9]
    rng = np.random.default_rng(7)
    outcomes = {"read": 0, "refused": 0}
    for k in range(1, len(starts)):
        chunk = body[:starts[k]]
        for v in [chunk] + [_one_byte_changed(chunk, starts[:k], rng) for _ in range(16)]:
            lines = rinex_body.BodyLines(data[:at] + v, at)
            for events in ("refuse", "skip"):
                monkeypatch.setattr(rinex_body, "FEW_EPOCHS", 0)
                ref = _epochs_or_refusal(lines, events)
                monkeypatch.setattr(rinex_body, "FEW_EPOCHS", 8)
                got = _epochs_or_refusal(lines, events)
                assert (ref is None) == (got is None)
                outcomes["refused" if ref is None else "read"] += 1
                if ref is not None:
                    assert list(ref) == list(got)
                    for key in ref:
                        assert ref[key].dtype == got[key].dtype
                        np.testing.assert_array_equal(ref[key], got[key])
    assert outcomes["read"] > 10 and outcomes["refused"] > 10


def _one_byte_changed(chunk: bytes, epoch_starts: list, rng) -> bytes:
    """``chunk`` with one byte changed, mostly in an epoch line (its first 40 columns)."""
    b = bytearray(chunk)
    at = int(rng.choice(epoch_starts)) + int(rng.integers(40)) if rng.random() < 0.8 else int(rng.integers(len(b)))
    b[min(at, len(b) - 1)] = int(rng.choice([32, 45, 46, 48, 49, 50, 54, 55, 57, 62, 65, 10]))
    return bytes(b)


@pytest.mark.parametrize("n", [0, 1, 5, 256, 257, 600])
def test_distinct_is_np_unique_with_inverse(n):
    """The satellites' distinct values and indices, by a dict for few records, as ``np.unique`` gives them
    (integer codes of RINEX 3 names; RINEX 2 names as <= 3-character str)."""
    rng = np.random.default_rng(n)
    codes = rng.integers(0x473030, 0x473040, n)
    names = [rng.choice(["G01", "G1", "R24", "R 3", "E11", "S20", "G10"]) for _ in range(n)]
    names = [str(x) for x in names]
    for values, ref in ((codes, np.unique(codes, return_inverse=True)),
                        (names, np.unique(np.array(names, dtype="U3"), return_inverse=True))):
        uniq, inv = rinex_body.distinct(values)
        assert uniq == ref[0].tolist() and [type(u) for u in uniq] == [type(u) for u in ref[0].tolist()]
        np.testing.assert_array_equal(inv, ref[1].ravel())


@pytest.mark.parametrize("seed", range(3))
def test_few_epochs_gps_seconds_as_the_array_path(seed, monkeypatch):
    """Epoch times of up to 16 epochs in Python: the values (to the bit) and refusals (bad date, hour > 23,
    minute > 59) of the array path."""
    rng = np.random.default_rng(seed)
    for n in (0, 1, 3, 16):
        for _ in range(40):
            y = rng.integers(1980, 2100, n)
            mo, d = rng.integers(1, 13, n), rng.integers(1, 32, n)
            h, mi = rng.integers(0, 25, n), rng.integers(0, 61, n)
            sec = np.round(rng.uniform(0, 60, n), int(rng.integers(0, 8)))
            out = []
            for few in (0, 16):
                monkeypatch.setattr(rinex_body, "FEW_DATES", few)
                try:
                    out.append(rinex_body._gps_seconds(y, mo, d, h, mi, sec))
                except Unsupported as exc:
                    out.append(str(exc))
            if isinstance(out[0], str):
                assert isinstance(out[1], str)
            else:
                assert out[0].dtype == out[1].dtype and out[0].tobytes() == out[1].tobytes()


def _few_decimals_by_regex(f):
    """The per-field reading before: the pattern of a decimal number, then ``float``."""
    from cdgps_cli.io._fixed_width import _DECIMAL

    out = []
    for row in f:
        field = row.tobytes()
        if _DECIMAL.fullmatch(field):
            out.append(float(field))
        elif field.strip(b" "):
            raise Unsupported("number")
        else:
            out.append(np.nan)
    return np.array(out, dtype=np.float64)


@pytest.mark.parametrize("width", [0, 1, 3, 11, 14])
def test_few_decimals_by_float_as_by_the_pattern(width):
    """Fields of digits, signs, dots and blanks (and a few other bytes: e, E, _, n, i, tab) in random
    arrangements: one ``float`` per field reads and refuses exactly what the decimal pattern did."""
    from cdgps_cli.io._fixed_width import _few_decimals

    rng = np.random.default_rng(width)
    alphabet = np.frombuffer(b"0123456789+-. " + b"    " + b"012.", np.uint8)
    odd = np.frombuffer(b"eE_ni\t\\", np.uint8)
    outcomes = {"read": 0, "refused": 0}
    for _ in range(3000):
        n = int(rng.integers(1, 4))
        f = alphabet[rng.integers(0, alphabet.size, (n, width))]
        if width and rng.random() < 0.1:
            f[int(rng.integers(n)), int(rng.integers(width))] = odd[int(rng.integers(odd.size))]
        if width and rng.random() < 0.3:                  # right-aligned numbers, as writers write them
            text = f"{rng.uniform(-1e4, 1e4):.{int(rng.integers(0, 4))}f}"[-width:].rjust(width)
            f[0] = np.frombuffer(text.encode(), np.uint8)
        try:
            ref = _few_decimals_by_regex(f)
        except Unsupported:
            ref = None
        try:
            got = _few_decimals(np.ascontiguousarray(f))
        except Unsupported:
            got = None
        assert (ref is None) == (got is None), f.tobytes()
        if ref is not None:
            assert ref.tobytes() == got.tobytes()
        outcomes["refused" if ref is None else "read"] += 1
    assert outcomes["read"] > 50 and (outcomes["refused"] > 50 or width == 0)


def test_reader_tables_are_the_dict_constructors_tables():
    """rinex._frame (the readers' table builder) gives pd.DataFrame(columns, copy=...)'s table: values,
    dtypes (object str arrays -> pandas' str), column index and its dtype, RangeIndex; copy=True owns
    its arrays; an empty column set and mismatched lengths go to the constructor (its table / error)."""
    import numpy as np
    import pandas as pd
    import pytest

    from cdgps_cli.io.rinex import _frame

    cols = {"time_gps_s": np.arange(4.0), "sat": np.array(["G01", "R02", "E11", "C30"], dtype=object),
            "lli": np.array([0, 1, 0, 2], dtype=np.int64), "snr": np.array([np.nan, 1.5, 2.0, 3.0], dtype=np.float32)}
    for copy in (False, True):
        ref, got = pd.DataFrame(cols, copy=copy), _frame(cols, copy=copy)
        pd.testing.assert_frame_equal(got, ref, check_exact=True)
        assert got.columns.dtype == ref.columns.dtype and type(got.index) is type(ref.index)
    owned = _frame(cols, copy=True)
    cols["time_gps_s"][0] = 99.0
    assert owned["time_gps_s"].iloc[0] == 0.0
    pd.testing.assert_frame_equal(_frame({}), pd.DataFrame({}))
    with pytest.raises(ValueError):
        _frame({"a": np.arange(3.0), "b": np.arange(2.0)})


def _random_body(rng) -> tuple[bytes, int]:
    """A header-like prefix and a body of random lines (lengths 0-90, some CRLF, some Latin-1 bytes, with
    or without a final LF): bytes and the body's offset."""
    head = b"x" * int(rng.integers(0, 5)) + b"\n"
    lines = []
    for _ in range(int(rng.integers(1, 90))):
        n = int(rng.integers(0, 91))
        text = bytes(rng.choice(np.frombuffer(b" 0123456789.-G>\xe9", np.uint8), n).tolist())
        lines.append(text + (b"\r" if rng.random() < 0.2 else b""))
    body = b"\n".join(lines) + (b"\n" if rng.random() < 0.7 else b"")
    return head + body, len(head)


@pytest.mark.parametrize("seed", range(6))
def test_few_fields_gathered_in_python_as_by_numpy(seed, monkeypatch):
    """BodyLines.gather of up to FEW_FIELDS fields (sliced in Python) gives the numpy path's bytes, dtype,
    shape and writability: one column or one per line, fields past a line's end, CR endings, width 1-16."""
    rng = np.random.default_rng(seed)
    for _ in range(60):
        data, at = _random_body(rng)
        lines = rinex_body.BodyLines(data, at)
        n = int(rng.integers(0, 65))
        line = rng.integers(0, lines.n, n).astype(np.int64)
        width = int(rng.integers(1, 17))
        col = int(rng.integers(0, 90)) if rng.random() < 0.5 else rng.integers(0, 90, n).astype(np.int64)
        out = []
        for few in (0, 64):
            monkeypatch.setattr(rinex_body, "FEW_FIELDS", few)
            try:
                out.append(lines.gather(line, col, width))
            except Unsupported:
                out.append(None)
        ref, got = out
        assert (ref is None) == (got is None)
        if ref is not None:
            assert got.dtype == ref.dtype and got.shape == ref.shape and got.flags.writeable
            assert got.tobytes() == ref.tobytes()


def test_flag_values_by_tables_as_by_comparisons():
    """flag_values' look-up tables: the values (int64) and refusals of the byte comparisons they replaced."""
    def by_comparisons(ch, use):
        ok = (ch == 32) | ((ch >= 48) & (ch <= 57))
        if not np.all(ok | ~use):
            raise Unsupported("flag")
        return np.where(use & (ch != 32), ch.astype(np.int64) - 48, 0)

    rng = np.random.default_rng(11)
    odd = np.array([32, 48, 49, 57, 58, 47, 0, 255, 65, 13], np.uint8)
    for n in (0, 1, 15, 300):
        for _ in range(300):
            ch = rng.choice(odd if rng.random() < 0.3 else odd[:4], n)
            use = rng.random(n) < 0.7
            out = []
            for f in (by_comparisons, rinex_body.flag_values):
                try:
                    out.append(f(ch, use))
                except Unsupported:
                    out.append(None)
            assert (out[0] is None) == (out[1] is None)
            if out[0] is not None:
                assert out[0].dtype == out[1].dtype and np.array_equal(out[0], out[1])


@pytest.mark.parametrize("version", [2.11, 3.04])
def test_few_record_sats_as_by_integer_codes(version, monkeypatch):
    """record_sats of up to FEW_RECORDS records (distinct 3-byte fields in Python) gives the names, dtypes,
    indices and refusals of the integer-code path: RINEX 2 and 3 satellite fields, blanks, bad systems,
    non-ASCII bytes."""
    rng = np.random.default_rng(int(version * 100))
    good = [b"G05", b"G 5", b" 5 ", b"R24", b"E11", b"C30", b"S20", b"J01", b"G10", b" 12", b"M01", b"I03"]
    bad = [b"X01", b"G5a", b"\xe905", b"  ", b"G  ", b"   "]
    sat_id = lambda s: rinex._sat_id(s, version)                       # noqa: E731
    outcomes = {"read": 0, "refused": 0}
    for n in (0, 1, 3, 22, 256):
        for _ in range(60):
            pool = good + (bad if rng.random() < 0.3 else [])
            raw = np.frombuffer(b"".join(pool[int(i)].ljust(3)[:3] for i in rng.integers(0, len(pool), n)),
                                np.uint8).reshape(n, 3)
            out = []
            for few in (0, 256):
                monkeypatch.setattr(rinex_body, "FEW_RECORDS", few)
                try:
                    out.append(rinex_body.record_sats(raw, sat_id))
                except Unsupported:
                    out.append(None)
            ref, got = out
            assert (ref is None) == (got is None)
            outcomes["refused" if ref is None else "read"] += 1
            if ref is not None:
                assert ref[0].dtype == got[0].dtype and ref[0].tolist() == got[0].tolist()
                assert ref[1].dtype == got[1].dtype and np.array_equal(ref[1], got[1])
    assert outcomes["read"] > 20 and outcomes["refused"] > 20


@pytest.mark.parametrize("seed", range(3))
def test_few_bytes_body_lines_as_numpy(seed, monkeypatch):
    """BodyLines of a body of up to FEW_BYTES bytes (lines found in Python): the starts, lengths (int64),
    count of the numpy path: LF, CRLF, lone CRs, blank lines, no final LF, an offset at or past the end."""
    rng = np.random.default_rng(seed)
    for _ in range(800):
        n = int(rng.integers(0, 300))
        data = bytes(rng.choice(np.frombuffer(b"ab \r\n\n\r>", np.uint8), n).tolist())
        offset = int(rng.integers(0, n + 2))
        out = []
        for few in (-1, 4096):
            monkeypatch.setattr(rinex_body, "FEW_BYTES", few)
            lines = rinex_body.BodyLines(data, offset)
            out.append((lines.start, lines.length, lines.n))
        (s0, l0, n0), (s1, l1, n1) = out
        assert n0 == n1 and s0.dtype == s1.dtype == l0.dtype == l1.dtype == np.int64
        assert np.array_equal(s0, s1) and np.array_equal(l0, l1)


@pytest.mark.parametrize("seed", range(3))
def test_few_v3_satellites_as_by_integer_codes(seed, monkeypatch):
    """read_rinex_signals' satellites of up to FEW_RECORDS RINEX 3 records (3-byte strings) are the integer-code
    path's: names, indices (dtype too), refusals of non-ASCII bytes and blank record lines."""
    rng = np.random.default_rng(seed)
    pool = [b"G05", b"G 5", b"R24", b"E11", b"C 3", b"S20", b"J01", b"G10", b"   ", b"\xe905"]
    for n in (1, 2, 22, 256):
        for _ in range(40):
            fields = [pool[int(i)] for i in rng.integers(0, len(pool) - (rng.random() < 0.7), n)]
            data = b"\n".join(f + b" 123.456" if f.strip() or rng.random() < 0.8 else b"" for f in fields) + b"\n"
            lines = rinex_body.BodyLines(data, 0)
            rec_line = np.arange(n, dtype=np.int64)
            out = []
            for few in (0, 256):
                monkeypatch.setattr(rinex_body, "FEW_RECORDS", few)
                try:
                    out.append(rinex_signals._record_satellites(lines, rec_line, 1, True, None))
                except Unsupported as exc:
                    out.append(str(exc))
            ref, got = out
            if isinstance(ref, str):
                assert got == ref
            else:
                assert got[0] == ref[0] and got[1].dtype == ref[1].dtype and np.array_equal(got[1], ref[1])


def _header_by_apply(path, lines):
    """The header state and END OF HEADER index of applying ``lines[1:]`` one by one (the reference), or the error."""
    hdr = rinex._ObsHeader(path, 3.04, False)
    try:
        end = next((i for i in range(1, len(lines)) if hdr.apply(lines[i], i + 1) == "END OF HEADER"), None)
    except Exception as exc:                                  # noqa: BLE001
        return repr(exc)
    return hdr.info, end


def _header_by_apply_header(path, lines):
    hdr = rinex._ObsHeader(path, 3.04, False)
    try:
        end = hdr.apply_header(lines)
    except Exception as exc:                                  # noqa: BLE001
        return repr(exc)
    return hdr.info, end


def test_apply_header_as_line_by_line():
    """_ObsHeader.apply_header (unread labels passed over) gives the header, END OF HEADER index and errors of
    applying every line: the headers of the test and shared RINEX files, and copies with one header line's
    field changed (malformed numbers, a lost END OF HEADER, continuation lines first)."""
    paths = [p for d in (SHARED, Path(__file__).resolve().parents[1] / "data") if d.exists() for p in sorted(d.rglob("*"))
             if p.is_file() and p.name.lower().endswith(("o", ".obs"))]
    rng = np.random.default_rng(5)
    outcomes = {"read": 0, "refused": 0}
    for path in paths:
        data, _ = rinex._read_bytes(path)
        lines = rinex._split_lines(data[:data.find(b"END OF HEADER") + 20])
        variants = [lines]
        for _ in range(30):
            v = list(lines)
            i = int(rng.integers(1, len(v)))
            at = int(rng.integers(0, 60))
            v[i] = v[i][:at] + str(rng.choice(["x", "9", " ", "-", "."])) + v[i][at + 1:]
            if rng.random() < 0.1:
                v = v[:i] + v[i + 1:]
            variants.append(v)
        for v in variants:
            ref, got = _header_by_apply(path, v), _header_by_apply_header(path, v)
            assert got == ref
            outcomes["refused" if isinstance(ref, str) else "read"] += 1
    assert outcomes["read"] > 20 and outcomes["refused"] > 5, outcomes


def _clocks_by_index(lines, ep, col):
    """The receiver clocks as read before (a NaN array, filled epoch by epoch where the line is longer than col)."""
    clk = np.full(ep.size, np.nan)
    for k in np.flatnonzero(lines.length[ep] > col).tolist():
        s = int(lines.start[ep[k]])
        field = lines.data[s + col:s + int(lines.length[ep[k]])]
        if field.strip():
            try:
                clk[k] = rinex_body.strict_float(field)
            except ValueError:
                raise Unsupported("clock") from None
    return clk


def test_clocks_as_by_index():
    """rinex_body._clocks (one pass over the lines' bounds as lists): the values (bits), NaN for blank or short
    lines, and refusals (nan, inf, exponents are numbers; letters are not) of the indexed reading."""
    rng = np.random.default_rng(2)
    tails = [b"", b"   ", b"  -0.123456789012", b"   0.000000000000", b"1e-3", b"  nan", b" 12_0", b" x", b"+5.", b"  -.5  "]
    for _ in range(400):
        rows = [b"> 2021 09 22 00 00  0.0000000  0  0" + tails[int(i)] for i in rng.integers(0, len(tails), 5)]
        rows = [r[:int(rng.integers(20, len(r) + 1))] if rng.random() < 0.2 else r for r in rows]
        lines = rinex_body.BodyLines(b"\n".join(rows) + b"\n", 0)
        ep = rng.permutation(lines.n)[:int(rng.integers(0, lines.n + 1))].astype(np.int64)
        out = []
        for f in (_clocks_by_index, rinex_body._clocks):
            try:
                out.append(f(lines, ep, 35))
            except Unsupported:
                out.append(None)
        assert (out[0] is None) == (out[1] is None)
        if out[0] is not None:
            assert out[1].dtype == np.float64 and out[0].tobytes() == out[1].tobytes()


def _sat_id_steps(s: str, version: float) -> str:
    """rinex._sat_id as it was: the normalising steps for every field."""
    s = s.rstrip()
    if len(s) < 2:
        raise ValueError(s)
    s = s.rjust(3)
    system = s[0] if s[0] != " " else ("G" if version < 3 else "")
    if system not in "GRESJCIM" or not system:
        raise ValueError(s)
    prn = s[1:3].strip()
    if not prn.isdigit():
        raise ValueError(s)
    return f"{system}{int(prn):02d}"


def test_sat_id_fast_path_as_the_steps():
    """_sat_id's shortcut for fields already 'G05': every field of up to 3 characters over blanks, digits (ASCII
    and not), system letters and others, RINEX 2 and 3: the value or the error message of the steps."""
    import itertools

    alphabet = " 0159GRESJCIMXg\u00b2\u0663\t"
    for n in (0, 1, 2, 3):
        for chars in itertools.product(alphabet, repeat=n):
            for version in (2.11, 3.04):
                out = []
                for f in (_sat_id_steps, rinex._sat_id):
                    try:
                        out.append(f("".join(chars), version))
                    except ValueError as exc:
                        out.append(("error", str(exc)))
                assert out[0] == out[1], (chars, version)
