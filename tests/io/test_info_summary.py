"""Issue 29 item 3: ``cdgps info`` answers from the MCAP summary and the ``cdgps.info`` record without
decoding a message, says exactly what decoding every message says (``--deep``), and keeps every check:
the CRCs, and new index checks that catch what a forger who recomputes the CRCs changes in the summary
or the record."""

from __future__ import annotations

import json
import shutil
import struct
import zlib
from pathlib import Path

import pytest
from click.testing import CliRunner

import cdgps_cli.io.run as run_mod
from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.mcap import INFO_METADATA
from cdgps_cli.io.mcap_integrity import RECORD_SHA256_KEY, read_metadata, record_sha256
from cdgps_cli.pipeline.gnss_ingest import run_info
from cdgps_cli.pipeline.ingest import ingest_structure
from cdgps_cli.sim.structure import SimOptions, parse_outage, parse_slip, simulate, write_simulation

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"
OLD = ROOT / "tests" / "data" / "format-2026-12-02"


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


@pytest.fixture(scope="module")
def files(tmp_path_factory, dof2_path):
    """A testbed RUN with slips and outages (lock restarts, gaps), a 2-DOF RUN with gyros and its STATES."""
    d = tmp_path_factory.mktemp("info")
    cfg = load_config(TESTBED)
    res = simulate(cfg, SimOptions(duration_s=8.0, seed=7, phase_sigma_m=0.01,
                                   slips=[parse_slip("a2:PL3:2.0:-2"), parse_slip("a1:PL1:5.0:+1")],
                                   outages=[parse_outage("PL6:3:1")]))
    write_simulation(res, d / "tb")
    lines = (d / "tb" / "receiver.csv").read_text().splitlines(keepends=True)
    keep = [ln for ln in lines[1:] if not 6.0 < float(ln.split(",")[0]) < 6.5]     # an epoch gap for every channel
    (d / "tb" / "gap.csv").write_text(lines[0] + "".join(keep))
    ingest_structure(cfg, d / "tb" / "gap.csv", d / "TB.mcap")
    for args in (["simulate", dof2_path, "--duration", "6", "-o", d / "sim"],
                 ["ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", dof2_path, "-o", d / "RUN.mcap"],
                 ["init", d / "RUN.mcap", "--duration", "3", "-o", d / "INIT.json"],
                 ["estimate", d / "RUN.mcap", "--init", d / "INIT.json", "-o", d / "STATES.mcap"]):
        r = _run(*args)
        assert r.exit_code == 0, r.output
    return d


def _no_decoding(monkeypatch):
    def refuse(*a, **k):
        raise AssertionError("the messages were decoded")
    monkeypatch.setattr(run_mod, "read_mcap", refuse)


@pytest.mark.parametrize("name", ["TB.mcap", "RUN.mcap", "STATES.mcap"])
def test_summary_answer_is_the_decoded_answer(files, name, monkeypatch):
    deep = run_info(files / name, deep=True)
    _no_decoding(monkeypatch)
    fast = run_info(files / name)
    assert fast == deep
    assert json.dumps(fast) == json.dumps(deep)                    # the same text, key order included
    if name == "TB.mcap":
        assert len(fast["slips"]) >= 2 and fast["gaps"] and len(fast["channels"]) == 36


def test_cli_info_text_and_json(files):
    fast, deep = _run("info", files / "TB.mcap", "--json"), _run("info", files / "TB.mcap", "--json", "--deep")
    assert fast.exit_code == deep.exit_code == 0 and fast.stdout == deep.stdout
    text = _run("info", files / "TB.mcap")
    assert "lock restarts" in text.stdout and INFO_METADATA not in text.stdout


def test_older_files_are_read_message_by_message_with_a_note(tmp_path, capsys):
    shutil.copy(OLD / "run.mcap", tmp_path / "old.mcap")
    assert INFO_METADATA not in read_metadata(tmp_path / "old.mcap")
    info = run_info(tmp_path / "old.mcap")
    assert info["topics"] and "channels" in info
    assert f"{tmp_path / 'old.mcap'}: written by an older cdgps, without a {INFO_METADATA} record" in capsys.readouterr().err


# ---- behind recomputed CRCs (a forger, or another tool) ---------------------------------------------


def _summary_start(data) -> int:
    return struct.unpack("<Q", bytes(data[-28:-20]))[0]


def _recompute_crcs(data: bytearray) -> bytes:
    s = _summary_start(data)
    data[s - 4:s] = struct.pack("<I", zlib.crc32(bytes(data[:s - 13])))
    data[-12:-8] = struct.pack("<I", zlib.crc32(bytes(data[s:-12])))
    return bytes(data)


def _summary_record(data, opcode: int) -> int:
    pos = _summary_start(data)
    while data[pos] != opcode:
        pos += 9 + struct.unpack("<Q", bytes(data[pos + 1:pos + 9]))[0]
    return pos


def _edit_info_record(src: Path, dst: Path, old: bytes, new: bytes) -> None:
    """Change bytes inside the cdgps.info record (same length), its record_sha256 and the CRCs recomputed."""
    data = bytearray(src.read_bytes())
    meta = read_metadata(src)[INFO_METADATA]
    rec = {k: v.replace(old.decode(), new.decode(), 1) for k, v in meta.items()}
    at = data.index(old, data.index(INFO_METADATA.encode()))
    data[at:at + len(old)] = new
    sha_old, sha_new = record_sha256(INFO_METADATA, meta).encode(), record_sha256(INFO_METADATA, rec).encode()
    at = data.index(sha_old)
    data[at:at + len(sha_old)] = sha_new
    dst.write_bytes(_recompute_crcs(data))
    assert read_metadata(dst)[INFO_METADATA] == rec and RECORD_SHA256_KEY not in rec


def test_statistics_that_disagree_with_the_message_indexes(files, tmp_path):
    data = bytearray((files / "RUN.mcap").read_bytes())
    at = _summary_record(data, 0x0B) + 9                             # Statistics: message_count
    n = struct.unpack("<Q", bytes(data[at:at + 8]))[0]
    data[at:at + 8] = struct.pack("<Q", n + 1)
    bad = tmp_path / "stats.mcap"
    bad.write_bytes(_recompute_crcs(data))
    r = _run("info", bad)
    assert r.exit_code == 2 and str(bad) in r.output and "index check failed" in r.output


def test_chunk_index_that_disagrees_with_its_chunk(files, tmp_path):
    data = bytearray((files / "RUN.mcap").read_bytes())
    at = _summary_record(data, 0x08) + 9 + 8                         # Chunk Index: message_end_time
    t = struct.unpack("<Q", bytes(data[at:at + 8]))[0]
    data[at:at + 8] = struct.pack("<Q", t + 1)
    bad = tmp_path / "ci.mcap"
    bad.write_bytes(_recompute_crcs(data))
    with pytest.raises(CdgpsError, match=r"ci\.mcap: MCAP index check failed: .*chunk"):
        run_info(bad)


def test_info_record_that_disagrees_with_the_message_indexes(files, tmp_path):
    meta = read_metadata(files / "RUN.mcap")[INFO_METADATA]
    count = json.loads(meta["topics"])["/cdgps/phase"]["messages"]
    bad = tmp_path / "rec.mcap"
    _edit_info_record(files / "RUN.mcap", bad, f'"messages": {count}'.encode(), f'"messages": {count + 1}'.encode()
                      if len(str(count + 1)) == len(str(count)) else f'"messages": {count - 1}'.encode())
    with pytest.raises(CdgpsError, match=r"rec\.mcap: the cdgps\.info record disagrees with the message indexes"):
        run_info(bad)


def test_deep_compares_the_record_with_the_messages(files, tmp_path):
    """A changed lock-restart time in the record: no index shows it; --deep refuses it."""
    meta = read_metadata(files / "TB.mcap")[INFO_METADATA]
    t = json.loads(meta["structure"])["channels"]
    first = next(c for c in t if c["lock_restarts_s"])["lock_restarts_s"][0]
    old = f'"lock_restarts_s": [{first!r}'.encode()
    assert old in (files / "TB.mcap").read_bytes()
    new = old[:-1] + (b"7" if old[-1:] != b"7" else b"3")
    bad = tmp_path / "slip.mcap"
    _edit_info_record(files / "TB.mcap", bad, old, new)
    r = _run("info", bad, "--deep")
    assert r.exit_code == 2 and "record disagrees with the decoded messages" in r.output and str(bad) in r.output


def test_chunk_crcs_are_checked_when_there_is_no_data_section_crc(files, tmp_path):
    """A file without a data-section CRC (another tool's): its chunks are decompressed and CRC-checked."""
    from tests.io.test_mcap_integrity import _foreign_copy

    good, bad = tmp_path / "f.mcap", tmp_path / "fbad.mcap"
    _foreign_copy(files / "RUN.mcap", good)
    assert run_info(good)["topics"] == run_info(files / "RUN.mcap")["topics"]
    data = bytearray(good.read_bytes())
    at = _summary_record(data, 0x08) + 9 + 8 + 8                     # Chunk Index: chunk_start_offset
    start = struct.unpack("<Q", bytes(data[at:at + 8]))[0]
    data[start + 200] ^= 0x40                                        # inside the compressed records
    s = _summary_start(data)
    data[-12:-8] = struct.pack("<I", zlib.crc32(bytes(data[s:-12])))
    bad.write_bytes(bytes(data))
    with pytest.raises(CdgpsError, match=r"fbad\.mcap: MCAP index check failed: chunk at byte \d+ "
                                         r"(does not decompress|fails its CRC check)"):
        run_info(bad)
