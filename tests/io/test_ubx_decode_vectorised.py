"""The vectorised pieces of the UBX reader (issue 29 item 4) against plain frame-by-frame references
written here: RXM-RAWX payload gathering (undecodable frames and their byte offsets), the RXM-SFRBX
counters taken from header bytes, and the (time, satellite) sort and repeated-row check."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import sfrbx, ubx, ubx_frames
from cdgps_cli.io.ubx_frames import split_stream

LOG = Path(__file__).resolve().parents[3] / "shared" / "data" / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"


def _frame(cls: int, mid: int, payload: bytes) -> bytes:
    body = bytes((cls, mid)) + len(payload).to_bytes(2, "little") + payload
    a = b = 0
    for v in body:
        a = (a + v) & 255
        b = (b + a) & 255
    return b"\xb5\x62" + body + bytes((a, b))


@pytest.fixture(scope="module")
def log():
    data = LOG.read_bytes()
    return data, split_stream(data)[0]


def _damaged(data: bytes, frames: list) -> bytes:
    """The log with three RXM-RAWX frames made undecodable (numMeas + 1, a 2-byte payload, a
    repeated signal) and a 2-byte RXM-RAWX frame at the very end, checksums valid."""
    rawx = [(o, f) for o, c, m, f in frames if (c, m) == (2, 0x15)]
    out, last = [], 0
    for k, (o, f) in enumerate(rawx[:12]):
        pl = bytearray(f[6:-2])
        if k == 3:
            pl[11] += 1
        elif k == 7:
            pl = pl[:2]
        elif k == 11:
            pl[48:80] = pl[16:48]
        else:
            continue
        out += [data[last:o], _frame(2, 0x15, bytes(pl))]
        last = o + len(f)
    return b"".join(out) + data[last:] + _frame(2, 0x15, b"\x01\x02")


def _reference_rawx(frames: list) -> tuple[list, list]:
    """(rows (offset, svId, cpMes), undecodable offsets) decoded frame by frame with struct."""
    rows, bad = [], []
    for o, c, m, f in frames:
        if (c, m) != (2, 0x15):
            continue
        pl = f[6:-2]
        if len(pl) < 16 or len(pl) != 16 + 32 * pl[11]:
            bad.append(o)
            continue
        meas = [struct.unpack_from("<ddfBBBBHBBBBBB", pl, 16 + 32 * j) for j in range(pl[11])]
        keys = [(r[3], r[4], r[5]) for r in meas]
        if len(set(keys)) < len(keys):
            bad.append(o)
            continue
        rows += [(o, r[4], r[1]) for r in meas]
    return rows, sorted(bad)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("damage", [False, True])
def test_rawx_gathered_as_frame_by_frame(log, damage, compiled, monkeypatch):
    if compiled and not hasattr(ubx_frames._ubxcore, "rawx_rows"):
        pytest.skip("cdgps_cli.io._ubxcore not built with rawx_rows (optional)")
    monkeypatch.setattr(ubx_frames, "USE_COMPILED", compiled)
    data, frames = log
    if damage:
        data = _damaged(data, frames)
        frames = split_stream(data)[0]
    x = np.frombuffer(data, np.uint8)
    off = np.array([o for o, c, m, _ in frames if (c, m) == (2, 0x15)], np.int64)
    n = np.array([len(f) - 8 for _, c, m, f in frames if (c, m) == (2, 0x15)], np.int64)
    epochs, meas, bad = ubx._decode_rawx(x, off, n)
    rows, ref_bad = _reference_rawx(frames)
    assert bad == ref_bad and len(bad) == (4 if damage else 0)
    got = list(zip(epochs["offset"][meas["epoch"]].tolist(), meas["svId"].tolist(), meas["cpMes"].tolist()))
    assert got == rows
    ep2, meas2, bad2 = ubx._decode_rawx_frames([(o, f) for o, c, m, f in frames if (c, m) == (2, 0x15)])
    assert bad2 == bad and np.array_equal(ep2, epochs) and np.array_equal(meas2, meas)


def test_compiled_rawx_rows_equal_numpy(log, monkeypatch):
    """``_ubxcore.rawx_rows`` gives the numpy gather's rows and repeated-signal frames exactly (a frame
    repeating a signal, frames of 0 and 255 measurements among them)."""
    if not hasattr(ubx_frames._ubxcore, "rawx_rows"):
        pytest.skip("cdgps_cli.io._ubxcore not built with rawx_rows (optional)")
    data, frames = log
    rawx = [f for _, c, m, f in frames if (c, m) == (2, 0x15)][:6]
    pl = bytearray(rawx[2][6:-2])
    pl[48:80] = pl[16:48]                                  # frame 2 lists its first signal twice
    rng = np.random.default_rng(7)
    big = bytes(rawx[0][6:22]) + rng.integers(0, 256, 32 * 255, dtype=np.uint8).tobytes()
    bodies = [bytes(rawx[0][6:-2]), bytes(rawx[1][6:-2]), bytes(pl), bytes(rawx[3][6:22]), big]
    bodies[3] = bodies[3][:11] + b"\0" + bodies[3][12:]      # numMeas 0
    bodies[4] = bodies[4][:11] + b"\xff" + bodies[4][12:]    # numMeas 255
    blob = b"".join(_frame(2, 0x15, b) for b in bodies)
    x = np.frombuffer(blob, np.uint8)
    off = np.cumsum([0] + [len(b) + 8 for b in bodies])[:-1].astype(np.int64)
    num = x[off + 17].astype(np.int64)
    got = ubx._rawx_rows(x, off, num)
    monkeypatch.setattr(ubx_frames, "USE_COMPILED", False)
    ref = ubx._rawx_rows(x, off, num)
    assert got[0].tobytes() == ref[0].tobytes() and got[0].dtype == ref[0].dtype
    assert got[1].tolist() == ref[1].tolist() and 2 in ref[1].tolist()
    assert len(ref[0]) == int(num.sum()) == rawx[0][17] + rawx[1][17] + pl[11] + 0 + 255


def _sfrbx(gnss: int, sv: int, sig: int, words: int, n_words: int | None = None) -> tuple:
    n_words = words if n_words is None else n_words
    return (0, 2, 0x13, _frame(2, 0x13, bytes((gnss, sv, sig, 0, words, 0, 2, 0)) + b"\0" * (4 * n_words)))


def test_sfrbx_counters_from_headers(log):
    """Every kind of frame the decoder only counts, mixed with the real log's, counted as one by one."""
    _, frames = log
    extra = [_sfrbx(2, 5, 3, 8), _sfrbx(2, 5, 1, 9), _sfrbx(3, 20, 0, 9), _sfrbx(0, 7, 3, 10), _sfrbx(0, 7, 0, 8),
             _sfrbx(1, 131, 0, 8), _sfrbx(5, 2, 0, 10), _sfrbx(5, 3, 1, 9), _sfrbx(6, 3, 0, 4), _sfrbx(0, 7, 0, 10, 9),
             _sfrbx(2, 5, 1, 8)]
    mixed = frames[:40] + extra + frames[40:] + extra[::-1]
    for week in (None, 2381):
        for glonass in (False, True):
            _, stats = sfrbx.sfrbx_ephemerides(mixed, week, glonass=glonass)
            ref = {"galileo_other_frames": 0, "beidou_cnav_frames": 0, "gps_cnav_frames": 0, "qzss_cnav_frames": 0,
                   "other_systems": {}}
            for _, c, m, f in mixed:
                pl = f[6:-2]
                if (c, m) != (2, 0x13) or len(pl) < 8 or len(pl) != 8 + 4 * pl[4]:
                    continue
                g, s, w = pl[0], pl[2], pl[4]
                if g == 2 and (w != 8 or s not in (0, 1, 5)):
                    ref["galileo_other_frames"] += 1
                elif g == 2 and week is not None:
                    pass
                elif g == 3:
                    ref["beidou_cnav_frames"] += w != 10
                elif g == 6 and glonass:
                    pass
                elif g == 5:
                    ref["qzss_cnav_frames"] += w != 10 or s != 0
                elif g != 0:
                    ref["other_systems"][str(g)] = ref["other_systems"].get(str(g), 0) + 1
                elif w == 10 and s != 0:
                    ref["gps_cnav_frames"] += 1
            assert {k: stats[k] for k in ref} == ref
            assert list(stats["other_systems"]) == list(ref["other_systems"])    # order of first appearance
            assert stats["sfrbx_frames"] == sum(c == 2 and m in (0x13, 0x11) for _, c, m, _ in mixed)


def test_l1_sort_as_pandas_and_names_the_first_repeat():
    """Sorted by (time, satellite name) as ``sort_values`` sorts the table, G100 before G11; a repeated
    (time, satellite) across two epochs is named at its first repeat in log order."""
    meas = np.zeros(7, dtype=[("svId", "u1"), ("epoch", "<i8")])
    meas["svId"] = [11, 100, 3, 2, 11, 100, 5]
    meas["epoch"] = [0, 0, 0, 1, 1, 1, 1]
    t = np.array([10.0, 9.0])
    for t in (np.array([10.0, 9.0]), np.array([9.0, 10.0])):       # epochs back in time (lexsort), in order (one key)
        got = ubx._sorted_l1(Path("x.ubx"), meas, np.arange(7), t)
        table = pd.DataFrame({"time_gps_s": t[meas["epoch"]], "sat": ubx._GPS_SAT_NAMES[meas["svId"]]})
        order = table.sort_values(["time_gps_s", "sat"], kind="stable").index.to_numpy()
        assert np.array_equal(got, meas[order])
    sel = np.array([1, 2, 4, 6])
    assert np.array_equal(ubx._sorted_l1(Path("x.ubx"), meas, sel, t), meas[sel[[1, 0, 3, 2]]])
    t = np.array([10.0, 10.0])
    table = pd.DataFrame({"time_gps_s": t[meas["epoch"]], "sat": ubx._GPS_SAT_NAMES[meas["svId"]]})
    with pytest.raises(CdgpsError) as new:
        ubx._sorted_l1(Path("x.ubx"), meas, np.arange(7), t)
    with pytest.raises(CdgpsError) as old:
        ubx._checked_sorted(Path("x.ubx"), table)
    assert str(new.value) == str(old.value) and "G11" in str(new.value)


@pytest.mark.parametrize("seed", range(6))
def test_time_rank_order_is_lexsort(seed):
    """The one-key sort gives ``np.lexsort((rank, time))`` wherever the times do not decrease (ties of
    time and rank kept in row order), and falls back to it where they do."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    tm = np.sort(rng.integers(0, 20, n)).astype(np.float64) * 0.1
    if seed == 5:
        tm = tm[::-1].copy()
    rank = rng.integers(0, 256, n)
    if seed == 4:
        rank[:] = 7
    assert np.array_equal(ubx._time_rank_order(tm, rank), np.lexsort((rank, tm)))


def test_empty_nav_is_a_fresh_empty_table():
    from cdgps_cli.core.records import NAV_COLUMNS

    first, _ = sfrbx.sfrbx_ephemerides([], 2381)
    first.loc[0] = 1.0                                     # a caller's change does not reach the next caller
    again, _ = sfrbx.sfrbx_ephemerides([], None)
    pd.testing.assert_frame_equal(again, pd.DataFrame([], columns=list(NAV_COLUMNS)), check_index_type=True)


def test_std_tables_and_shared_signal_codes_as_per_measurement():
    """The standard deviations by 16-entry tables are the per-measurement formulas to the bit, and the L1 table
    and signal counts from the signal codes computed once are those of the fields read again."""
    k = np.arange(16, dtype=np.uint8)
    assert ubx._PR_STD_M[k].tobytes() == (0.01 * 2.0 ** k.astype(np.int64)).tobytes()
    assert ubx._CP_STD_CYCLES[k].tobytes() == (0.004 * k.astype(np.int64)).tobytes()
    rng = np.random.default_rng(3)
    meas = np.zeros(400, ubx._RAWX_ROW)
    meas["gnssId"] = rng.choice([0, 0, 2, 3, 6], 400)
    meas["sigId"] = rng.choice([0, 0, 1, 3], 400)
    meas["svId"] = np.concatenate([rng.permutation(np.arange(1, 41)) for _ in range(10)])   # once an epoch each
    meas["epoch"] = np.arange(400) // 40
    meas["prStdev"], meas["cpStdev"] = rng.integers(0, 256, 400), rng.integers(0, 256, 400)
    meas["cpMes"], meas["trkStat"] = rng.normal(size=400), rng.integers(0, 16, 400)
    t = 1e9 + np.arange(10, dtype=np.float64)
    reset = np.zeros(10, bool)
    code = ubx._signal_codes(meas)
    assert ubx._signal_counts(meas, code) == ubx._signal_counts(meas)
    ref = ubx._l1_table(Path("x.ubx"), meas, t, reset)
    got = ubx._l1_table(Path("x.ubx"), meas, t, reset, (code == 0).nonzero()[0])
    pd.testing.assert_frame_equal(got[0], ref[0], check_exact=True)
    assert got[1] == ref[1]


def test_byte_membership_tables_are_isin():
    """The I/NAV signal and BeiDou GEO look-up tables (indexed by a header byte) are np.isin of every byte value."""
    v = np.arange(256)
    assert np.array_equal(sfrbx._INAV_SIGNAL_BYTE[v], np.isin(v, sorted(sfrbx._INAV_SIGNALS)))
    assert np.array_equal(sfrbx._BDS_GEO_BYTE[v], np.isin(v, sorted(sfrbx._BDS_GEO)))
