"""``cdgps ingest`` of many consecutive files per antenna as one record (issue 29, item 2).

Real files are cut into pieces (RINEX at chosen epochs with :func:`cdgps_cli.sim.rinex_edit.edit_rinex3_obs`,
UBX at frame boundaries, the receiver CSV at chosen times); ingesting the pieces — given in any
order, by repeating the option or by a quoted glob — must give the RUN of the whole file: the same
messages (every topic, byte for byte), the same observation and ephemeris attachments; only the
provenance differs (the ``cdgps.ingest`` input names and sha256, ``record_sha256``, and
``gnss/receivers.json``, which lists the files).  Day boundaries and GPS week rollovers inside the
record are continuous; overlaps, gaps, mismatched and damaged files are reported or refused.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.io.log_sequence import expand_paths, join_tables
from cdgps_cli.io.ubx_frames import split_stream
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
MOSAIC_ROVER = DATA / "real-pairs" / "mosaic-static" / "rover.obs"
UBX_WALK = DATA / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
PROVENANCE_ATTACHMENTS = {"gnss/receivers.json"}


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _parts(path):
    """(messages: (topic, log time, publish time, sequence, bytes) in file order, attachments, metadata)."""
    with open(path, "rb") as fh:
        r = make_reader(fh)
        msgs = [(ch.topic, m.log_time, m.publish_time, m.sequence, m.data) for _, ch, m in r.iter_messages(log_time_order=False)]
        att = {a.name: a.data for a in r.iter_attachments()}
        meta = {m.name: dict(m.metadata) for m in r.iter_metadata()}
    return msgs, att, meta


def _is_input_key(k: str) -> bool:
    return k in ("record_sha256", "ephemeris_source") or any(k.startswith(p) for p in ("rinex:", "ubx:", "receiver_csv", "gyro_csv",
                                                                   "actuator_csv"))


def _info_counts(data: bytes) -> dict:
    """gnss/info.json without the receivers' file names."""
    info = json.loads(data)
    info["receivers"] = [{k: v for k, v in r.items() if k != "file"} for r in info["receivers"]]
    return info


def assert_same_record(whole: Path, pieces: Path, n_files: dict, other_config: bool = False) -> None:
    """The RUN of the pieces has the whole file's data (see the module docstring) and names every piece
    (``other_config``: the pieces were listed in another config file, whose name and sha256 differ)."""
    mw, aw, tw = _parts(whole)
    mp, ap, tp = _parts(pieces)
    assert len(mw) > 0 and mw == mp
    assert set(aw) == set(ap)
    for k in aw:
        if k == "gnss/info.json":          # info's receivers: the same counts, each naming its own files
            assert _info_counts(aw[k]) == _info_counts(ap[k])
        elif k not in PROVENANCE_ATTACHMENTS | ({"config.toml"} if other_config else set()):
            assert aw[k] == ap[k], k
    iw, ip = tw["cdgps.ingest"], tp["cdgps.ingest"]
    skip = {"config_path", "config_sha256"} if other_config else set()
    assert ({k: v for k, v in iw.items() if not _is_input_key(k) and k not in skip}
            == {k: v for k, v in ip.items() if not _is_input_key(k) and k not in skip})
    for key, n in n_files.items():      # the pieces in time order, each with its sha256
        assert [ip[f"{key}[{i}]"] for i in range(n)] and all(f"{key}[{i}]_sha256" in ip for i in range(n))
        assert f"{key}[{n}]" not in ip and key not in ip


# ------------------------------------------------------------------------------------------------
# RINEX


def _split_rinex(src: Path, out: Path, stem: str, bounds, suffix=".obs") -> list[Path]:
    """RINEX 3 pieces [b_i, b_{i+1}) of ``src`` (GPS s bounds; -inf/inf for open ends)."""
    text = src.read_text()
    paths = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        p = out / f"{stem}_{i:02d}{suffix}"
        p.write_text(edit_rinex3_obs(text, keep=lambda t, a=a, b=b: a <= t < b))
        paths.append(p)
    return paths


T0_MOSAIC = gps_seconds(2024, 6, 24, 8, 20)


@pytest.fixture(scope="module")
def mosaic(tmp_path_factory):
    """The real mosaic-X5 rover file (301 epochs at 1 s), its RUN, and three pieces of it."""
    d = tmp_path_factory.mktemp("mosaic")
    pieces = _split_rinex(MOSAIC_ROVER, d, "rover", [-np.inf, T0_MOSAIC + 100, T0_MOSAIC + 200, np.inf])
    r = _cli("-q", "ingest", "--rinex", f"R={MOSAIC_ROVER}", "-o", d / "whole.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert "joins" not in json.loads(r.stdout)                     # one file: the old provenance keys
    meta = _parts(d / "whole.mcap")[2]["cdgps.ingest"]
    assert meta["rinex:R"] == "rover.obs" and "rinex:R[0]" not in meta
    return d, pieces


def test_rinex_pieces_in_any_order_give_the_whole_files_run(mosaic):
    d, (a, b, c) = mosaic
    # given out of time order, by repetition and by a glob (the order comes from the first epochs)
    r = _cli("ingest", "--rinex", f"R={c}", "--rinex", f"R={d}/rover_0[01].obs", "-o", d / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(d / "whole.mcap", d / "p.mcap", {"rinex:R": 3})
    s = json.loads(r.stdout)
    j = s["joins"]["R"]
    assert [f["file"] for f in j["files"]] == ["rover_00.obs", "rover_01.obs", "rover_02.obs"]
    assert j["gaps"] == [] and j["overlaps"] == []
    meta = _parts(d / "p.mcap")[2]["cdgps.ingest"]
    assert [meta[f"rinex:R[{i}]"] for i in range(3)] == ["rover_00.obs", "rover_01.obs", "rover_02.obs"]
    run = read_gnss_run(d / "p.mcap")
    assert run.receivers["R"].raw.equals(read_gnss_run(d / "whole.mcap").receivers["R"].raw)


def test_rinex_overlap_is_kept_once_with_a_warning_naming_both_files(mosaic, tmp_path):
    d, _ = mosaic
    a, b = _split_rinex(MOSAIC_ROVER, tmp_path, "ov", [-np.inf, T0_MOSAIC + 150, np.inf])
    b.write_text(edit_rinex3_obs(MOSAIC_ROVER.read_text(), keep=lambda t: t >= T0_MOSAIC + 140))   # 10 s repeated
    r = _cli("ingest", "--rinex", f"R={tmp_path}/ov_*.obs", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(d / "whole.mcap", tmp_path / "p.mcap", {"rinex:R": 2})
    ov = json.loads(r.stdout)["joins"]["R"]["overlaps"]
    assert ov == [{"file": "ov_01.obs", "earlier_file": "ov_00.obs", "start_s": T0_MOSAIC + 140,
                   "end_s": T0_MOSAIC + 149, "epochs": 10, "identical": True}]
    assert "ov_01.obs repeats 10 epoch(s) of ov_00.obs (2024-06-24 08:22:20 GPST – 2024-06-24 08:22:29 GPST)" in r.output


def test_rinex_gap_between_files_is_reported_with_its_times(mosaic, tmp_path):
    a, b = _split_rinex(MOSAIC_ROVER, tmp_path, "g", [-np.inf, T0_MOSAIC + 100, np.inf])
    b.write_text(edit_rinex3_obs(MOSAIC_ROVER.read_text(), keep=lambda t: t >= T0_MOSAIC + 130))
    r = _cli("ingest", "--rinex", f"R={a}", "--rinex", f"R={b}", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    gaps = json.loads(r.stdout)["joins"]["R"]["gaps"]
    assert gaps == [{"after": "g_00.obs", "before": "g_01.obs", "start_s": T0_MOSAIC + 99, "end_s": T0_MOSAIC + 130,
                     "gap_s": 31.0, "missing_epochs": 30}]
    assert ("gap of 31 s (30 epochs missing) between g_00.obs (last epoch 2024-06-24 08:21:39 GPST) and g_01.obs "
            "(first epoch 2024-06-24 08:22:10 GPST)") in r.output


def test_rinex_file_of_another_rate_or_receiver_is_refused_naming_it(mosaic, tmp_path):
    a, _ = _split_rinex(MOSAIC_ROVER, tmp_path, "m", [-np.inf, T0_MOSAIC + 100, np.inf])
    slow = tmp_path / "m_slow.obs"
    slow.write_text(edit_rinex3_obs(MOSAIC_ROVER.read_text(), keep=lambda t: t >= T0_MOSAIC + 100 and t % 2 == 0))
    r = _cli("ingest", "--rinex", f"R={a}", "--rinex", f"R={slow}", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "m_slow.obs (R): epoch interval 2 s differs from 1 s in" in r.output
    other = tmp_path / "m_other.obs"
    other.write_text(edit_rinex3_obs(MOSAIC_ROVER.read_text(), keep=lambda t: t >= T0_MOSAIC + 100)
                     .replace("SEPT MOSAIC-X5      ", "TRIMBLE NETR9       ", 1))
    r = _cli("ingest", "--rinex", f"R={a}", "--rinex", f"R={other}", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "m_other.obs (R): receiver_type 'TRIMBLE NETR9' differs from 'SEPT MOSAIC-X5'" in r.output
    assert not (tmp_path / "p.mcap").exists()


def test_truncated_last_rinex_file_is_refused_naming_file_line_and_time(mosaic, tmp_path):
    a, b = _split_rinex(MOSAIC_ROVER, tmp_path, "t", [-np.inf, T0_MOSAIC + 100, np.inf])
    b.write_bytes(b.read_bytes()[:150_000])         # cut inside an epoch record
    r = _cli("ingest", "--rinex", f"R={tmp_path}/t_*.obs", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert f"{b}, line " in r.output and "GPST announces" in r.output and "but the file ends" in r.output
    assert not (tmp_path / "p.mcap").exists()


def test_interleaved_files_and_empty_patterns_are_refused(mosaic, tmp_path):
    a = tmp_path / "even.obs"
    b = tmp_path / "odd.obs"
    a.write_text(edit_rinex3_obs(MOSAIC_ROVER.read_text(), keep=lambda t: t % 2 == 0))
    b.write_text(edit_rinex3_obs(MOSAIC_ROVER.read_text(), keep=lambda t: t % 2 == 1))
    r = _cli("ingest", "--rinex", f"R={a}", "--rinex", f"R={b}", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "lies inside the span of the earlier file" in r.output and "not consecutive" in r.output
    r = _cli("ingest", "--rinex", f"R={tmp_path}/nothing_*.obs", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and "--rinex R: the pattern" in r.output and "matches no file" in r.output


# ------------------------------------------------------------------------------------------------
# a day boundary and a GPS week rollover inside the record (simulated RINEX pair)


def test_saturday_midnight_week_rollover_rinex_pair(tmp_path):
    """Simulated base + rover crossing 2024-01-06 24:00 GPST (Saturday → Sunday: new day, GPS week
    2295 → 2296), each cut at midnight and 30 s later; the pieces (listed by glob in the config)
    give the whole record, with continuous times across the rollover."""
    r = _cli("-q", "simulate-gnss", "--start", "2024-01-06T23:59:00", "--duration", 120, "-o", tmp_path)
    assert r.exit_code == 0, r.output
    mid = gps_seconds(2024, 1, 7)
    assert mid % 604800 == 0                                  # the week rollover
    for n in ("base", "rover"):
        _split_rinex(tmp_path / f"{n}.rnx", tmp_path, n, [-np.inf, mid, mid + 30, np.inf], suffix=".rnx")
    cfg = (tmp_path / "config.toml").read_text()
    (tmp_path / "pieces.toml").write_text(cfg.replace('"base.rnx"', '"base_*.rnx"').replace('"rover.rnx"', '"rover_0?.rnx"'))
    r = _cli("-q", "ingest", "--config", tmp_path / "config.toml", "-o", tmp_path / "whole.mcap")
    assert r.exit_code == 0, r.output
    r = _cli("-q", "ingest", "--config", tmp_path / "pieces.toml", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(tmp_path / "whole.mcap", tmp_path / "p.mcap", {"rinex:base": 3, "rinex:rover": 3},
                       other_config=True)
    s = json.loads(r.stdout)
    assert s["common_epochs"]["rover"]["common_epochs"] == 120
    for n in ("base", "rover"):
        t = np.unique(read_gnss_run(tmp_path / "p.mcap").receivers[n].raw["time_gps_s"].to_numpy())
        assert t.size == 120 and t[0] < mid <= t[-1]
        assert np.all(np.abs(np.diff(t) - 1.0) < 0.02)          # 1 s epochs (ms clock tags), no jump at the rollover
        assert s["joins"][n]["gaps"] == [] and len(s["joins"][n]["files"]) == 3


# ------------------------------------------------------------------------------------------------
# UBX


def _ubx_frame(cls: int, mid: int, payload: bytes) -> bytes:
    body = bytes([cls, mid]) + struct.pack("<H", len(payload)) + payload
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


def _rawx_offsets(data: bytes) -> list[int]:
    return [off for off, cls, mid, _ in split_stream(data)[0] if (cls, mid) == (0x02, 0x15)]


def _split_bytes(data: bytes, out: Path, stem: str, cuts) -> list[Path]:
    bounds = [0, *cuts, len(data)]
    paths = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        p = out / f"{stem}_{i:02d}.ubx"
        p.write_bytes(data[a:b])
        paths.append(p)
    return paths


@pytest.fixture(scope="module")
def ubx_whole(tmp_path_factory) -> Path:
    """The RUN of the whole walk log."""
    out = tmp_path_factory.mktemp("ubx") / "whole.mcap"
    r = _cli("-q", "ingest", "--ubx", f"U={UBX_WALK}", "-o", out)
    assert r.exit_code == 0, r.output
    return out


def test_ubx_pieces_cut_at_frames_give_the_whole_logs_run(tmp_path, ubx_whole):
    """The real u-blox F9P walk log (RXM-RAWX at 4 Hz, RXM-SFRBX, NMEA) cut before two RXM-RAWX frames:
    the same observations and the same 19 ephemerides (the RXM-SFRBX subframes are decoded across
    the cuts: one ephemeris has its subframes in two pieces)."""
    data = UBX_WALK.read_bytes()
    off = _rawx_offsets(data)
    _split_bytes(data, tmp_path, "walk", [off[200], off[400]])
    r = _cli("-q", "ingest", "--ubx", f"U={tmp_path}/walk_*.ubx", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(ubx_whole, tmp_path / "p.mcap", {"ubx:U": 3})
    s = json.loads(r.stdout)
    assert s["ephemerides"] == 19 and s["integrity"]["U"]["problems"] == []
    assert [f["epochs"] for f in s["joins"]["U"]["files"]] == [200, 200, 136]


def test_ubx_frame_cut_by_file_rotation_is_joined_again(tmp_path, ubx_whole):
    """A logger rotating files by size cuts frames in two: the walk log cut inside an RXM-RAWX frame
    and inside the next frame after another 300 epochs gives the whole log's RUN (no epoch lost),
    with a warning and nothing for --strict to refuse."""
    data = UBX_WALK.read_bytes()
    off = _rawx_offsets(data)
    _split_bytes(data, tmp_path, "rot", [off[200] + 50, off[500] + 7])
    r = _cli("ingest", "--strict", "--ubx", f"U={tmp_path}/rot_*.ubx", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(ubx_whole, tmp_path / "p.mcap", {"ubx:U": 3})
    s = json.loads(r.stdout)
    assert s["joins"]["U"]["frames_joined_across_files"] == ["rot_00.ubx → rot_01.ubx", "rot_01.ubx → rot_02.ubx"]
    assert s["integrity"]["U"]["problems"] == [] and s["receivers"][0]["epochs"] == 536
    assert s["joins"]["U"]["gaps"] == [] and "gap of" not in r.output
    assert "UBX frame(s) cut by the file rotation (rot_00.ubx → rot_01.ubx, rot_01.ubx → rot_02.ubx) joined again" in r.output
    (tmp_path / "rot_01.ubx").write_bytes(data[off[200] + 50: off[300]] + b"\xb5\x62\x02\x15junk" + data[off[300]: off[500] + 7])
    r = _cli("ingest", "--ubx", f"U={tmp_path}/rot_*.ubx", "-o", tmp_path / "q.mcap", "--json")
    assert r.exit_code == 0, r.output                      # a real loss left after the join names its file and byte
    s = json.loads(r.stdout)
    assert s["integrity"]["U"]["problems"] == [f"1 frame(s) failing the checksum (byte offsets rot_01.ubx byte "
                                               f"{off[300] - off[200] - 50})", "8 bytes skipped between frames"]
    assert s["joins"]["U"]["gaps"] == [] and "gap of" not in r.output      # the cut epochs are found again


def test_ubx_pieces_with_one_missing_are_not_joined_across_the_hole(tmp_path):
    """Three pieces cut inside frames, the middle one missing: nothing is joined again across the hole, each piece's
    own loss (its truncated tail) is said, and the gap (the gate itself: the test below)."""
    data = UBX_WALK.read_bytes()
    off = _rawx_offsets(data)
    paths = _split_bytes(data, tmp_path, "hole", [off[150] + 60, off[330] + 60])
    paths[1].unlink()
    r = _cli("ingest", "--ubx", f"U={tmp_path}/hole_*.ubx", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert "frames_joined_across_files" not in s["joins"]["U"] and "joined again" not in r.output
    assert not any("checksum" in p for p in s["integrity"]["U"]["problems"]), s["integrity"]["U"]["problems"]
    assert any("truncated frame at the end" in p for p in s["integrity"]["U"]["problems"])
    assert len(s["joins"]["U"]["gaps"]) == 1


def test_the_byte_stream_join_is_tried_only_between_logs_that_follow_one_another(tmp_path):
    """The gate of ``_rejoin_cut_frames``: a 287 s gap between two pieces of a 1 s log (a piece missing: the real M8P
    rover's case, where the join made a frame failing its checksum under a "joined again" claim) stops it before any
    byte is read; a 2 s gap (the epoch a cut frame held) and a base logging every 1–8 s with a 6 s gap go on to
    read the pieces (here absent: the read raises)."""
    import numpy as np
    import pandas as pd

    from cdgps_cli.io.gnss_run import GnssReceiver, _rejoin_cut_frames

    def rx(times):
        files = [{"file": "a.ubx", "truncated_tail_bytes": 41}, {"file": "b.ubx"}]
        return GnssReceiver("r", "ubx", "a.ubx", {}, pd.DataFrame({"time_gps_s": np.asarray(times, float)}),
                            {"files": files})
    missing = [tmp_path / "a.ubx", tmp_path / "b.ubx"]
    one_s = np.r_[np.arange(0.0, 300.0), np.arange(587.0, 900.0)]
    _rejoin_cut_frames("r", rx(one_s), {"overlaps": [], "gaps": [{"gap_s": 287.0}]}, missing, [])    # no read
    for times, gap in ((np.r_[np.arange(0.0, 300.0), np.arange(302.0, 600.0)], 2.0),
                       (np.cumsum(np.tile([1.0, 3.0, 8.0, 2.0], 100)), 6.0)):
        with pytest.raises((OSError, Exception)):
            _rejoin_cut_frames("r", rx(times), {"overlaps": [], "gaps": [{"gap_s": gap}]}, missing, [])


@pytest.mark.parametrize("frames, extra", [((100, 300), (0, 0)), ((150, 330), (60, 9))], ids=["at-frames", "inside-frames"])
def test_ubx_pieces_with_gnss_signals_keep_the_whole_logs_signal_table(tmp_path, frames, extra):
    """With ``[gnss] signals`` the multi-signal table (here GPS L1 + L2C, lock times and half-cycle flags) of the
    pieces is the whole log's too, whether they are cut at frames or inside RXM-RAWX frames (a logger's file
    rotation: then the one byte stream's, as the GPS L1 table is; a sweep of real u-blox files found the M8P pair in
    pieces losing 21 base and 20 rover signal phases at the cuts, and 3 epochs of init)."""
    data = UBX_WALK.read_bytes()
    off = _rawx_offsets(data)
    _split_bytes(data, tmp_path, "sg", [off[frames[0]] + extra[0], off[frames[1]] + extra[1]])
    job = '[gnss]\nname = "walk"\nsignals = ["G:L1", "G:L2"]\nmaster = "U"\nnav = []\n\n[gnss.antennas.U]\nubx = "{}"\n'
    (tmp_path / "whole.toml").write_text(job.format(UBX_WALK))
    (tmp_path / "pieces.toml").write_text(job.format("sg_*.ubx"))
    for name in ("whole", "pieces"):
        r = _cli("-q", "ingest", "--config", tmp_path / f"{name}.toml", "-o", tmp_path / f"{name}.mcap")
        assert r.exit_code == 0, r.output
    assert "gnss/signals/0/blocks.json" in _parts(tmp_path / "pieces.mcap")[1]
    assert_same_record(tmp_path / "whole.mcap", tmp_path / "pieces.mcap", {"ubx:U": 3}, other_config=True)


def _rtcm1005(station: int, xyz_m) -> bytes:
    """An RTCM 3 message 1005 (station ARP, ECEF in 0.1 mm, 38-bit signed) with its CRC-24Q."""
    from cdgps_cli.io.ubx_frames import crc24q

    fields = [(1005, 12), (station, 12), (0, 6), (1, 1), (0, 1), (0, 1), (0, 1), (round(xyz_m[0] * 1e4), 38), (0, 1),
              (0, 1), (round(xyz_m[1] * 1e4), 38), (0, 2), (round(xyz_m[2] * 1e4), 38)]
    bits = 0
    for v, n in fields:
        bits = (bits << n) | (v & ((1 << n) - 1))
    payload = bits.to_bytes(19, "big")
    head = bytes((0xD3, 0, len(payload))) + payload
    return head + crc24q(head).to_bytes(3, "big")


def test_ubx_record_position_is_the_last_rtcm_base_of_its_files(tmp_path):
    """Only the second file carries the base's RTCM 1005: the record has its position (as the whole log
    would), and the summary says where it came from."""
    data = UBX_WALK.read_bytes()
    cut = _rawx_offsets(data)[300]
    xyz = (-3962108.6726, 3381309.5703, 3668678.6243)
    (tmp_path / "b_00.ubx").write_bytes(data[:cut])
    (tmp_path / "b_01.ubx").write_bytes(data[cut:] + _rtcm1005(7, xyz))
    r = _cli("-q", "ingest", "--ubx", f"U={tmp_path}/b_*.ubx", "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    rx = json.loads(r.stdout)["receivers"][0]
    assert rx["position_source"] == "RTCM 1005 ARP (station 7)"
    assert np.allclose(rx["position_ecef_m"], xyz, atol=1e-4)


def _retimed_rawx_log(data: bytes, shift_s: float) -> bytes:
    """The RXM-RAWX frames of a log only, every epoch moved by ``shift_s`` (week and rcvTow rewritten)."""
    out = []
    for _, cls, mid, fr in split_stream(data)[0]:
        if (cls, mid) != (0x02, 0x15):
            continue
        pl = bytearray(fr[6:-2])
        tow, week = struct.unpack_from("<dH", pl, 0)
        t = week * 604800.0 + tow + shift_s
        new_week = int(t // 604800)
        struct.pack_into("<dH", pl, 0, t - new_week * 604800.0, new_week)
        out.append(_ubx_frame(cls, mid, bytes(pl)))
    return b"".join(out)


def test_ubx_week_rollover_inside_the_record(tmp_path):
    """The walk log's RXM-RAWX epochs moved so that the end of GPS week 2381 falls in the middle of
    the record (a day boundary too), cut there: continuous times across the rollover, the whole
    log's observations."""
    data = UBX_WALK.read_bytes()
    t_first = [week * 604800.0 + tow for _, c, m, fr in split_stream(data)[0] if (c, m) == (0x02, 0x15)
               for tow, week in [struct.unpack_from("<dH", fr, 6)]]
    end_of_week = (int(t_first[0] // 604800) + 1) * 604800.0
    shift = end_of_week - t_first[268] + 0.125                  # epoch 268 lands 0.125 s after the rollover
    log = _retimed_rawx_log(data, shift)
    (tmp_path / "whole.ubx").write_bytes(log)
    off = _rawx_offsets(log)
    _split_bytes(log, tmp_path, "wk", [off[268]])
    r = _cli("-q", "ingest", "--ubx", f"U={tmp_path / 'whole.ubx'}", "-o", tmp_path / "whole.mcap")
    assert r.exit_code == 0, r.output
    r = _cli("-q", "ingest", "--ubx", f"U={tmp_path / 'wk_01.ubx'}", "--ubx", f"U={tmp_path / 'wk_00.ubx'}",
             "-o", tmp_path / "p.mcap")
    assert r.exit_code == 0, r.output
    assert_same_record(tmp_path / "whole.mcap", tmp_path / "p.mcap", {"ubx:U": 2})
    t = np.unique(read_gnss_run(tmp_path / "p.mcap").receivers["U"].raw["time_gps_s"].to_numpy())
    assert t[267] < end_of_week < t[268] and t.size == 536
    assert np.all(np.abs(np.diff(t) - 0.25) < 0.01)


def test_truncated_ubx_piece_warns_naming_file_and_time_and_strict_refuses(tmp_path):
    data = UBX_WALK.read_bytes()
    off = _rawx_offsets(data)
    a, b = _split_bytes(data[: off[500] + 40], tmp_path, "tr", [off[250]])     # the last file ends inside a frame
    r = _cli("ingest", "--ubx", f"U={tmp_path}/tr_*.ubx", "-o", tmp_path / "p.mcap")
    assert r.exit_code == 0, r.output
    assert ("tr_01.ubx (2 files) (U): corrupt UBX data, skipped: tr_01.ubx (last epoch 2025-08-28 17:32:44.498 GPST): "
            "40 bytes of a truncated frame at the end") in r.output
    r = _cli("ingest", "--strict", "--ubx", f"U={tmp_path}/tr_*.ubx", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and (f"{b} (U, epochs 2025-08-28 17:31:42.248 GPST – 2025-08-28 17:32:44.498 GPST): corrupt "
                                 f"UBX data: 40 bytes of a truncated frame at the end (refused by --strict)") in r.output
    assert not (tmp_path / "s.mcap").exists()


# ------------------------------------------------------------------------------------------------
# the native receiver CSV


@pytest.fixture(scope="module")
def testbed_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("csv")
    r = _cli("-q", "simulate", TESTBED, "--duration", 15, "--random-slips", 3, "-o", d)
    assert r.exit_code == 0, r.output
    r = _cli("-q", "ingest", d / "receiver.csv", d / "gyro.csv", "--config", TESTBED, "-o", d / "whole.mcap")
    assert r.exit_code == 0, r.output
    return d


def _split_csv(src: Path, out: Path, stem: str, bounds) -> list[Path]:
    lines = src.read_text().splitlines(keepends=True)
    t = np.array([float(x.split(",", 1)[0]) for x in lines[1:]])
    paths = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        p = out / f"{stem}_{i:02d}.csv"
        p.write_text(lines[0] + "".join(x for x, ti in zip(lines[1:], t) if a <= ti < b))
        paths.append(p)
    return paths


def test_receiver_csv_pieces_give_the_whole_logs_run(testbed_csv, tmp_path):
    d = testbed_csv
    _split_csv(d / "receiver.csv", tmp_path, "receiver", [-np.inf, 5.0, 10.0, np.inf])
    _split_csv(d / "gyro.csv", tmp_path, "gyro", [-np.inf, 7.5, np.inf])
    (tmp_path / "receiver_01.csv").write_text((tmp_path / "receiver_01.csv").read_text()
                                              + "".join(x for x in (d / "receiver.csv").read_text().splitlines(True)
                                                        if x.startswith("10.0,")))          # 10.0 s repeated in _02
    r = _cli("ingest", f"{tmp_path}/receiver_*.csv", f"{tmp_path}/gyro_*.csv", "--config", TESTBED,
             "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(d / "whole.mcap", tmp_path / "p.mcap", {"receiver_csv": 3, "gyro_csv": 2})
    s = json.loads(r.stdout)
    assert [f["file"] for f in s["joins"]["receiver_csv"]["files"]] == ["receiver_00.csv", "receiver_01.csv", "receiver_02.csv"]
    assert s["joins"]["receiver_csv"]["overlaps"][0]["start_s"] == 10.0
    assert "receiver_02.csv repeats 1 epoch(s) of receiver_01.csv (10 s – 10 s); the rows are identical" in r.output


def test_receiver_csv_gap_and_corrupt_piece(testbed_csv, tmp_path):
    d = testbed_csv
    a, b, c = _split_csv(d / "receiver.csv", tmp_path, "rx", [-np.inf, 5.0, 7.0, np.inf])
    b.unlink()
    r = _cli("ingest", f"{tmp_path}/rx_*.csv", "--config", TESTBED, "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    g = json.loads(r.stdout)["joins"]["receiver_csv"]["gaps"]
    assert g == [{"after": "rx_00.csv", "before": "rx_02.csv", "start_s": 4.9, "end_s": 7.0, "gap_s": pytest.approx(2.1),
                  "missing_epochs": 20}]
    assert "gap of 2.1 s (20 epochs missing) between rx_00.csv (last epoch 4.9 s) and rx_02.csv (first epoch 7 s)" in r.output
    c.write_text(c.read_text()[:-25])                     # the last file cut inside its last row
    r = _cli("ingest", f"{tmp_path}/rx_*.csv", "--config", TESTBED, "-o", tmp_path / "q.mcap")
    assert r.exit_code == 2 and f"{c}, line {len(c.read_text().splitlines())}" in r.output
    assert not (tmp_path / "q.mcap").exists()


def test_actuator_event_logs_join_without_a_rate_or_gaps(testbed_csv, tmp_path):
    """Actuator logs have rows only when a command changes: their pieces are joined without a rate
    check or a gap report (a 2.5 s pause between commands is not a gap)."""
    d = testbed_csv
    head = "time_s,actuator,force_n\n"
    rows = ["5.0,a3+z,1.4\n", "6.0,a3+z,0.0\n", "6.5,a4-z,1.4\n", "9.0,a4-z,0.0\n", "9.5,a4-z,1.4\n"]
    (tmp_path / "act.csv").write_text(head + "".join(rows))
    (tmp_path / "act_00.csv").write_text(head + "".join(rows[:2]))
    (tmp_path / "act_01.csv").write_text(head + "".join(rows[2:]))
    r = _cli("-q", "ingest", d / "receiver.csv", "--actuators", tmp_path / "act.csv", "--config", TESTBED,
             "-o", tmp_path / "whole.mcap")
    assert r.exit_code == 0, r.output
    r = _cli("ingest", d / "receiver.csv", "--actuators", f"{tmp_path}/act_*.csv", "--config", TESTBED,
             "-o", tmp_path / "p.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert_same_record(tmp_path / "whole.mcap", tmp_path / "p.mcap", {"actuator_csv": 2})
    assert json.loads(r.stdout)["joins"]["actuator_csv"]["gaps"] == [] and "gap of" not in r.output


def test_receiver_csv_of_another_receiver_is_refused(testbed_csv, tmp_path):
    a, b = _split_csv(testbed_csv / "receiver.csv", tmp_path, "rx", [-np.inf, 5.0, np.inf])
    b.write_text(b.read_text().replace(",rx1,", ",rx9,"))
    r = _cli("ingest", f"{tmp_path}/rx_*.csv", "--config", TESTBED, "-o", tmp_path / "p.mcap")
    assert r.exit_code == 2 and f"{b}: antenna a1 is measured by receiver 'rx9', by 'rx1' in {a}" in r.output
    assert not (tmp_path / "p.mcap").exists()


# ------------------------------------------------------------------------------------------------
# the join itself


def test_join_orders_by_first_epoch_not_by_name(tmp_path):
    import pandas as pd

    p1 = ("z_first.csv", pd.DataFrame({"t": [0.0, 1.0, 2.0], "v": [1, 2, 3]}))
    p2 = ("a_second.csv", pd.DataFrame({"t": [2.0, 3.0, 6.0], "v": [9, 4, 5]}))
    tab, rep, order = join_tables([p2, p1], "t", 1.0)
    assert order == [1, 0] and tab["t"].tolist() == [0, 1, 2, 3, 6] and tab["v"].tolist() == [1, 2, 3, 4, 5]
    assert rep.overlaps[0]["identical"] is False and "the rows DIFFER; kept those of z_first.csv" in rep.warnings[0]
    (tmp_path / "x[1].obs").write_text("")
    assert expand_paths([str(tmp_path / "x[1].obs")], "--rinex A") == [str(tmp_path / "x[1].obs")]   # a real name
    with pytest.raises(CdgpsError, match="given twice"):
        expand_paths([str(tmp_path / "x[1].obs"), str(tmp_path / "x[1].obs")], "--rinex A")
