"""Corrupt receiver data is reported (issue 12 item 3): a real u-blox log (../shared/data/ubx) with
a flipped bit inside an RXM-RAWX frame, a truncated tail, a checksum-valid but undecodable frame
or a destroyed sync word.  Each loss is counted by the reader, warned about at ingest (naming the
file), kept in the RUN (the CRC-checked receivers.json and the ingest metadata), shown by
``cdgps info``, and refused by ``ingest --strict`` (exit 2, file and count named, no output).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.ubx import read_ubx_rawx

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ubx" / "pygpsdata-RXMRAWX.log"


@pytest.fixture(scope="module")
def clean() -> bytes:
    if not SHARED.exists():
        pytest.skip(f"shared test data not available: {SHARED}")
    return SHARED.read_bytes()


def _offsets(data: bytes) -> list[tuple[int, int]]:
    """(offset, payload length) of every frame of a clean log, framed independently."""
    out, k = [], 0
    while k < len(data):
        assert data[k : k + 2] == b"\xb5\x62"
        n = struct.unpack_from("<H", data, k + 4)[0]
        out.append((k, n))
        k += 8 + n
    return out


def _fletcher(body: bytes) -> bytes:
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def _flip(data: bytes) -> tuple[bytes, dict]:
    """One bit flipped inside the payload of the 6th RXM-RAWX (a carrier phase)."""
    k, _ = _offsets(data)[5]
    b = bytearray(data)
    b[k + 6 + 16 + 8] ^= 0x04
    return bytes(b), {"bad_checksum_frames": 1, "n_frames": 13, "epochs": 13, "offset": k}


def _truncate(data: bytes) -> tuple[bytes, dict]:
    k, _ = _offsets(data)[6]
    return data[: k + 50], {"truncated_tail_bytes": 50, "n_frames": 6, "epochs": 6}


def _undecodable(data: bytes) -> tuple[bytes, dict]:
    """numMeas of the 4th RXM-RAWX raised by 3 (more measurements than the frame holds), with a
    recomputed, valid checksum."""
    k, n = _offsets(data)[3]
    b = bytearray(data)
    b[k + 6 + 11] += 3
    b[k + 6 + n : k + 8 + n] = _fletcher(bytes(b[k + 2 : k + 6 + n]))
    return bytes(b), {"undecodable_frames": 1, "n_frames": 14, "epochs": 13, "offset": k}


def _forged_255(data: bytes) -> tuple[bytes, dict]:
    """The 4th RXM-RAWX rebuilt with numMeas = 255: its measurement blocks repeated to fill 255, the
    length and checksum recomputed (a frame no receiver writes: one signal listed many times)."""
    k, n = _offsets(data)[3]
    pl = bytearray(data[k + 6 : k + 6 + n])
    blocks = [bytes(pl[16 + 32 * i : 48 + 32 * i]) for i in range(pl[11])]
    pl[11] = 255
    payload = bytes(pl[:16]) + b"".join(blocks[i % len(blocks)] for i in range(255))
    body = data[k + 2 : k + 4] + struct.pack("<H", len(payload)) + payload
    frame = data[k : k + 2] + body + _fletcher(body)
    return data[:k] + frame + data[k + 8 + n :], {"undecodable_frames": 1, "n_frames": 14, "epochs": 13, "offset": k}


def _no_sync(data: bytes) -> tuple[bytes, dict]:
    """The sync word of the 3rd frame destroyed: the whole frame is bytes between frames."""
    k, n = _offsets(data)[2]
    b = bytearray(data)
    b[k] = 0x00
    return bytes(b), {"skipped_bytes": n + 8, "n_frames": 13, "epochs": 13}


CASES = {"flipped_bit": _flip, "truncated_tail": _truncate, "undecodable": _undecodable, "no_sync": _no_sync,
         "forged_255": _forged_255}
COUNTERS = ("bad_checksum_frames", "undecodable_frames", "skipped_bytes", "truncated_tail_bytes")


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.mark.parametrize("case", sorted(CASES))
def test_reader_counts_each_loss(clean, tmp_path, case):
    data, exp = CASES[case](clean)
    p = tmp_path / f"{case}.ubx"
    p.write_bytes(data)
    info, obs = read_ubx_rawx(p)
    assert info["n_frames"] == exp["n_frames"] and info["n_epochs"] == exp["epochs"]
    assert obs["time_gps_s"].nunique() == exp["epochs"]
    for c in COUNTERS:
        if c == "skipped_bytes" and case == "flipped_bit":
            # the corrupt frame's own bytes are skipped: up to the next valid frame
            assert info[c] == _offsets(clean)[6][0] - exp["offset"]
        else:
            assert info[c] == exp.get(c, 0), c
    if "offset" in exp:
        key = "bad_frame_offsets" if case == "flipped_bit" else "undecodable_frame_offsets"
        assert info[key] == [exp["offset"]]


@pytest.mark.parametrize("case", sorted(CASES))
def test_ingest_warns_keeps_counts_and_strict_refuses(clean, tmp_path, case):
    data, exp = CASES[case](clean)
    p = tmp_path / f"{case}.ubx"
    p.write_bytes(data)
    out = tmp_path / "run.mcap"
    r = _cli("-q", "ingest", "--ubx", f"A={p}", "-o", out)
    assert r.exit_code == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if "corrupt UBX data" in ln]
    assert len(warn) == 1 and p.name in warn[0] and "corrupt UBX data" in warn[0]       # even with -q
    # the counts in the RUN: the CRC-checked receivers.json and the ingest metadata record
    rx = read_gnss_run(out).receivers["A"]
    meta = read_mcap(out, topics=[]).metadata["cdgps.ingest"]["ubx:A_integrity"]
    fields = dict(kv.split("=") for kv in meta.split())
    for c in COUNTERS:
        assert int(rx.info[c]) == int(fields[c])
        assert (int(fields[c]) > 0) == (c in exp or (c == "skipped_bytes" and case == "flipped_bit")), c
    assert int(fields["n_frames"]) == exp["n_frames"]
    # cdgps info: one integrity line
    r = _cli("info", out)
    assert r.exit_code == 0
    lines = [ln for ln in r.stdout.splitlines() if "integrity:" in ln]
    assert len(lines) == 1 and f"{exp['n_frames']} frames read" in lines[0]
    js = json.loads(_cli("info", out, "--json").stdout)
    g = js["gnss"]["receivers"][0]["integrity"]
    assert g["problems"] and all(g[c] == int(fields[c]) for c in COUNTERS)
    # --strict: exit 2, the file and the count named, no output, no traceback
    out2 = tmp_path / "strict.mcap"
    r = _cli("ingest", "--strict", "--ubx", f"A={p}", "-o", out2)
    assert r.exit_code == 2 and not out2.exists()
    assert p.name in r.stderr and "corrupt UBX data" in r.stderr and "Traceback" not in r.stderr
    key = next(c for c in COUNTERS if c in exp)
    assert f"{exp[key]} " in r.stderr


def test_clean_log_and_nmea_between_frames_are_not_losses(clean, tmp_path):
    """NMEA sentences with correct checksums between frames are a receiver's normal output: counted
    apart (``nmea_bytes``), no warning, accepted by --strict; a corrupt sentence is skipped data."""
    gga = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
    offs = _offsets(clean)
    mixed = b"".join(gga + clean[k : k + 8 + n] for k, n in offs)
    p = tmp_path / "mixed.ubx"
    p.write_bytes(mixed)
    info, _ = read_ubx_rawx(p, strict=True)
    assert info["nmea_bytes"] == len(gga) * len(offs) and info["skipped_bytes"] == 0
    for f in (SHARED, p):
        r = _cli("ingest", "--strict", "--ubx", f"A={f}", "-o", tmp_path / "run.mcap")
        assert r.exit_code == 0 and "corrupt UBX data" not in r.stderr, r.stderr
        r = _cli("info", tmp_path / "run.mcap")
        assert "14 frames read, 0 failing the checksum, 0 RXM-RAWX" in r.stdout
    bad = mixed.replace(b"*47", b"*48", 1)
    p.write_bytes(bad)
    info, _ = read_ubx_rawx(p)
    assert info["skipped_bytes"] == len(gga) and info["nmea_bytes"] == len(gga) * (len(offs) - 1)


def test_strict_is_for_gnss_files(tmp_path):
    r = _cli("ingest", "r.csv", "--config", "c.toml", "--strict", "-o", tmp_path / "o.mcap")
    assert r.exit_code == 2 and "--strict applies to GNSS receiver files" in r.stderr



def test_config_warns_of_a_damaged_log_as_ingest_does(tmp_path):
    # 'cdgps config' wrote a starter config from a damaged log without a word while 'ingest' warned
    walk = SHARED.parents[1] / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
    if not walk.is_file():
        pytest.skip(f"shared test data not available: {walk}")
    data = bytearray(walk.read_bytes())
    for k in range(1000, len(data), len(data) // 5):          # a byte of five frames: checksums fail
        data[k] ^= 0xFF
    p = tmp_path / "damaged.ubx"
    p.write_bytes(bytes(data))
    r = _cli("-q", "ingest", "--ubx", f"A={p}", "-o", tmp_path / "run.mcap")
    said = [ln for ln in r.stderr.splitlines() if "corrupt UBX data" in ln]
    r = _cli("-q", "config", "--ubx", f"A={p}", "-o", tmp_path / "run.toml", "--json")
    assert r.exit_code == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if "corrupt UBX data" in ln]
    assert len(said) == 1 and warn == said                                    # the same words, even with -q
    assert json.loads(r.stdout)["warnings"] == [said[0].removeprefix("cdgps: warning: ")]
    r = _cli("-q", "config", "--ubx", f"A={walk}", "-o", tmp_path / "clean.toml", "--json")
    assert r.exit_code == 0 and "corrupt" not in r.stderr and json.loads(r.stdout)["warnings"] == []
