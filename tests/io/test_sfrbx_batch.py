"""The batch RXM-SFRBX decoding (io/sfrbx_batch.py) gives the frame-by-frame walk's table and counters.

Exact equality (``DataFrame.equals``, dtypes, every counter) on every u-blox log of tests/data and of
the shared data, for several reference weeks, with and without GLONASS; and on those logs' subframes
corrupted (bits flipped: parity, CRC-24Q and BCH failures, records out of range), re-ordered and moved
to other satellites, so that the fallbacks (ICD parity chain, de-interleaved BeiDou words) and the
"first valid record of each (satellite, toe, IODE)" rule are exercised.  The encoded GPS, Galileo,
BeiDou D1/D2 and GLONASS logs of test_sfrbx*.py run through the batch decoding by default.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.io import sfrbx, sfrbx_batch
from cdgps_cli.io.ubx_frames import split_stream, split_stream_spans

DATA = Path(__file__).resolve().parents[1] / "data"
SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
LOGS = [DATA / "pygpsdata_testobsnavdata.log", DATA / "ublox-glo.log", DATA / "ubx_20080526_head.ubx",
        DATA / "pygpsdata-RXMRAWX.log", SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx",
        SHARED / "ubx" / "ubx_20080526.ubx", SHARED / "ubx" / "pygpsdata-RXMRAWX.log",
        DATA / "qzsl6tool-f9p-hiroshima" / "20230919-114418.ubx"]


def _both(run):
    """(table, counters) of ``run()`` frame by frame and in batch."""
    old = sfrbx.BATCH
    try:
        sfrbx.BATCH = False
        ref = run()
        sfrbx.BATCH = True
        got = run()
    finally:
        sfrbx.BATCH = old
    return ref, got


def _assert_same(ref, got):
    (a, sa), (b, sb) = ref, got
    assert sa == sb
    assert list(a.columns) == list(b.columns) and list(a.dtypes) == list(b.dtypes)
    assert a.equals(b)


@pytest.mark.parametrize("path", LOGS, ids=lambda p: p.name)
def test_batch_equals_the_walk_on_every_log(path):
    if not path.exists():
        pytest.skip(f"{path} not available")
    data = path.read_bytes()
    off, end, _, _ = split_stream_spans(data)
    n = 0
    for week in (None, 1480, 2381, 2414):
        for glonass in (False, True):
            ref, got = _both(lambda: sfrbx.sfrbx_ephemerides_at(data, off, end, week, glonass=glonass))
            _assert_same(ref, got)
            n += len(ref[0])
    if path.name in ("gnss_1730.ubx", "pygpsdata_testobsnavdata.log", "ubx_20080526.ubx", "20230919-114418.ubx"):
        assert n > 0                                       # records were compared, not only empty tables


def _corrupted(frames, seed):
    """The SFRBX/SFRB frames of ``frames``, some with a bit of their words flipped, a few moved to another
    satellite, neighbours swapped."""
    rng = np.random.default_rng(seed)
    out = []
    for i, c, m, fr in frames:
        if (c, m) not in ((0x02, 0x13), (0x02, 0x11)):
            continue
        b = bytearray(fr)
        if len(b) > 20 and rng.random() < 0.15:
            k = int(rng.integers(14 if m == 0x13 else 8, len(b) - 2))
            b[k] ^= 1 << int(rng.integers(8))
        if m == 0x13 and rng.random() < 0.05:
            b[7] = int(rng.integers(1, 40))
        out.append((i, c, m, bytes(b)))
    for k in rng.integers(0, max(len(out) - 1, 1), len(out) // 20).tolist():
        if k + 1 < len(out):
            out[k], out[k + 1] = out[k + 1], out[k]
    return out


@pytest.mark.parametrize("seed", range(4))
def test_batch_equals_the_walk_on_corrupted_subframes(seed):
    logs = [(p, w) for p, w in ((DATA / "pygpsdata_testobsnavdata.log", 2414), (DATA / "ubx_20080526_head.ubx", 1480),
                                (SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx", 2381)) if p.exists()]
    failures = {"parity_failures": 0, "galileo_bad_pages": 0, "beidou_bch_failures": 0}
    for path, week in logs:
        frames = _corrupted(split_stream(path.read_bytes())[0], seed)
        for glonass in (False, True):
            ref, got = _both(lambda: sfrbx.sfrbx_ephemerides(frames, week, glonass=glonass))
            _assert_same(ref, got)
        for k in failures:
            failures[k] += ref[1][k]
    assert all(failures.values()), failures                # every check failed somewhere


def test_icd_parity_chain_and_interleaved_beidou_words_take_the_fallback():
    """GPS subframes in the IS-GPS-200 transmitted form (D29*/D30* from the previous word, data
    complemented) and BeiDou words as transmitted (codewords interleaved) fail the array checks and are
    read frame by frame, as the walk reads them."""
    path = SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    if not path.exists():
        pytest.skip("shared u-blox log not available")
    frames = []
    for i, c, m, fr in split_stream(path.read_bytes())[0]:
        if (c, m) != (0x02, 0x13):
            continue
        w = np.frombuffer(fr[14:-2], "<u4").astype(np.int64)
        if fr[6] == 0 and fr[8] == 0 and len(w) == 10:         # GPS L1: the transmitted chain
            d29 = d30 = 0
            chain = []
            for v in w.tolist():
                data = (v >> 6) & 0xFFFFFF
                par = sfrbx.parity_bits(data, d29, d30)
                t = ((data ^ 0xFFFFFF) if d30 else data) << 6 | par
                chain.append(t)
                d29, d30 = (t >> 1) & 1, t & 1
            fr = fr[:14] + np.array(chain, "<u4").tobytes() + fr[-2:]
        elif fr[6] == 3 and len(w) == 10:                      # BeiDou: words 2-10 interleaved
            words = [int(w[0])] + [_interleave(int(v) & 0x3FFFFFFF) for v in w[1:]]
            fr = fr[:14] + np.array(words, "<u4").tobytes() + fr[-2:]
        frames.append((i, c, m, fr))
    ref, got = _both(lambda: sfrbx.sfrbx_ephemerides(frames, 2381))
    _assert_same(ref, got)
    assert ref[1]["gps_subframes"] > 20 and ref[1]["beidou_subframes"] > 20 and len(ref[0]) >= 15


def _interleave(logical: int) -> int:
    """Logical layout (11 + 11 information bits, 4 + 4 parity) → transmitted (bits alternating)."""
    bits = [(logical >> (29 - k)) & 1 for k in range(30)]
    c1 = bits[0:11] + bits[22:26]
    c2 = bits[11:22] + bits[26:30]
    out = 0
    for a, b in zip(c1, c2):
        out = (out << 2) | (a << 1) | b
    return out


def test_interleave_is_the_inverse_of_the_decoder_deinterleave():
    rng = np.random.default_rng(1)
    for v in rng.integers(0, 1 << 30, 50).tolist():
        assert sfrbx._deinterleave(_interleave(v)) == v


def test_latest_of_type_and_first_per_key():
    sat = np.array([5, 7, 5, 5, 7, 5])
    typ = np.array([0, 1, 1, 0, 0, 1])
    assert sfrbx_batch.latest_of_type(sat, typ, 2).tolist() == [[0, -1], [-1, 1], [0, 2], [3, 2], [4, 1], [3, 5]]
    assert sfrbx_batch.latest_of_type(np.zeros(0, int), np.zeros(0, int), 3).shape == (0, 3)
    keep = sfrbx_batch.first_per_key(np.array([1, 2, 1, 1]), np.array([0.0, 0.0, 0.0, 16.0]), np.array([3, 3, 3, 3]))
    assert keep.tolist() == [0, 1, 3]


def test_field_table_reads_split_and_signed_fields():
    table = sfrbx_batch.FieldTable({"a": (False, ((0, 3, 5),)), "b": (True, ((0, 30, 4), (1, 0, 6))),
                                    "c": (True, ((1, 2, 32),))}, 40, 2)
    rng = np.random.default_rng(2)
    bits = rng.integers(0, 2, (20, 80)).astype(np.uint8)
    got = table.values(bits)

    def ref(row, pieces, signed):
        v, n = 0, 0
        for blk, st, nb in pieces:
            for k in range(nb):
                v, n = v << 1 | int(row[blk * 40 + st + k]), n + 1
        return v - (1 << n) if signed and v >> (n - 1) else v

    for name, (signed, pieces) in {"a": (False, ((0, 3, 5),)), "b": (True, ((0, 30, 4), (1, 0, 6))),
                                   "c": (True, ((1, 2, 32),))}.items():
        assert got[name].tolist() == [ref(r, pieces, signed) for r in bits]


def test_sisa_and_first_per_key_as_select_and_diff():
    """_sisa_m by nested np.where is np.select's value for every 8-bit index (and the scalar decoder's); first_per_key
    by slice comparisons gives the indices np.diff's comparisons gave, on random keys with repeats."""
    idx = np.arange(-2, 260, dtype=np.int64)
    ref = np.select([idx < 50, idx < 75, idx < 100, idx < 126],
                    [idx * 0.01, 0.5 + (idx - 50) * 0.02, 1.0 + (idx - 75) * 0.04, 2.0 + (idx - 100) * 0.16], np.nan)
    got = sfrbx_batch._sisa_m(idx)
    assert got.dtype == ref.dtype and got.tobytes() == ref.tobytes()
    assert [sfrbx._sisa_m(int(i)) for i in range(126)] == got[2:128].tolist()

    def by_diff(sat, toe, iode):
        m = sat.size
        if m < 2:
            return np.arange(m)
        o = np.lexsort((np.arange(m), iode, toe, sat))
        new = np.ones(m, bool)
        new[1:] = (np.diff(sat[o]) != 0) | (toe[o][1:] != toe[o][:-1]) | (np.diff(iode[o]) != 0)
        return np.sort(o[new])

    rng = np.random.default_rng(4)
    for n in (0, 1, 2, 5, 50, 300):
        sat, iode = rng.integers(1, 6, n), rng.integers(0, 4, n)
        toe = rng.choice([0.0, 16.0, 7200.0, np.nan], n)
        got, ref = sfrbx_batch.first_per_key(sat, toe, iode), by_diff(sat, toe, iode)
        assert got.dtype == ref.dtype and np.array_equal(got, ref)
