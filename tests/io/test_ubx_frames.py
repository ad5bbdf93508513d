"""Framing of mixed UBX / NMEA / RTCM 3 streams (issue 14 item 3): every genuine frame is found,
what lies between is counted exactly, the RTCM CRC-24Q is checked, and the real u-blox logs of
../shared/data/ubx frame completely."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdgps_cli.io.ubx_frames import NMEA_MAX_CHARS, crc24q, split_stream

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ubx"


def _crc24q_bitwise(data: bytes) -> int:
    """CRC-24Q one bit at a time (RTCM 10403 §4: polynomial 0x1864CFB, initial value 0)."""
    crc = 0
    for byte in data:
        for i in range(7, -1, -1):
            crc ^= ((byte >> i) & 1) << 23
            crc = ((crc << 1) ^ 0x1864CFB) if crc & 0x800000 else (crc << 1)
            crc &= 0xFFFFFF
    return crc


def _ubx(cls: int, mid: int, payload: bytes) -> bytes:
    body = bytes((cls, mid)) + struct.pack("<H", len(payload)) + payload
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes((a, b))


def _rtcm(mtype: int, rest: bytes) -> bytes:
    payload = bytes((mtype >> 4, ((mtype & 15) << 4))) + rest
    head = bytes((0xD3, len(payload) >> 8, len(payload) & 0xFF)) + payload
    return head + _crc24q_bitwise(head).to_bytes(3, "big")


def _nmea(body: str) -> bytes:
    x = 0
    for c in body.encode():
        x ^= c
    return f"${body}*{x:02X}\r\n".encode()


def test_crc24q_check_value_and_bitwise_agreement():
    assert crc24q(b"123456789") == 0xCDE703            # the published CRC-24Q check value
    rng = random.Random(1)
    for n in (0, 1, 3, 100, 1029):
        d = bytes(rng.randrange(256) for _ in range(n))
        assert crc24q(d) == _crc24q_bitwise(d)


_FRAME = st.one_of(
    st.tuples(st.just("ubx"), st.integers(0, 255), st.integers(0, 255), st.binary(max_size=60)),
    st.tuples(st.just("nmea"), st.sampled_from(["GPGGA", "GNRMC", "GPGSV"]), st.text("0123456789.,NEW", max_size=40)),
    st.tuples(st.just("rtcm"), st.sampled_from([1005, 1006, 1077, 1087, 1127, 1230, 4072]), st.binary(max_size=80)),
)
# garbage free of the three start markers, so what is expected is exact
_GARBAGE = st.binary(max_size=30).map(lambda b: bytes(x for x in b if x not in (0xB5, 0x24, 0xD3)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(_GARBAGE, _FRAME), max_size=25), _GARBAGE)
def test_interleaved_stream_is_split_exactly(items, tail):
    data, want_ubx, want_rtcm, n_nmea, nmea_bytes, garbage = b"", [], {}, 0, 0, len(tail)
    for junk, fr in items:
        data += junk
        garbage += len(junk)
        if fr[0] == "ubx":
            f = _ubx(fr[1], fr[2], fr[3])
            want_ubx.append((len(data), f))
        elif fr[0] == "nmea":
            f = _nmea(f"{fr[1]},{fr[2]}")
            n_nmea += 1
            nmea_bytes += len(f)
        else:
            f = _rtcm(fr[1], fr[2])
            want_rtcm[fr[1]] = want_rtcm.get(fr[1], 0) + 1
        data += f
    data += tail
    ubx, rtcm, stats = split_stream(data)
    assert [(o, f) for o, _, _, f in ubx] == want_ubx
    assert stats["rtcm_frames"] == dict(sorted(want_rtcm.items()))
    assert [t for _, t, _ in rtcm] == [t for t in (fr[1] for _, fr in items if fr[0] == "rtcm")]
    assert stats["nmea_sentences"] == n_nmea and stats["nmea_bytes"] == nmea_bytes
    assert stats["skipped_bytes"] == garbage
    assert stats["bad_checksum_frames"] == stats["bad_crc_rtcm_frames"] == stats["truncated_tail_bytes"] == 0


def test_random_garbage_and_corrupt_frames_cost_only_themselves():
    """Arbitrary garbage (with its own false 0xB5 0x62 / '$' / 0xD3), a UBX frame and an RTCM frame
    with a flipped bit: every intact frame is found; the corrupt ones are counted."""
    rng = random.Random(7)
    good_ubx = [_ubx(2, 0x15, bytes(rng.randrange(256) for _ in range(48))) for _ in range(30)]
    good_rtcm = [_rtcm(1077, bytes(rng.randrange(256) for _ in range(120))) for _ in range(30)]
    bad_u = bytearray(_ubx(2, 0x13, bytes(40)))
    bad_u[20] ^= 1
    bad_r = bytearray(_rtcm(1005, bytes(17)))
    bad_r[10] ^= 1
    parts = []
    for u, r in zip(good_ubx, good_rtcm):
        parts += [bytes(rng.randrange(256) for _ in range(rng.randrange(200))), u, r, _nmea("GPGGA,1,2,3")]
    parts.insert(7, bytes(bad_u))
    parts.insert(13, bytes(bad_r))
    data = b"".join(parts)
    ubx, rtcm, stats = split_stream(data)
    assert [f for *_, f in ubx if f in good_ubx] == good_ubx
    assert [f for *_, f in rtcm if f in good_rtcm] == good_rtcm
    assert stats["bad_checksum_frames"] >= 1 and stats["bad_crc_rtcm_frames"] >= 1
    assert stats["nmea_sentences"] >= 30
    accounted = sum(len(f) for *_, f in ubx) + sum(len(f) for *_, f in rtcm) + stats["nmea_bytes"] + stats["skipped_bytes"]
    assert accounted == len(data)


@pytest.mark.parametrize("name", ["pygpsdata-RXMRAWX.log", "pygpsdata-ESF.log", "ubx_20080526.ubx"])
def test_real_logs_frame_completely(name):
    p = SHARED / name
    if not p.exists():
        pytest.skip(f"shared test data not available: {p}")
    data = p.read_bytes()
    ubx, rtcm, stats = split_stream(data)
    accounted = sum(len(f) for *_, f in ubx) + sum(len(f) for *_, f in rtcm) + stats["nmea_bytes"] \
        + stats["skipped_bytes"] + stats["truncated_tail_bytes"]
    assert accounted == len(data)
    assert len(ubx) > 10 and stats["bad_checksum_frames"] == 0


def test_high_precision_nmea_longer_than_82_characters_is_nmea():
    """u-blox high-precision NMEA mode writes GGA sentences past NMEA 0183's 82 characters (92 in the
    real all-band log of ../shared/data/real-pairs/ublox-walk): they are NMEA, not skipped bytes;
    a sentence past NMEA_MAX_CHARS, or with a wrong checksum, is not."""
    gga = _nmea("GNGGA,173021.75,4005.8014957,N,10508.8299894,W,4,12,0.62,1601.435,M,-21.387,M,0.8,0000")
    assert len(gga) == 92
    _, _, stats = split_stream(gga + gga)
    assert stats["nmea_sentences"] == 2 and stats["skipped_bytes"] == 0
    too_long = _nmea("GNTXT," + "x" * NMEA_MAX_CHARS)
    bad = gga.replace(b"*62", b"*63")
    _, _, stats = split_stream(too_long + bad)
    assert stats["nmea_sentences"] == 0 and stats["skipped_bytes"] == len(too_long) + len(bad)
