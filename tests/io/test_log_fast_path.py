"""The typed reading of the CSV logs (issue 29 item 4) gives what the text reading gives.

:func:`cdgps_cli.io.logs._fast_table` reads numbers as floats and names as categoricals with pandas' C
reader, and hands over to the text reading whenever there is something to report.  For a valid log
and for each odd value below (in a number column, a name column, the header), both readings end the
same way: the same table (values bit for bit, names as text) or the same CdgpsError message.  Plus:
the typed reading is what runs on a valid log (not a silent fallback).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import logs

from tests._shared import REPO_ROOT

CFG = load_config(REPO_ROOT / "configs" / "testbed-1998.toml")
HEAD = "time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz\n"


def _log(rows=40):
    lines = [HEAD]
    for k in range(rows):
        for a in ("a2", "a3"):
            for x in ("PL1", "PL2"):
                lines.append(f"{k * 0.1:.1f},rx1,master,{a},{x},{1000.123456789 + k * 0.37:.9f},{k},{45 - k % 3 if k % 5 else ''}\n")
    return lines


def _outcome(path, reader):
    try:
        df = reader(path, CFG)
    except CdgpsError as exc:
        return "error", str(exc)
    return "table", {c: (df[c].astype(str).to_numpy().tolist() if df[c].dtype == object or isinstance(
        df[c].dtype, (pd.CategoricalDtype, pd.StringDtype)) else df[c].to_numpy().tobytes()) for c in df.columns}


def _both(path, reader, monkeypatch):
    fast = _outcome(path, reader)
    with monkeypatch.context() as m:
        m.setattr(logs, "FAST_PARSE", False)
        slow = _outcome(path, reader)
    return fast, slow


ODD = ["", " ", "nan", "NaN", "-nan", "inf", "-inf", "1e400", "1e5", "+1", ".5", "1.", "-0", "0x10", "1_000",
       "1,5", "abc", " 2 ", "2 ", "1e-320", "١", "9" * 30, "\"3\"", "'4'", "1.5e", "--1"]


@pytest.mark.parametrize("column", [0, 3, 4, 5, 6, 7])
@pytest.mark.parametrize("value", ODD)
def test_same_outcome_as_the_text_reading(tmp_path, monkeypatch, column, value):
    lines = _log()
    f = lines[7].rstrip("\n").split(",")
    f[column] = value
    lines[7] = ",".join(f) + "\n"
    p = tmp_path / "receiver.csv"
    p.write_text("".join(lines))
    fast, slow = _both(p, logs.read_receiver_log, monkeypatch)
    assert fast == slow


def test_the_unchanged_log_is_a_table(tmp_path, monkeypatch):
    p = tmp_path / "receiver.csv"
    p.write_text("".join(_log()))
    fast, slow = _both(p, logs.read_receiver_log, monkeypatch)
    assert fast == slow and fast[0] == "table"


@pytest.mark.parametrize("change", ["padded-name", "duplicate", "backwards", "unknown-antenna", "other-master",
                                   "crlf", "blank-line", "header-space", "negative-zero-duplicate", "quoted"])
def test_same_outcome_for_row_problems(tmp_path, monkeypatch, change):
    lines = _log()
    if change == "padded-name":
        lines[5] = lines[5].replace(",a2,", ", a2,")
    elif change == "duplicate":
        lines.insert(6, lines[5])
    elif change == "backwards":
        lines[9], lines[20] = lines[20], lines[9]
    elif change == "unknown-antenna":
        lines[9] = lines[9].replace(",a2,", ",a9,")
    elif change == "other-master":
        lines[9] = lines[9].replace(",master,", ",a2,")
    elif change == "crlf":
        lines = [ln.replace("\n", "\r\n") for ln in lines]
    elif change == "blank-line":
        lines.insert(8, "\n")
    elif change == "header-space":
        lines[0] = lines[0].replace("lock", " lock")
    elif change == "negative-zero-duplicate":
        lines.insert(2, lines[1].replace("0.0,", "-0.0,", 1))
    elif change == "quoted":
        lines[9] = lines[9].replace(",a2,", ',"a2",')
    p = tmp_path / "receiver.csv"
    p.write_text("".join(lines))
    fast, slow = _both(p, logs.read_receiver_log, monkeypatch)
    assert fast == slow


def test_valid_logs_take_the_typed_reading(tmp_path, monkeypatch):
    p = tmp_path / "receiver.csv"
    p.write_text("".join(_log()))
    seen = []
    real = logs._fast_table
    monkeypatch.setattr(logs, "_fast_table", lambda *a: seen.append(real(*a)) or seen[-1])
    df = logs.read_receiver_log(p, CFG)
    assert seen and seen[0] is not None and isinstance(df["antenna"].dtype, pd.CategoricalDtype)
    assert df["lock"].dtype == np.int64 and np.isnan(df["snr_dbhz"].to_numpy()).sum() == 32
    g = tmp_path / "gyro.csv"
    g.write_text("time_s,gyro,rate_rad_s\n0.0,g1,0.5\n0.1,g1,0.25\n")
    fast, slow = _both(g, logs.read_gyro_log, monkeypatch)
    assert fast == slow and fast[0] == ("table" if "g1" in CFG.gyro_names else "error")


def _streamed(path, kind, block_bytes):
    """The outcome of reading ``path`` a block of ``block_bytes`` at a time (the blocks joined)."""
    try:
        blocks = list(logs.valid_blocks(path, kind, CFG, block_bytes=block_bytes))
    except CdgpsError as exc:
        return "error", str(exc)
    df = pd.concat(blocks, ignore_index=True) if len(blocks) > 1 else blocks[0]
    return "table", {c: (df[c].astype(str).to_numpy().tolist() if df[c].dtype == object or isinstance(
        df[c].dtype, (pd.CategoricalDtype, pd.StringDtype)) else df[c].to_numpy().tobytes()) for c in df.columns}


@pytest.mark.parametrize("block", [1, 5, 7, 100, 1 << 20])
def test_duplicates_found_in_blocks_as_in_one_table(tmp_path, block):
    """The duplicate-row check of a log read in blocks (tiny blocks here: one line, a few lines, cut
    anywhere in an epoch) finds the rows the one-table check finds, the same message; a repeated
    row across a block edge too."""
    lines = _log(12)
    lines.insert(9, lines[7])                         # same time, later in the same epoch
    lines.insert(30, lines[29])                       # a row right after itself
    p = tmp_path / "receiver.csv"
    p.write_text("".join(lines))
    whole = _outcome(p, logs.read_receiver_log)
    assert whole[0] == "error" and whole[1].count("duplicate row") == 2
    assert _streamed(p, "receiver", block) == whole


@pytest.mark.parametrize("block", [1, 37, 400, 1 << 20])
@pytest.mark.parametrize("change", ["valid", "many-kinds", "late-problem", "bad-line", "backwards-at-edge", "blank-line",
                                   "padded-number"])
def test_blocks_give_the_whole_files_outcome(tmp_path, block, change):
    """A log read in blocks of any size ends as the whole file read at once: the same table (values
    bit for bit) or the same message — every kind of problem in the checks' order, the first lines
    of each with their line numbers in the file, the counts, the time of the first problem."""
    lines = _log(30)
    if change == "many-kinds":
        lines[100] = lines[100].replace(",a2,", ",a9,")
        for k in (3, 50, 90, 91, 92, 93, 94, 95, 110):
            f = lines[k].split(",")
            f[5] = "abc"
            lines[k] = ",".join(f)
        lines[70] = lines[70].replace(",master,", ",a2,")
        lines.insert(60, lines[59])
    elif change == "late-problem":
        f = lines[-3].split(",")
        f[0] = "-1"
        lines[-3] = ",".join(f)
    elif change == "bad-line":
        lines[80] = lines[80].rstrip("\n") + ",extra\n"
    elif change == "backwards-at-edge":
        lines[41], lines[45] = lines[45], lines[41]
    elif change == "blank-line":
        lines.insert(50, "\n")
        lines[90] = lines[90].replace(",a2,", ",a9,")
    elif change == "padded-number":
        lines[20] = lines[20].replace(",rx1,", ",rx1 ,")
    p = tmp_path / "receiver.csv"
    p.write_text("".join(lines))
    whole = _outcome(p, logs.read_receiver_log)
    assert (whole[0] == "table") == (change in ("valid", "padded-number")), whole      # (names are stripped)
    assert _streamed(p, "receiver", block) == whole
