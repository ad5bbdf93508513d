"""A GNSS ingest of u-blox UBX logs read block by block of GPS time (issue 29: a day of a 10 Hz u-blox pair in bounded
memory).

The independent check is the whole-log ingest (every log read at once, as before): the RUN written block by block
is the same file, byte for byte, on the real u-blox walk log (RXM-RAWX at 4 Hz with RXM-SFRBX and NMEA between the
frames: its ephemerides, decoded across the blocks, are the navigation source), with several signals, as several
files, and in pairs with a UBX and a RINEX receiver; the blocks are made short here so that a two-minute log crosses
several.  The cut itself is checked against a plain framing of the whole log (every RXM-RAWX frame's offset and time),
and the joined read summaries against the whole log's.  A log the blocks cannot give exactly (compressed, with a
corrupt frame, frames cut by a file rotation, ESF sensor messages, no RXM-RAWX) is read whole: the same RUN, the same
error.
"""

import gzip
import json
import math
import struct

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.config.structure import load_gnss_config
from cdgps_cli.io import gnss_archive, gnss_hours
from cdgps_cli.io.ubx import UBX_SIGNALS, read_ubx_block, read_ubx_log, read_ubx_signals, sfrbx_of_blocks
from cdgps_cli.io.ubx_frames import rtcm_station_arp, split_stream
from cdgps_cli.io.ubx_hours import check_ubx_block, join_ubx_infos, ubx_hours
from cdgps_cli.pipeline import gnss_ingest
from tests._shared import REPO_ROOT
from tests.io.test_sfrbx import _ubx_frame as _frame

SHARED = REPO_ROOT.parent / "shared" / "data"
WALK = SHARED / "real-pairs" / "ublox-walk"
UBX_WALK = WALK / "gnss_1730.ubx"
RAWX_LOG = SHARED / "ubx" / "pygpsdata-RXMRAWX.log"
LEGACY = SHARED / "ubx" / "ubx_20080526.ubx"
WALK_XYZ = (-1276965.2487, -4717231.7278, 4087230.1460)
"""The walk receiver's RINEX header position (ECEF m): a master position for a pair of the walk log with itself."""

pytestmark = pytest.mark.skipif(not UBX_WALK.is_file(), reason="needs ../shared/data/real-pairs/ublox-walk")


def _ingest(cfg_path, out, whole: bool, monkeypatch, block_s: float) -> tuple[dict, list]:
    said = []
    with monkeypatch.context() as m:
        m.setattr(gnss_archive, "OBS_BLOCK_S", block_s)
        if whole:
            m.setattr(gnss_hours, "hourly_inputs", lambda *a, **k: None)
        s = gnss_ingest.ingest_gnss(load_gnss_config(cfg_path), out, progress=said.append)
    return s, said


def _same_run(cfg_path, tmp_path, monkeypatch, block_s: float = 30.0) -> dict:
    """Ingest block by block and whole: the same file and summary; returns how the first one read."""
    s_h, said = _ingest(cfg_path, tmp_path / "hours.mcap", False, monkeypatch, block_s)
    s_w, _ = _ingest(cfg_path, tmp_path / "whole.mcap", True, monkeypatch, block_s)
    assert (tmp_path / "hours.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()
    how = s_h.pop("reading")
    assert not s_w.pop("reading")["hour_by_hour"]
    s_h.pop("output"), s_w.pop("output")
    assert s_h == s_w
    fell_back = any("reading the files whole" in m or "reading them whole" in m for m in said)
    assert how["hour_by_hour"] and not fell_back or not how["hour_by_hour"] and how["why_whole"]
    return how


def _config(tmp_path, antennas: dict, signals=(), nav=(), master_xyz=None) -> object:
    lines = ["[gnss]"]
    if signals:
        lines.append(f"signals = {json.dumps(list(signals))}")
    if nav:
        lines.append(f"nav = {json.dumps([str(p) for p in nav])}")
    if len(antennas) > 1:
        lines.append(f'master = "{next(iter(antennas))}"')
    for n, (kind, path) in antennas.items():
        lines += [f"[gnss.antennas.{n}]", f"{kind} = {json.dumps(str(path))}"]
        if master_xyz is not None and n == next(iter(antennas)):
            lines.append(f"position_ecef_m = {list(master_xyz)}")
    p = tmp_path / "job.toml"
    p.write_text("\n".join(lines) + "\n")
    return p


# ------------------------------------------------------------------------------------------------
# the cut and the blocks' summaries


def _rawx_frames(data: bytes) -> list[tuple[int, float]]:
    """(offset, GPS s) of every RXM-RAWX frame of a log, by a plain framing of it all."""
    out = []
    for off, cls, mid, fr in split_stream(data)[0]:
        if (cls, mid) == (0x02, 0x15):
            tow, week = struct.unpack_from("<dH", fr, 6)
            out.append((off, week * 604800.0 + tow))
    return out


@pytest.mark.parametrize("log", [UBX_WALK, RAWX_LOG])
@pytest.mark.parametrize("block_s", [1.0, 7.0, 60.0, 3600.0])
def test_the_cut_is_a_plain_framing_of_the_log(log, block_s):
    frames = _rawx_frames(log.read_bytes())
    h = ubx_hours(log, block_s)
    assert (h.first_s, h.last_s) == (frames[0][1], frames[-1][1])
    want = {}
    for off, t in frames:
        want.setdefault(math.floor(t / block_s), (off, t))
    got = {k: (a, t) for k, a, _, t in h.blocks}
    assert [k for k, *_ in h.blocks] == sorted(want)
    assert {k: v[1] for k, v in got.items()} == {k: v[1] for k, v in want.items()}
    assert [a for k, a, *_ in h.blocks[1:]] == [want[k][0] for k, *_ in h.blocks[1:]]      # at the frames' starts
    assert h.blocks[0][1] == 0 and h.blocks[-1][2] == log.stat().st_size
    assert all(a[2] == b[1] for a, b in zip(h.blocks, h.blocks[1:]))                      # the blocks tile the log


@pytest.mark.parametrize("log", [UBX_WALK, RAWX_LOG])
@pytest.mark.parametrize("block_s", [7.0, 60.0])
def test_the_blocks_join_to_the_whole_logs_reading(log, block_s):
    sigs = list(UBX_SIGNALS)
    h = ubx_hours(log, block_s)
    parts, last = [], None
    for j in range(len(h.blocks)):
        b = read_ubx_block(log, h.block_bytes(j), sigs)
        check_ubx_block(h, j, b, last)
        last = float(b["time_s"][-1])
        parts.append(b)
    info = join_ubx_infos([b["info"] for b in parts], [a for _, a, _, _ in h.blocks])
    nav, info["sfrbx"] = sfrbx_of_blocks(b"".join(b["sfrbx"] for b in parts), info["week"])
    info["rtcm_base"] = rtcm_station_arp([r for b in parts for r in b["rtcm_arp"]])
    w_info, w_obs, w_nav = read_ubx_log(log)
    assert json.dumps(info) == json.dumps(w_info)                      # key for key, in the same order
    assert pd.concat([b["obs"] for b in parts], ignore_index=True).equals(w_obs)
    assert pd.concat([b["signals"] for b in parts], ignore_index=True).equals(read_ubx_signals(log, sigs))
    assert nav.equals(w_nav) and (len(nav) > 0) == (log == UBX_WALK)


# ------------------------------------------------------------------------------------------------
# the ingest: the same RUN


@pytest.mark.parametrize("signals", [(), ("G:L1", "G:L2", "E:E1", "E:E5a"), ("E:E1", "E:E5a")])
def test_a_real_ublox_log_block_by_block_is_the_whole_logs_run(tmp_path, monkeypatch, signals):
    """The walk log alone (its ephemerides from its RXM-SFRBX frames), with GPS L1 only, with four signals, and
    anchored on Galileo E1."""
    how = _same_run(_config(tmp_path, {"walk": ("ubx", UBX_WALK)}, signals), tmp_path, monkeypatch)
    assert how["hour_by_hour"] and how["blocks"] == 5


def test_a_ublox_record_of_several_logs(tmp_path, monkeypatch):
    """The walk log cut before two RXM-RAWX frames into three logs, given out of time order: their ephemerides
    decoded across the logs (one has its subframes in two of them), the joins the whole reading's."""
    data = UBX_WALK.read_bytes()
    off = [o for o, _ in _rawx_frames(data)]
    bounds = [0, off[200], off[400], len(data)]
    for name, (a, b) in zip("bca", zip(bounds[:-1], bounds[1:])):      # (by name: the last piece first)
        (tmp_path / f"walk_{name}.ubx").write_bytes(data[a:b])
    cfg = _config(tmp_path, {"walk": ("ubx", f"{tmp_path}/walk_*.ubx")}, ("G:L1", "E:E1"))
    how = _same_run(cfg, tmp_path, monkeypatch)
    assert how["hour_by_hour"]
    s, _ = _ingest(cfg, tmp_path / "again.mcap", False, monkeypatch, 30.0)
    assert s["ephemerides"] == 19 and [f["epochs"] for f in s["joins"]["walk"]["files"]] == [200, 200, 136]


def test_a_pair_of_a_rinex_master_and_a_ublox_rover(tmp_path, monkeypatch):
    """The walk receiver's own RINEX (convbin) as the master and its UBX log as the rover (one receiver: every epoch
    in common), with the RINEX navigation file; and two UBX logs."""
    how = _same_run(_config(tmp_path, {"base": ("rinex", WALK / "gnss_1730_convbin.obs"), "rover": ("ubx", UBX_WALK)},
                            nav=[WALK / "gnss_1730_convbin.nav"]), tmp_path, monkeypatch)
    assert how["hour_by_hour"]
    (tmp_path / "copy.ubx").write_bytes(UBX_WALK.read_bytes())
    how = _same_run(_config(tmp_path, {"base": ("ubx", UBX_WALK), "rover": ("ubx", tmp_path / "copy.ubx")},
                            master_xyz=WALK_XYZ), tmp_path, monkeypatch, 45.0)
    assert how["hour_by_hour"]


def _retimed(data: bytes, shift_s: float) -> bytes:
    """The log with every RXM-RAWX epoch moved by ``shift_s`` (week and rcvTow rewritten, checksums again) and
    without its RXM-SFRBX frames (ephemerides of another day); the other frames and the bytes between them as they
    are."""
    out, at = [], 0
    for off, cls, mid, fr in split_stream(data)[0]:
        if (cls, mid) == (0x02, 0x13):
            out.append(data[at:off])
            at = off + len(fr)
        if (cls, mid) != (0x02, 0x15):
            continue
        tow, week = struct.unpack_from("<dH", fr, 6)
        out += [data[at:off], _with_time(fr, week * 604800.0 + tow + shift_s)]
        at = off + len(fr)
    return b"".join(out + [data[at:]])


def test_a_ublox_log_across_a_gps_week(tmp_path, monkeypatch):
    """The walk log's epochs moved so that the end of a GPS week falls in its middle: blocks on both sides, the same
    RUN (without ephemerides: a single receiver is ingested with a warning)."""
    data = UBX_WALK.read_bytes()
    t0 = _rawx_frames(data)[0][1]
    shift = (math.floor(t0 / 604800) + 1) * 604800.0 - 60.0 - t0
    (tmp_path / "w.ubx").write_bytes(_retimed(data, shift))
    h = ubx_hours(tmp_path / "w.ubx", 3600.0)
    assert len(h.blocks) == 2 and h.blocks[1][3] >= (math.floor(t0 / 604800) + 1) * 604800.0
    how = _same_run(_config(tmp_path, {"walk": ("ubx", tmp_path / "w.ubx")}), tmp_path, monkeypatch, 3600.0)
    assert how["hour_by_hour"]


def _rtcm(mtype: int, payload_bits: list) -> bytes:
    """An RTCM 3 frame of message ``mtype`` with the fields ``payload_bits`` [(value, bits)] after its number."""
    from cdgps_cli.io.ubx_frames import crc24q

    v, n = mtype, 12
    for value, bits in payload_bits:
        v, n = (v << bits) | (value & ((1 << bits) - 1)), n + bits
    n_bytes = (n + 7) // 8
    body = (v << (8 * n_bytes - n)).to_bytes(n_bytes, "big")
    head = bytes([0xD3, n_bytes >> 8, n_bytes & 0xFF]) + body
    return head + crc24q(head).to_bytes(3, "big")


def test_a_base_log_with_rtcm_between_its_frames(tmp_path, monkeypatch):
    """A base's log with RTCM 3 between its frames (a station position 1005 every 100 epochs, an MSM-sized 1077 after
    every epoch), one block ending in an RTCM frame: the same RUN, the station position the last 1005's."""
    x, y, z = (round(c * 1e4) for c in WALK_XYZ)
    st = _rtcm(1005, [(42, 12), (0, 6), (1, 4), (x, 38), (0, 2), (y, 38), (0, 2), (z, 38)])
    msm = _rtcm(1077, [(42, 12), (123456, 30)] + [(7, 8)] * 40)
    data = UBX_WALK.read_bytes()
    frames = _rawx_frames(data)
    h = ubx_hours(UBX_WALK, 30.0)
    cut = h.blocks[2][1]
    out, at = [], 0
    for i, (off, _) in enumerate(frames[1:], 1):
        out += [data[at:off], msm + (st if i % 100 == 0 or off == cut else b"")]
        at = off
    (tmp_path / "base.ubx").write_bytes(b"".join(out + [data[at:]]))
    how = _same_run(_config(tmp_path, {"base": ("ubx", tmp_path / "base.ubx")}), tmp_path, monkeypatch)
    assert how["hour_by_hour"]
    s, _ = _ingest(_config(tmp_path, {"base": ("ubx", tmp_path / "base.ubx")}), tmp_path / "again.mcap", False,
                   monkeypatch, 30.0)
    assert s["receivers"][0]["position_source"].startswith("RTCM 1005") and s["integrity"]["base"]["problems"] == []


# ------------------------------------------------------------------------------------------------
# what the blocks cannot give: read whole


def _corrupt(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1:]


def test_damaged_logs_block_by_block_are_the_whole_logs_run(tmp_path, monkeypatch):
    """Losses inside the blocks (a frame failing its checksum, the log cut short) are counted as the whole reading
    counts them, byte offsets in the log included; noise just before a block's first frame, where a framing of the
    whole log could read across the cut, and a compressed log are read whole."""
    data = UBX_WALK.read_bytes()
    frames = _rawx_frames(data)
    h = ubx_hours(UBX_WALK, 30.0)
    cut = h.blocks[2][1]
    cases = {
        "a corrupt frame": (_corrupt(data, frames[300][0] + 40), True),
        "two corrupt frames and noise": (_corrupt(_corrupt(data, frames[10][0] + 3), frames[420][0] + 9)[:frames[200][0]]
                                         + b"\xb5\x62\x02\x15\x00" + data[frames[200][0]:], True),
        "cut short": (data[:frames[500][0] + 100], True),
        "noise before a block": (data[:cut] + b"\xd3\x00\x13\x3e\xd0" + data[cut:], False),
        "compressed": (gzip.compress(data, mtime=0), False),
    }
    for what, (content, by_blocks) in cases.items():
        (tmp_path / "log.ubx").write_bytes(content)
        how = _same_run(_config(tmp_path, {"walk": ("ubx", tmp_path / "log.ubx")}), tmp_path, monkeypatch)
        assert how["hour_by_hour"] == by_blocks, (what, how)


@pytest.mark.parametrize("seed", range(4))
def test_random_damage_gives_the_whole_logs_run(tmp_path, monkeypatch, seed):
    """Bytes flipped, dropped and inserted at random places of the log: block by block or whole, the same RUN
    (more seeds in the session's note)."""
    rng = np.random.default_rng(seed)
    data = bytearray(UBX_WALK.read_bytes())
    for at in sorted(rng.integers(0, len(data) - 1, 6).tolist(), reverse=True):
        kind = rng.integers(3)
        if kind == 0:
            data[at] ^= int(rng.integers(1, 256))
        elif kind == 1:
            del data[at:at + int(rng.integers(1, 40))]
        else:
            data[at:at] = rng.integers(0, 256, int(rng.integers(1, 40))).astype(np.uint8).tobytes()
    (tmp_path / "log.ubx").write_bytes(bytes(data))
    _same_run(_config(tmp_path, {"walk": ("ubx", tmp_path / "log.ubx")}), tmp_path, monkeypatch, 20.0)


def test_strict_refuses_a_damaged_log_as_whole(tmp_path, monkeypatch):
    data = UBX_WALK.read_bytes()
    (tmp_path / "log.ubx").write_bytes(_corrupt(data, _rawx_frames(data)[300][0] + 40))
    cfg = load_gnss_config(_config(tmp_path, {"walk": ("ubx", tmp_path / "log.ubx")}))
    with monkeypatch.context() as m:
        m.setattr(gnss_archive, "OBS_BLOCK_S", 30.0)
        with pytest.raises(gnss_ingest.CdgpsError, match=r"corrupt UBX data: 1 frame\(s\) failing the checksum \(byte offsets"
                           r".*the first loss is at byte \d+, after the epoch of 2025-08-28 17:31:\d\d"):
            gnss_ingest.ingest_gnss(cfg, tmp_path / "out.mcap", strict=True)     # (the file, its byte and the time)
    assert not (tmp_path / "out.mcap").exists()


def test_a_log_with_esf_messages_is_read_whole(tmp_path, monkeypatch):
    """ESF-MEAS (the receiver's IMU; here one accelerometer sample): the sensor tables read the log whole, and so
    does the ingest."""
    esf = _frame(0x10, 0x02, struct.pack("<IHH", 75_000, 1 << 11, 0) + struct.pack("<I", (16 << 24) | 1024))
    (tmp_path / "log.ubx").write_bytes(UBX_WALK.read_bytes() + esf)
    how = _same_run(_config(tmp_path, {"walk": ("ubx", tmp_path / "log.ubx")}), tmp_path, monkeypatch)
    assert not how["hour_by_hour"] and "ESF" in how["why_whole"]


def _with_time(fr: bytes, t: float, week: int | None = None) -> bytes:
    """An RXM-RAWX frame with its time set to ``t`` GPS s (or its week field to ``week``), checksum again."""
    pl = bytearray(fr[6:-2])
    w = int(t // 604800) if math.isfinite(t) else struct.unpack_from("<H", pl, 8)[0]
    struct.pack_into("<dH", pl, 0, t - w * 604800.0, w if week is None else week)
    return _frame(0x02, 0x15, bytes(pl))


def test_what_a_review_found_is_read_as_whole(tmp_path, monkeypatch):
    """A review's reproductions: a valid frame carrying frames in its payload just before a block's first RXM-RAWX
    frame (a framing of the whole log reads the carrier, and not the RXM-RAWX frame inside it, which the cut found:
    read whole); an epoch with a NaN time (now an undecodable frame, counted, in both readings: it was a traceback in
    the writer); a first epoch in GPS week 0 or a year early (a bisection per block with an epoch, not one per hour
    between): the whole reading's RUN or error."""
    data = UBX_WALK.read_bytes()
    frames = _rawx_frames(data)
    h = ubx_hours(UBX_WALK, 7.0)
    cut = h.blocks[3][1]
    i = next(k for k, (o, _) in enumerate(frames) if o == cut)
    inner = _with_time(data[cut:frames[i + 1][0]][:data[cut:].index(b"\xb5\x62", 2)], h.blocks[3][3] - 0.001)
    carrier = _frame(0x21, 0x99, _frame(0x0A, 0x04, b"\x00" * 4) + inner)
    nan_epoch = _with_time(data[frames[300][0]:frames[301][0]][:data[frames[300][0]:].index(b"\xb5\x62", 2)],
                           float("nan"))
    o0 = frames[0][0]
    first = data[o0:o0 + 8 + int.from_bytes(data[o0 + 4:o0 + 6], "little")]
    cases = {
        "a frame across the cut": data[:cut] + carrier + data[cut:],
        "a NaN time": data[:frames[300][0]] + nan_epoch + data[frames[300][0]:],
        "week 0 first": data[:o0] + _with_time(first, frames[0][1], week=0) + data[o0 + len(first):],
        "a year early first": data[:o0] + _with_time(first, frames[0][1] - 3.15e7) + data[o0 + len(first):],
    }
    for what, content in cases.items():
        (tmp_path / "log.ubx").write_bytes(content)
        cfg = _config(tmp_path, {"walk": ("ubx", tmp_path / "log.ubx")}, nav=[WALK / "gnss_1730_convbin.nav"])
        got = []
        for whole in (False, True):
            try:
                s, _ = _ingest(cfg, tmp_path / f"{whole}.mcap", whole, monkeypatch, 7.0)
                got.append((s.pop("reading"), s.pop("output") and None, s, (tmp_path / f"{whole}.mcap").read_bytes()))
            except gnss_ingest.CdgpsError as exc:
                got.append(str(exc))
        if isinstance(got[0], str) or isinstance(got[1], str):
            assert got[0] == got[1], what
        else:
            assert got[0][2:] == got[1][2:], what
            assert got[0][0]["hour_by_hour"] == (what != "a frame across the cut"), (what, got[0][0])
            if what == "a NaN time":                 # (not a time: counted as an undecodable frame, as whole)
                assert got[0][2]["integrity"]["walk"]["undecodable_frames"] == 1
    assert len(ubx_hours(tmp_path / "log.ubx", 7.0).blocks) == len(h.blocks) + 1      # (the year early: one more)


def test_an_error_is_the_whole_logs_error(tmp_path, monkeypatch):
    """An epoch out of time order in a late block, and a legacy RXM-RAW log: exit 2 as whole, the same message."""
    data = UBX_WALK.read_bytes()
    frames = _rawx_frames(data)
    a, b = frames[450][0], frames[451][0]
    c = frames[452][0]
    (tmp_path / "log.ubx").write_bytes(data[:a] + data[b:c] + data[a:b] + data[c:])       # two epochs swapped
    cfg = _config(tmp_path, {"walk": ("ubx", tmp_path / "log.ubx")})
    errors = []
    for whole in (False, True):
        with pytest.raises(gnss_ingest.CdgpsError) as exc:
            _ingest(cfg, tmp_path / f"out{whole}.mcap", whole, monkeypatch, 30.0)
        errors.append(str(exc.value))
        assert not (tmp_path / f"out{whole}.mcap").exists()
    assert errors[0] == errors[1] and "earlier than the previous one" in errors[0]
    if LEGACY.is_file():
        cfg = _config(tmp_path, {"old": ("ubx", LEGACY)})
        with pytest.raises(gnss_ingest.CdgpsError, match="RXM-RAW"):
            _ingest(cfg, tmp_path / "old.mcap", False, monkeypatch, 30.0)


def test_thin_ublox_tables_give_the_lock_counts(tmp_path, monkeypatch):
    """The lock counters of a UBX receiver from its thin tables (time, satellite, phase, lock time, half cycle) are
    those of its whole tables, GPS L1 and anchored on another signal."""
    from cdgps_cli.io.gnss_run import read_receiver_file
    from cdgps_cli.io.ubx import read_ubx_signals as sig

    rx = read_receiver_file("walk", "ubx", UBX_WALK)
    rx.signals = sig(UBX_WALK, ["E:E1", "G:L1"])
    thin = gnss_hours.ThinTables(ubx=True)
    thin.add(rx.raw, rx.signals)
    small = type(rx)(rx.name, rx.format, rx.file, rx.header, thin.frame("raw"), rx.info, rx.nav)
    small.signals = thin.frame("signals")
    for signals in ((), ("E:E1", "G:L1")):
        want = gnss_ingest.lock_summary(rx, gnss_ingest.anchor_obs(rx, signals)[
            ["time_gps_s", "sat", "phase_l1_cycles", "lli_l1"]])
        assert gnss_ingest.lock_summary(small, gnss_ingest.lock_obs(small, signals)) == want
        assert gnss_ingest.lock_summary(rx, gnss_ingest.lock_obs(rx, signals)) == want
    assert np.isin(["lock_time_ms", "half_cycle"], small.raw.columns).all()
    r = rx.raw                         # in groups of satellites of 500 rows: the bits of all the rows at once
    want = gnss_ingest.ubx_loss_of_lock(r["time_gps_s"].to_numpy(), r["sat"].to_numpy(), r["phase_cycles"].to_numpy(),
                                        r["lock_time_ms"].to_numpy(dtype=float), r["half_cycle"].to_numpy() == 1)
    monkeypatch.setattr(gnss_ingest, "_LOCK_ROWS_PER_PASS", 500)
    assert len(gnss_ingest._channel_groups(np.bincount(pd.factorize(r["sat"])[0]), 500)) > 5
    for tab in (r, small.raw):
        assert np.array_equal(gnss_ingest._ubx_lli(tab, tab["time_gps_s"].to_numpy(), None), want)


def test_frame_checksum_is_the_byte_by_byte_fletcher_sum():
    """The vectorised check equals the UBX protocol's byte-by-byte 8-bit Fletcher loop and the stream's prefix-sum
    checksums (ubx_frames._Fletcher), and refuses a frame with one payload byte or one checksum byte changed."""
    from cdgps_cli.io.ubx_frames import _Fletcher  # noqa: PLC0415
    from cdgps_cli.io.ubx_hours import _fletcher_ok  # noqa: PLC0415

    rng = np.random.default_rng(3)
    for n in (0, 1, 16, 255, 256, 1000, 4000):
        body = bytes([0x02, 0x15]) + n.to_bytes(2, "little") + rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        a = b = 0
        for byte in body:
            a, b = (a + byte) & 0xFF, (b + a + byte) & 0xFF
        frame = b"\xb5\x62" + body + bytes((a, b))
        assert _Fletcher(frame)(2, len(frame) - 2) == bytes((a, b))
        assert _fletcher_ok(frame)
        for k in (4, len(frame) - 1, len(frame) - 2):
            bad = bytearray(frame)
            bad[k] ^= 0x01
            assert not _fletcher_ok(bytes(bad)), (n, k)
