"""Issue 12 item 2: every byte of a cdgps MCAP that a computation uses is checked before it is used.

A flipped byte in each region (data section, summary, a metadata value, a channel topic) is a clean
error naming the file; behind recomputed CRCs (a forger, or a tool that writes none) the metadata
records' own ``record_sha256`` and the readers' expected-record checks still refuse it.  Clean files
round-trip; zero CRC fields follow the documented policy (docs/hardening.md, "MCAP integrity").
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap.writer import Writer

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.mcap_integrity import RECORD_SHA256_KEY, read_metadata, record_sha256
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.states import States
from cdgps_cli.pipeline.estimate_outputs import evaluate


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


def assert_clean_error(r, *words):
    assert r.exit_code == 2, f"exit {r.exit_code}: {r.output}\n{r.exception!r}"
    assert isinstance(r.exception, SystemExit) and "Traceback" not in r.output
    for w in words:
        assert str(w) in r.output, f"{w!r} not in {r.output!r}"


@pytest.fixture(scope="module")
def files(tmp_path_factory, dof2_path):
    """A 6 s 2-DOF simulation with RUN.mcap, INIT.json, STATES.mcap, and a 30 s GNSS RUN.mcap."""
    d = tmp_path_factory.mktemp("integrity")
    for args in (["simulate", dof2_path, "--duration", "6", "-o", d / "sim"],
                 ["ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", dof2_path, "-o", d / "RUN.mcap"],
                 ["init", d / "RUN.mcap", "--duration", "3", "-o", d / "INIT.json"],
                 ["estimate", d / "RUN.mcap", "--init", d / "INIT.json", "-o", d / "STATES.mcap"],
                 ["simulate-gnss", "--duration", "30", "--seed", "2", "--out", d / "gsim"],
                 ["ingest", "--config", d / "gsim" / "config.toml", "-o", d / "GRUN.mcap"]):
        r = _run(*args)
        assert r.exit_code == 0, r.output
    return d


def _summary_start(data) -> int:
    return struct.unpack("<Q", bytes(data[-8 - 4 - 8 - 8:-8 - 4 - 8]))[0]


def _recompute_crcs(data: bytearray) -> bytearray:
    """Data-section and summary CRCs recomputed over the (damaged) bytes."""
    s = _summary_start(data)
    data[s - 4:s] = struct.pack("<I", zlib.crc32(bytes(data[:s - 13])))
    data[-12:-8] = struct.pack("<I", zlib.crc32(bytes(data[s:-12])))
    return data


def _mutated(src: Path, dst: Path, offset: int, new: int | None = None, fix_crcs: bool = False) -> Path:
    data = bytearray(src.read_bytes())
    data[offset] = (data[offset] ^ 0x01) if new is None else new
    dst.write_bytes(bytes(_recompute_crcs(data) if fix_crcs else data))
    return dst


def test_clean_files_round_trip(files):
    """Every record carries a record_sha256 that matches its content; readers return the content without it."""
    for name in ("RUN.mcap", "STATES.mcap", "GRUN.mcap"):
        with open(files / name, "rb") as fh:
            raw = {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}
        meta = read_metadata(files / name)
        assert set(raw) == set(meta) and meta
        for rec, data in raw.items():
            assert data.pop(RECORD_SHA256_KEY) == record_sha256(rec, data)
            assert meta[rec] == data
        assert read_mcap(files / name).metadata == meta
    r = _run("evaluate", "--truth", files / "sim", "--estimate", files / "STATES.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert "nis" in json.loads(r.output)


def test_flipped_byte_in_data_section(files, tmp_path):
    with open(files / "RUN.mcap", "rb") as fh:
        chunk = make_reader(fh).get_summary().chunk_indexes[0]
    bad = _mutated(files / "RUN.mcap", tmp_path / "run.mcap", chunk.chunk_start_offset + 60)
    with pytest.raises(CdgpsError, match=r"run\.mcap: the MCAP data section fails its CRC check"):
        read_mcap(bad)
    for cmd in (["info", bad], ["init", bad, "-o", tmp_path / "i.json"]):
        assert_clean_error(_run(*cmd), bad, "data section fails its CRC check")
    assert not (tmp_path / "i.json").exists()


def test_flipped_byte_in_summary(files, tmp_path):
    data = (files / "STATES.mcap").read_bytes()
    bad = _mutated(files / "STATES.mcap", tmp_path / "st.mcap", _summary_start(data) + 30)
    assert_clean_error(_run("evaluate", "--truth", files / "sim", "--estimate", bad), bad,
                       "summary section fails its CRC check")


def test_flipped_final_biases_digit(files, tmp_path):
    """The campaign's case (66.67 mm and one wrong integer, exit 0): now refused, also behind fixed CRCs."""
    data = (files / "STATES.mcap").read_bytes()
    at = data.index(b'"bias_m": ', data.index(b"final_biases")) + len(b'"bias_m": ') + 3   # a digit of a final bias
    assert chr(data[at]).isdigit()
    new = ord("7") if data[at] != ord("7") else ord("3")
    bad = _mutated(files / "STATES.mcap", tmp_path / "st.mcap", at, new)
    assert_clean_error(_run("evaluate", "--truth", files / "sim", "--estimate", bad), bad, "CRC check")
    _mutated(files / "STATES.mcap", bad, at, new, fix_crcs=True)
    with pytest.raises(CdgpsError, match=r"'cdgps.estimate' fails its record_sha256 check"):
        evaluate(files / "sim", bad)
    assert_clean_error(_run("evaluate", "--truth", files / "sim", "--estimate", bad), bad, "record_sha256")


def test_flipped_channel_topic(files, tmp_path):
    """A flipped residual topic made evaluate's NIS section vanish (exit 0): now an error naming the channel."""
    data = (files / "STATES.mcap").read_bytes()
    at = data.index(b"/cdgps/residuals", _summary_start(data)) + 8          # the summary's channel record
    bad = _mutated(files / "STATES.mcap", tmp_path / "st.mcap", at, ord("X"))
    assert_clean_error(_run("evaluate", "--truth", files / "sim", "--estimate", bad), bad, "summary section fails")
    _mutated(files / "STATES.mcap", bad, at, ord("X"), fix_crcs=True)
    with pytest.raises(CdgpsError, match=r"st\.mcap: no /cdgps/residuals channel"):
        States(bad)


def test_flipped_gnss_kind(files, tmp_path):
    data = (files / "GRUN.mcap").read_bytes()
    at = data.rindex(b"gnss", 0, _summary_start(data))                  # "kind": "gnss" in cdgps.ingest
    bad = _mutated(files / "GRUN.mcap", tmp_path / "g.mcap", at, ord("G"))
    assert_clean_error(_run("info", bad), bad, "data section fails its CRC check")
    _mutated(files / "GRUN.mcap", bad, at, ord("G"), fix_crcs=True)
    assert_clean_error(_run("info", bad), bad, "record_sha256")
    assert_clean_error(_run("init", bad, "-o", tmp_path / "i.json"), bad, "record_sha256")


def test_zero_crc_in_a_cdgps_file_is_refused(files, tmp_path):
    data = bytearray((files / "RUN.mcap").read_bytes())
    s = _summary_start(data)
    zero_data = bytearray(data)
    zero_data[s - 4:s] = bytes(4)
    (tmp_path / "a.mcap").write_bytes(bytes(zero_data))
    with pytest.raises(CdgpsError, match=r"a\.mcap: the data-section CRC is 0 in a file written by 'cdgps'"):
        read_mcap(tmp_path / "a.mcap")
    zero_summary = bytearray(data)
    zero_summary[-12:-8] = bytes(4)
    (tmp_path / "b.mcap").write_bytes(bytes(zero_summary))
    assert_clean_error(_run("info", tmp_path / "b.mcap"), tmp_path / "b.mcap", "summary has no CRC")


def _foreign_copy(src: Path, dst: Path, drop_sha: bool = False, enable_crcs: bool = True) -> None:
    """``src`` rewritten by the plain mcap writer (library 'other', default: no data-section CRC)."""
    with open(src, "rb") as fh, open(dst, "wb") as out:
        r = make_reader(fh)
        w = Writer(out, enable_crcs=enable_crcs)
        w.start(profile="cdgps", library="other")
        ids = {}
        for schema, channel, msg in r.iter_messages():
            if channel.id not in ids:
                sid = w.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sid, channel.metadata)
            w.add_message(ids[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        for a in r.iter_attachments():
            w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for m in r.iter_metadata():
            w.add_metadata(m.name, {k: v for k, v in m.metadata.items() if not (drop_sha and k == RECORD_SHA256_KEY)})
        w.finish()


def test_foreign_file_without_data_crc(files, tmp_path, capsys):
    """Accepted with one warning when its metadata carries record_sha256; refused without it."""
    _foreign_copy(files / "RUN.mcap", tmp_path / "f.mcap")
    assert read_mcap(tmp_path / "f.mcap").metadata == read_metadata(files / "RUN.mcap")
    assert "f.mcap: written by 'other' without a data-section CRC" in capsys.readouterr().err
    _foreign_copy(files / "RUN.mcap", tmp_path / "g.mcap", drop_sha=True)
    with pytest.raises(CdgpsError, match=r"g\.mcap: metadata record 'cdgps.ingest' carries no record_sha256"):
        read_mcap(tmp_path / "g.mcap")
    _foreign_copy(files / "RUN.mcap", tmp_path / "h.mcap", enable_crcs=False)
    with pytest.raises(CdgpsError, match=r"h\.mcap: the MCAP summary has no CRC"):
        read_mcap(tmp_path / "h.mcap")


def test_attachments_of_a_file_without_a_data_section_crc_are_checked_one_by_one(tmp_path):
    """A file from a writer that leaves the data-section CRC at 0: each attachment is checked against
    its own CRC (with the data-section CRC present, the section check covers their bytes)."""
    p = tmp_path / "foreign.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, enable_data_crcs=False)
        w.start(profile="", library="another writer")
        w.add_attachment(create_time=0, log_time=0, name="a.bin", media_type="application/octet-stream",
                         data=b"0123456789" * 50)
        w.finish()
    assert read_mcap(p).attachments["a.bin"] == b"0123456789" * 50
    raw = bytearray(p.read_bytes())
    at = raw.find(b"0123456789")
    raw[at + 5] ^= 0x01
    bad = tmp_path / "foreign_bad.mcap"
    bad.write_bytes(bytes(raw))
    with pytest.raises(CdgpsError, match=r"attachment 'a\.bin' fails its CRC check"):
        read_mcap(bad)


def test_crc32_combine_and_parallel_parts_equal_one_pass(tmp_path, monkeypatch):
    """The data-section CRC in parallel parts joined by crc32_combine is zlib's one-pass CRC-32."""
    import random
    import zlib as _zlib

    from cdgps_cli.io import mcap_integrity as mi

    rng = random.Random(7)
    for _ in range(200):
        a, b = os.urandom(rng.randrange(0, 2000)), os.urandom(rng.randrange(0, 2000))
        assert mi.crc32_combine(_zlib.crc32(a), _zlib.crc32(b), len(b)) == _zlib.crc32(a + b)
    data = os.urandom(300_001)
    p = tmp_path / "blob"
    p.write_bytes(data)
    monkeypatch.setattr(mi, "CRC_PARALLEL_MIN_BYTES", 1000)
    monkeypatch.setattr(mi.os, "cpu_count", lambda: 3)
    with open(p, "rb") as fh:
        for start, end in ((0, len(data)), (17, 299_000), (5, 900)):
            assert mi._crc_range(fh, start, end, bytearray(4096)) == _zlib.crc32(data[start:end])
        with pytest.raises(EOFError):                 # a range past the end of the file
            mi._crc_range(fh, 0, len(data) + 10, bytearray(4096))
