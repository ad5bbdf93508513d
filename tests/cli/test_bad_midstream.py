"""Bad input in the middle of a long record (issue 29): exit 2 naming the file and the time, no output.

* a RUN.mcap with one byte flipped inside a chunk in the middle of its data section: ``init``,
  ``estimate`` and ``info`` exit 2, naming the file and the chunk's time span in the run (from the
  summary, whose own CRC passes), and write nothing;
* a record of two consecutive receiver logs whose last file is truncated mid-line: ``ingest`` of the
  glob exits 2 naming that file, the line and the time, and writes no RUN.mcap.
"""

from __future__ import annotations

import re

import pytest
from mcap.reader import make_reader

from tests._shared import REPO_ROOT, run_cli

CFG = REPO_ROOT / "configs" / "testbed-1998-lumped.toml"


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    d = tmp_path_factory.mktemp("midstream")
    for args in (("simulate", CFG, "--duration", "90", "--seed", "2", "-o", d / "sim"),
                 ("ingest", d / "sim" / "receiver.csv", "--config", CFG, "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "--start", "0", "--duration", "20", "-o", d / "init.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    return d


def test_damaged_chunk_in_the_middle_names_the_file_and_time(record, tmp_path):
    raw = bytearray((record / "run.mcap").read_bytes())
    with open(record / "run.mcap", "rb") as fh:
        chunks = sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 2
    mid = chunks[len(chunks) // 2]
    raw[mid.chunk_start_offset + mid.chunk_length // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    span = f"at {mid.message_start_time / 1e9:g}–{mid.message_end_time / 1e9:g} s of the run"
    for args, out in ((("estimate", bad, "--init", record / "init.json", "--smooth", "-o", tmp_path / "st.mcap"),
                       tmp_path / "st.mcap"),
                      (("init", bad, "-o", tmp_path / "i.json"), tmp_path / "i.json"),
                      (("info", bad), None)):
        r = run_cli("-q", *args)
        assert r.exit_code == 2, r.output
        assert str(bad) in r.output and span in r.output and "Traceback" not in r.output, r.output
        assert out is None or not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]


def test_truncated_last_file_names_the_file_line_and_time(record, tmp_path):
    lines = (record / "sim" / "receiver.csv").read_text().splitlines(keepends=True)
    cut = 1 + 36 * 600                                     # the header and 60 s of 36 channels
    (tmp_path / "rx_00.csv").write_text("".join(lines[:cut]))
    second = "".join(lines[:1] + lines[cut:])
    (tmp_path / "rx_01.csv").write_text(second[:-25])      # the last line cut short
    out = tmp_path / "run.mcap"
    r = run_cli("-q", "ingest", str(tmp_path / "rx_*.csv"), "--config", CFG, "-o", out)
    assert r.exit_code == 2, r.output
    last_t = float(lines[-1].split(",")[0])
    assert "rx_01.csv" in r.output and f"time_s {last_t:g} s" in r.output, r.output
    assert re.search(rf"rx_01\.csv, line {len(lines) - cut + 1}:", r.output), r.output
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["rx_00.csv", "rx_01.csv"]


def test_bad_row_late_in_a_streamed_log_names_file_line_and_time(record, tmp_path, monkeypatch):
    """``ingest`` reads the log a block at a time (small blocks here, as a day's log in 4 MiB ones):
    a bad row near the end, after many blocks were written to the (unnamed) output, exits 2 naming
    the file, its line and the time before it, and leaves no RUN.mcap."""
    from cdgps_cli.io import logs

    block_bytes = 20_000                 # 1.3 MB of log: ~65 blocks before the bad row (2000 B: 650, 6 s more CPU)
    monkeypatch.setattr(logs, "LOG_BLOCK_BYTES", block_bytes)
    lines = (record / "sim" / "receiver.csv").read_text().splitlines(keepends=True)
    k = len(lines) - 40
    assert sum(map(len, lines[:k])) > 50 * block_bytes          # the bad row comes after many blocks
    f = lines[k].split(",")
    prev_t = float(f[0])
    f[5] = "1.5e"
    lines[k] = ",".join(f)
    (tmp_path / "rx.csv").write_text("".join(lines))
    out = tmp_path / "new" / "run.mcap"
    r = run_cli("-q", "ingest", tmp_path / "rx.csv", "--config", CFG, "-o", out)
    assert r.exit_code == 2, r.output
    assert f"rx.csv, line {k + 1}: column phase_cycles: not a number (got '1.5e')" in r.output, r.output
    assert f"the first at time_s {prev_t:g} s" in r.output and "Traceback" not in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rx.csv"]          # (nor the output's folder)
