"""u-blox UBX logs: RXM-RAWX decoding, refusals (ESF-only, legacy RXM-RAW) and corrupt frames.

The RXM-RAWX values are checked against an independent decoding of the payload bytes with
``struct``, following the u-blox M8 receiver description (UBX-13003221, RXM-RAWX).
"""

from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.ubx import UBX_OBS_COLUMNS, read_ubx_rawx

DATA = Path(__file__).resolve().parents[1] / "data"
SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ubx"
RAWX = DATA / "pygpsdata-RXMRAWX.log"


def _frames(data: bytes):
    """(offset, class, id, payload) of every frame, assuming a clean log."""
    out, k = [], 0
    while k < len(data):
        assert data[k : k + 2] == b"\xb5\x62"
        n = struct.unpack_from("<H", data, k + 4)[0]
        out.append((k, data[k + 2], data[k + 3], data[k + 6 : k + 6 + n]))
        k += 8 + n
    return out


def _decode_rawx_gps_l1(payload: bytes):
    rcv_tow, week, leap_s, num, rec_stat = struct.unpack_from("<dHbBB", payload, 0)
    rows = []
    for i in range(num):
        pr, cp, do, gnss, sv, sig, _freq, lock, cno, pr_sd, cp_sd, _do_sd, trk = struct.unpack_from("<ddfBBBBHBBBBB", payload, 16 + 32 * i)
        if gnss == 0 and sig == 0:
            rows.append((week * 604800 + rcv_tow, f"G{sv:02d}", cp if trk & 2 else np.nan, pr if trk & 1 else np.nan, do, cno, lock, bool(trk & 2), bool(trk & 4), bool(trk & 8), 0.01 * 2 ** (pr_sd & 15), 0.004 * (cp_sd & 15)))
    return rows, leap_s, rec_stat


@pytest.fixture(scope="module")
def rawx():
    return read_ubx_rawx(RAWX)


def test_rawx_epochs_and_satellites(rawx):
    info, obs = rawx
    assert list(obs.columns) == list(UBX_OBS_COLUMNS)
    assert info["message_counts"] == {"RXM-RAWX": 14} and info["n_epochs"] == 14
    assert info["week"] == 2327 and info["leap_seconds"] == 18
    assert info["gps_satellites"] == ["G06", "G07", "G11", "G29"]
    assert info["signal_counts"] == {"BeiDou B1_ID1": 83, "GLONASS L1_OF": 105, "GPS L1_C/A": 56, "Galileo E1_C": 70}
    assert info["bad_checksum_frames"] == 0 and info["truncated_tail_bytes"] == 0 and info["skipped_bytes"] == 0
    t = np.unique(obs["time_gps_s"])
    assert len(t) == 14 and t[0] == 2327 * 604800 + 223793.0
    np.testing.assert_array_equal(np.diff(t), 1.0)
    assert len(obs) == 56 and (obs.groupby("sat").size() == 14).all()


def test_rawx_values_match_independent_decoding(rawx):
    _, obs = rawx
    rows = []
    for _, cls, mid, payload in _frames(RAWX.read_bytes()):
        assert (cls, mid) == (0x02, 0x15)
        r, leap, _ = _decode_rawx_gps_l1(payload)
        rows += r
    rows.sort(key=lambda r: (r[0], r[1]))
    cols = ["time_gps_s", "sat", "phase_l1_cycles", "pseudorange_l1_m", "doppler_l1_hz", "snr_l1_dbhz", "lock_time_ms", "cp_valid", "half_cycle_resolved", "sub_half_subtracted", "pr_std_m", "cp_std_cycles"]
    for k, c in enumerate(cols):
        got = obs[c].to_numpy()
        want = np.array([r[k] for r in rows])
        if got.dtype.kind == "f":
            np.testing.assert_array_equal(got, want.astype(float), err_msg=c)
        else:
            assert got.tolist() == want.tolist(), c


def test_rawx_fields_are_sane(rawx):
    _, obs = rawx
    assert obs["cp_valid"].all() and obs["pr_valid"].all() and obs["half_cycle_resolved"].all()
    assert obs["pseudorange_l1_m"].between(2.0e7, 2.6e7).all()
    assert obs["snr_l1_dbhz"].between(20, 55).all()
    assert obs["lock_time_ms"].between(0, 64500).all()
    assert (obs["doppler_l1_hz"].abs() < 5000).all()
    # u-blox starts the phase near pseudorange / λ: the difference is small against 2e7 m, and
    # the phase moves with the Doppler (cycles per second, opposite sign convention in u-blox: +Doppler = approaching)
    assert (np.abs(obs["phase_l1_cycles"] * GPS_L1_WAVELENGTH_M - obs["pseudorange_l1_m"]) < 1.0e3).all()
    for _, g in obs.groupby("sat"):
        dphi = np.diff(g["phase_l1_cycles"].to_numpy())
        dop = 0.5 * (g["doppler_l1_hz"].to_numpy()[1:] + g["doppler_l1_hz"].to_numpy()[:-1])
        np.testing.assert_allclose(dphi, -dop, atol=5.0)
        # lock time grows by the 1 s epoch spacing until it saturates
        lock = g["lock_time_ms"].to_numpy()
        assert np.all((np.diff(lock) == 1000) | (lock[1:] == 64500))


def test_esf_only_log_is_refused():
    with pytest.raises(CdgpsError, match=r"pygpsdata-ESF\.log: no RXM-RAWX messages \(found: ESF-MEAS ×19\)"):
        read_ubx_rawx(DATA / "pygpsdata-ESF.log")


def test_legacy_rxm_raw_is_refused_with_reason():
    with pytest.raises(CdgpsError) as exc:
        read_ubx_rawx(DATA / "ubx_20080526_head.ubx")
    msg = str(exc.value)
    assert "legacy" in msg and "RXM-RAW messages" in msg and "RXM-SFRB" in msg
    assert "no carrier lock time" in msg and "half-cycle" in msg and "RXM-RAWX" in msg


def test_every_shared_ubx_file_is_read_or_refused():
    if not SHARED.exists():
        pytest.skip(f"shared test data not available: {SHARED}")
    names = sorted(p.name for p in SHARED.iterdir())
    assert names == ["pygpsdata-ESF.log", "pygpsdata-RXMRAWX.log", "ubx_20080526.ubx"]
    info, obs = read_ubx_rawx(SHARED / "pygpsdata-RXMRAWX.log")
    assert info["n_epochs"] == 14 and len(obs) == 56
    with pytest.raises(CdgpsError, match=r"no RXM-RAWX messages \(found: ESF-MEAS ×19\)"):
        read_ubx_rawx(SHARED / "pygpsdata-ESF.log")
    with pytest.raises(CdgpsError, match=r"legacy u-blox raw log with 242 RXM-RAW messages .*RXM-SFRB ×842"):
        read_ubx_rawx(SHARED / "ubx_20080526.ubx")


def test_corrupt_and_truncated_frames(tmp_path):
    data = bytearray(RAWX.read_bytes())
    frames = _frames(bytes(data))
    off5 = frames[5][0]
    data[off5 + 100] ^= 0xFF  # a flipped byte inside the 6th RXM-RAWX
    cut = bytes(data[:-50])  # and the last one cut short
    p = tmp_path / "bad.ubx"
    p.write_bytes(cut)
    info, obs = read_ubx_rawx(p)
    assert info["n_epochs"] == 12 and info["bad_checksum_frames"] == 1 and info["bad_frame_offsets"] == [off5]
    assert info["truncated_tail_bytes"] == len(frames[-1][3]) + 8 - 50
    _, ref = read_ubx_rawx(RAWX)
    t_bad = {ref["time_gps_s"].unique()[5], ref["time_gps_s"].unique()[13]}
    expect = ref[~ref["time_gps_s"].isin(t_bad)].reset_index(drop=True)
    np.testing.assert_array_equal(obs["phase_l1_cycles"], expect["phase_l1_cycles"])
    with pytest.raises(CdgpsError, match=rf"bad\.ubx: corrupt UBX data: 1 frame\(s\) failing the checksum \(byte offsets {off5}\), \d+ bytes skipped between frames, \d+ bytes of a truncated frame at the end"):
        read_ubx_rawx(p, strict=True)


def test_noise_between_frames_and_gzip(tmp_path):
    data = RAWX.read_bytes()
    frames = _frames(data)
    noisy = b"$GPGGA,junk*00\r\n\xb5\x00\x01" + b"".join(data[o : o + 8 + len(pl)] + b"\xd3\x00\x00garbage" for o, _, _, pl in frames)
    p = tmp_path / "noisy.ubx.gz"
    p.write_bytes(gzip.compress(noisy))
    info, obs = read_ubx_rawx(p)
    _, ref = read_ubx_rawx(RAWX)
    assert info["n_epochs"] == 14 and info["bad_checksum_frames"] == 0
    assert info["skipped_bytes"] == len(noisy) - len(data)
    np.testing.assert_array_equal(obs["pseudorange_l1_m"], ref["pseudorange_l1_m"])


def test_not_a_ubx_log(tmp_path):
    p = tmp_path / "nmea.log"
    text = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n" * 10
    p.write_bytes(text)
    with pytest.raises(CdgpsError, match=rf"nmea\.log: no valid UBX frames found in {len(text)} bytes"):
        read_ubx_rawx(p)
    e = tmp_path / "empty.ubx"
    e.write_bytes(b"")
    with pytest.raises(CdgpsError, match=r"empty\.ubx: empty file"):
        read_ubx_rawx(e)
    with pytest.raises(CdgpsError, match=r"nofile\.ubx: cannot read"):
        read_ubx_rawx(tmp_path / "nofile.ubx")


def test_rawx_without_gps_l1(tmp_path):
    """Keep only the non-GPS measurements of each epoch (valid checksums recomputed)."""
    out = b""
    for _, cls, mid, payload in _frames(RAWX.read_bytes()):
        num = payload[11]
        meas = [payload[16 + 32 * i : 48 + 32 * i] for i in range(num)]
        keep = [m for m in meas if m[20] != 0]
        pl = payload[:11] + bytes([len(keep)]) + payload[12:16] + b"".join(keep)
        body = bytes([cls, mid]) + struct.pack("<H", len(pl)) + pl
        a = b = 0
        for x in body:
            a = (a + x) & 0xFF
            b = (b + a) & 0xFF
        out += b"\xb5\x62" + body + bytes([a, b])
    p = tmp_path / "nogps.ubx"
    p.write_bytes(out)
    with pytest.raises(CdgpsError, match=r"nogps\.ubx: 14 RXM-RAWX epochs but no GPS L1 C/A measurements \(signals found: .*Galileo E1_C ×70"):
        read_ubx_rawx(p)


def test_vectorised_decoding_matches_pyubx2(rawx):
    """The reader decodes RXM-RAWX with numpy (80 s → 1 s for a 10 MB log); pyubx2, the reference
    Python decoder, gives the same values for every GPS L1 C/A measurement and the same signal counts."""
    from pyubx2 import SIGID, UBXReader

    info, obs = rawx
    rows, signals = [], {}
    for off, _, _, payload in _frames(RAWX.read_bytes()):
        msg = UBXReader.parse(RAWX.read_bytes()[off : off + 8 + len(payload)])
        for i in range(1, msg.numMeas + 1):
            g, s = getattr(msg, f"gnssId_{i:02d}"), getattr(msg, f"sigId_{i:02d}")
            name = {0: "GPS", 2: "Galileo", 3: "BeiDou", 6: "GLONASS"}[g] + " " + SIGID[(g, s)]
            signals[name] = signals.get(name, 0) + 1
            if g == 0 and s == 0:
                rows.append((msg.week * 604800.0 + msg.rcvTow, f"G{getattr(msg, f'svId_{i:02d}'):02d}",
                             getattr(msg, f"cpMes_{i:02d}"), getattr(msg, f"prMes_{i:02d}"),
                             getattr(msg, f"locktime_{i:02d}"), getattr(msg, f"cno_{i:02d}")))
    rows.sort(key=lambda r: (r[0], r[1]))
    assert info["signal_counts"] == signals
    for k, c in enumerate(["time_gps_s", "sat", "phase_l1_cycles", "pseudorange_l1_m", "lock_time_ms", "snr_l1_dbhz"]):
        assert obs[c].tolist() == [r[k] for r in rows], c
