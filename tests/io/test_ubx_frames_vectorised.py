"""The numpy framer and the compiled walk (``_ubxcore``, where built) behind :func:`split_stream` against
the byte-by-byte walk in Python (``_split_stream_walk``, issue 29 item 4): the same frames, sentences and
counters, byte offsets included, on every u-blox log of ../shared/data and on damaged and mixed streams."""

from __future__ import annotations

import gzip
import random
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.io import ubx_frames
from cdgps_cli.io.ubx_frames import _split_stream_numpy, _split_stream_walk, split_stream
from tests.io.test_ubx_frames import _nmea, _rtcm, _ubx

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
LOGS = sorted(p for p in SHARED.rglob("*") if p.is_file() and p.suffix.lower() in (".ubx", ".log")
              and b"\xb5\x62" in p.read_bytes()[:4096])
MARKS = (0xB5, 0x62, 0x24, 0xD3, 0x0A, 0x0D, 0x2A, 0x2C, 0x41, 0x30)


def _same(data: bytes) -> None:
    want = _split_stream_walk(data)
    assert _split_stream_numpy(data) == want
    if ubx_frames._ubxcore is not None:
        assert ubx_frames._split_stream_compiled(data) == want


def test_split_stream_takes_the_compiled_walk_where_built(monkeypatch):
    data = _ubx(1, 7, b"ab") + _nmea("GPGGA,1") + _rtcm(1005, bytes(17))
    calls = []
    monkeypatch.setattr(ubx_frames, "_split_stream_numpy", lambda d: calls.append(d) or _split_stream_walk(d))
    assert split_stream(data) == _split_stream_walk(data)
    assert bool(calls) == (ubx_frames._ubxcore is None)
    monkeypatch.setattr(ubx_frames, "USE_COMPILED", False)
    split_stream(data)
    assert calls[-1] == data


def test_compiled_walk_is_built_here():
    """The machine that runs the suite has a C compiler: the extension is expected (CI builds it)."""
    if ubx_frames._ubxcore is None:
        pytest.skip("cdgps_cli.io._ubxcore not built (optional); the numpy path is what runs")
    assert ubx_frames._ubxcore.API == 1
    assert hasattr(ubx_frames._ubxcore, "rawx_rows"), "stale _ubxcore build: rebuild cdgps_cli/io/_ubxcore.c"


def test_shared_logs_found():
    assert len(LOGS) >= 3


@pytest.mark.parametrize("path", LOGS, ids=lambda p: p.name)
def test_every_shared_log_frames_identically(path):
    data = path.read_bytes()
    _same(gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data)


def _mixed(rng: random.Random) -> bytes:
    parts = []
    for _ in range(rng.randint(0, 12)):
        r = rng.random()
        if r < 0.35:
            parts.append(_ubx(2, 0x15, bytes(rng.randrange(256) for _ in range(rng.randint(0, 80)))))
        elif r < 0.55:
            parts.append(_rtcm(rng.choice([1005, 1077, 4072, 999]), bytes(rng.randrange(256) for _ in range(rng.randint(0, 40)))))
        elif r < 0.75:
            parts.append(_nmea("GPGGA," + ",".join(str(rng.randrange(1000)) for _ in range(rng.randint(0, 40)))))
        else:
            parts.append(bytes(rng.choice(MARKS + (rng.randrange(256),)) for _ in range(rng.randint(0, 30))))
    return b"".join(parts)


def _damage(rng: random.Random, data: bytes) -> bytes:
    d = bytearray(data)
    for _ in range(rng.randint(0, 6) if d else 0):
        d[rng.randrange(len(d))] = rng.choice(MARKS + (rng.randrange(256),))
    if d and rng.random() < 0.3:
        d = d[: rng.randrange(len(d))]
    return bytes(d)


def test_damaged_mixed_streams_frame_identically():
    """UBX, RTCM 3 (valid, bad CRC, implausible types), NMEA (long, damaged) and noise rich in the
    marker bytes, bytes flipped and tails cut: 400 streams, every counter and offset equal."""
    rng = random.Random(29)
    for _ in range(400):
        _same(_damage(rng, _mixed(rng)))


def test_damaged_real_log_frames_identically():
    log = SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    if not log.exists():
        pytest.skip("no shared u-blox walk log")
    base = log.read_bytes()[:40000]
    rng = random.Random(4)
    for _ in range(60):
        _same(_damage(rng, base))


@pytest.mark.parametrize("data", [b"", b"\xb5", b"\xb5\x62", b"\xb5\x62\x02\x15\xff", b"$GPGGA,*56\n",
                                  _nmea("GPGGA,1")[:-1], _ubx(1, 7, b"")[:-1] + b"\xb5\x62\x01",
                                  b"\xd3\x00\x02\x3e\xd0" + b"\x00\x00\x00", _rtcm(1005, bytes(17))])
def test_edge_streams_frame_identically(data):
    _same(data)


def test_deeply_overlapping_candidates_frame_identically():
    """Forty sync words each announcing a frame over the next ones: more layers of overlapping
    candidates than the disjoint sums take (the prefix-sum fallback), one genuine frame among them."""
    data = b"\xb5\x62\x01\x01\x30\x00" * 40 + _ubx(1, 7, bytes(range(40))) + bytes(100)
    assert ubx_frames.MAX_LAYERS < 40
    _same(data)
    assert len(split_stream(data)[0]) == 1


def test_bch15_syndrome_table_equals_long_division():
    from cdgps_cli.io.sfrbx import _bch15_syndrome_division, bch15_syndrome

    assert [bch15_syndrome(v) for v in range(1 << 16)] == [_bch15_syndrome_division(v) for v in range(1 << 16)]


def test_inav_words_equal_inav_word_page_by_page():
    """The column-wise I/NAV check and extraction against the per-page one, on the real log's
    Galileo pages with bits flipped (flags, CRC, data) and on random pages with right flags."""
    from cdgps_cli.io.sfrbx import _SFRBX, inav_word, inav_words

    log = SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    if not log.exists():
        pytest.skip("no shared u-blox walk log")
    frames, _, _ = split_stream(log.read_bytes())
    rows = [np.frombuffer(fr[14:46], "<u4") for _, c, m, fr in frames if (c, m) == _SFRBX and fr[6] == 2 and fr[10] == 8]
    rng = np.random.default_rng(5)
    real = np.array(rows, dtype=np.uint32)
    flipped = real ^ (np.uint32(1) << rng.integers(0, 32, real.shape).astype(np.uint32)) * (rng.random(real.shape) < 0.05)
    noise = rng.integers(0, 2**32, (200, 8), dtype=np.uint64).astype(np.uint32)
    noise[:, 0] &= 0x3FFFFFFF
    noise[:, 4] = (noise[:, 4] & 0x3FFFFFFF) | 0x80000000
    dw = np.concatenate((real, flipped.astype(np.uint32), noise))
    got = inav_words(dw)
    assert got == [inav_word(r.tolist()) for r in dw]
    assert sum(g is not None for g in got) >= len(real)


def test_checked_words_equal_the_per_subframe_checks():
    """GPS parity and BeiDou BCH checked column-wise give what gps_words_from_sfrbx /
    beidou_words_from_sfrbx give, on the real log's subframes with bits flipped; the rows they
    leave out are the ones those functions reject or must de-interleave."""
    from cdgps_cli.io.sfrbx import _checked_words, beidou_words_from_sfrbx, gps_words_from_sfrbx

    log = SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    if not log.exists():
        pytest.skip("no shared u-blox walk log")
    frames, _, _ = split_stream(log.read_bytes())
    sub = [f for f in frames if f[1:3] == (2, 0x13) and len(f[3]) == 56 and f[3][6] in (0, 3) and f[3][10] == 10]
    rng = random.Random(7)
    damaged = []
    for off, c, m, fr in sub:
        b = bytearray(fr)
        if rng.random() < 0.4:
            b[14 + rng.randrange(40)] ^= 1 << rng.randrange(8)
        damaged.append((off, c, m, bytes(b)))
    every = sub + damaged
    got = _checked_words([(i, c, m, fr) for i, (_, c, m, fr) in enumerate(every)])
    n_kept = 0
    for i, (_, _, _, fr) in enumerate(every):
        dw = np.frombuffer(fr[14:54], "<u4").tolist()
        want = gps_words_from_sfrbx(dw) if fr[6] == 0 else beidou_words_from_sfrbx(dw)
        if i in got:
            assert got[i] == want
            n_kept += 1
        elif fr[6] == 0:
            assert want is None or fr[8] != 0
    assert n_kept >= len(sub) // 2


def test_segment_sums_with_deep_overlaps_equal_direct_sums():
    """Disjoint layers by reduceat, and the prefix-sum fallback past MAX_LAYERS, both exact (mod 2^32)."""
    from cdgps_cli.io.ubx_frames import _segment_sums

    rng = np.random.default_rng(3)
    v = rng.integers(0, 2**32, 5000, dtype=np.uint64).astype(np.uint32)
    lo = np.sort(rng.integers(0, 4000, 600))
    hi = lo + 1 + rng.integers(0, 900, lo.size)
    want = np.array([int(v[a:b].astype(np.uint64).sum()) % 2**32 for a, b in zip(lo, hi)], np.uint32)
    assert np.array_equal(_segment_sums(v, lo, hi), want)


def test_rtcm_rounds_exhausted_falls_back_to_the_walk(monkeypatch):
    """Streams whose RTCM 3 frames keep moving the chain past MAX_RTCM_ROUNDS are walked: same result."""
    from cdgps_cli.io import ubx_frames

    rng = random.Random(8)
    streams = [_damage(rng, _mixed(rng)) for _ in range(40)]
    want = [_split_stream_walk(d) for d in streams]
    monkeypatch.setattr(ubx_frames, "MAX_RTCM_ROUNDS", 1)
    assert [_split_stream_numpy(d) for d in streams] == want


def test_false_syncs_switch_the_compiled_walk_to_prefix_sums():
    """Sync words announcing long frames that fail: the compiled walk sums them directly until that has cost
    more than the stream, then from prefix sums; frames on both sides of the switch equal the walk's, and a
    megabyte of such candidates stays fast (linear)."""
    import time

    false = b"\xb5\x62\x01\x01\xf0\x00" + bytes(range(40))
    data = _ubx(1, 7, b"ab") + false * 300 + _ubx(2, 0x15, bytes(30)) + false * 300 + _ubx(1, 7, b"cd")
    _same(data)
    assert len(split_stream(data)[0]) == 3
    if ubx_frames._ubxcore is not None:
        big = b"\xb5\x62\x01\x01\xff\xff" * 170_000 + _ubx(1, 7, b"ef")
        t = time.perf_counter()
        frames, _, stats = ubx_frames._split_stream_compiled(big)
        assert time.perf_counter() - t < 1.0
        assert len(frames) == 1 and stats["bad_checksum_frames"] == 170_000


def test_checksums_of_every_length_and_byte_frame_identically():
    """The compiled walk sums checksums 8 bytes a step: frames of every payload length 0-40 (every
    remainder of the step) with byte values up to 255, each good and with either checksum byte off by one."""
    rng = np.random.default_rng(29)
    parts = []
    for n in range(41):
        for bad in (None, -2, -1):
            fr = bytearray(_ubx(2, 0x13, bytes(rng.integers(200, 256, n, dtype=np.uint8))))
            if bad is not None:
                fr[bad] = (fr[bad] + 1) & 0xFF
            parts.append(bytes(fr))
    _same(b"".join(parts))


def test_long_checksums_frame_identically():
    """The compiled walk sums checksums 16 bytes a step (SSE2 where the compiler targets it): frames of payload
    lengths 0-300 (every remainder of the step, several blocks) and a few of kilobytes, bytes up to 255 (the
    widest sums), each good and with either checksum byte off by one."""
    rng = np.random.default_rng(16)
    parts = []
    for n in [*range(301), 1000, 1021, 4096, 8191, 20000]:
        for bad in (None, -2, -1):
            payload = rng.integers(0, 256, n, dtype=np.uint8) if n % 2 else np.full(n, 255, np.uint8)
            fr = bytearray(_ubx(2, 0x13, payload.tobytes()))
            if bad is not None:
                fr[bad] = (fr[bad] + 1) & 0xFF
            parts.append(bytes(fr))
    _same(b"".join(parts))
