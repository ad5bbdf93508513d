"""A RINEX 3 observation file whose last epoch the end of the file cuts (a logger stopped while writing it) is read
up to that epoch, as RTKLIB reads it, and the readers' header says what was left out (io/rinex.without_cut_last_epoch);
``rtk`` and ``ingest`` warn.  Every reader refused the whole file before (exit 2)."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.io.rinex import read_rinex_obs, without_cut_last_epoch
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
DATA = REPO_ROOT / "tests" / "data"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _cut(tmp_path, lines_after_epoch: int | None, name: str = "cut.obs"):
    """The real rover with its file ending ``lines_after_epoch`` record lines into its last epoch (None: in the
    middle of the epoch line itself)."""
    data = (MOSAIC / "rover.obs").read_bytes()
    last = data.rfind(b"\n>") + 1
    stop = data.find(b"\n", last) + 1
    for _ in range(lines_after_epoch or 0):
        stop = data.find(b"\n", stop) + 1
    cut = data[:stop + 20] if lines_after_epoch is not None else data[:last + 20]      # a record line cut too
    p = tmp_path / name
    p.write_bytes(cut)
    return p, data[:last]


@pytest.mark.parametrize("lines_after", [0, 29, None])
def test_the_cut_epoch_is_left_out_and_said(tmp_path, lines_after):
    p, whole_before = _cut(tmp_path, lines_after)
    data, what = without_cut_last_epoch(p.read_bytes())
    assert data == whole_before and what.startswith("line 17388: the last epoch")
    hdr, obs = read_rinex_obs(p)
    ref_hdr, ref = read_rinex_obs(MOSAIC / "rover.obs")
    assert hdr["last_epoch_cut"] == what and "last_epoch_cut" not in ref_hdr
    t_last = ref["time_gps_s"].max()
    np.testing.assert_array_equal(obs["time_gps_s"].to_numpy(), ref.loc[ref["time_gps_s"] < t_last, "time_gps_s"])
    sig_hdr, sig = read_rinex_signals(p, ["G:L1", "E:E1"])
    assert sig_hdr["last_epoch_cut"] == what and sig["time_gps_s"].max() < t_last


def test_whole_files_and_rinex_2_are_left_as_they_are():
    for p in (MOSAIC / "rover.obs", DATA / "07590920.05o", DATA / "demo3.10o"):
        data = p.read_bytes()
        assert without_cut_last_epoch(data) == (data, None), p


def test_rtk_reads_a_cut_rover_and_says_so(tmp_path):
    p, _ = _cut(tmp_path, 29)
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", p, "--nav", MOSAIC / "base.nav",
                "--signals", "G:L1", "-o", tmp_path / "x.csv", "--json")
    assert r.exit_code == 0, r.output
    assert "announces 57 records but the file ends after 30 (the file is cut)" in r.stderr


def test_a_last_line_cut_in_a_value_is_a_cut_epoch(tmp_path):
    """A logger stopped in the middle of a number: the last record line ends inside a value, with no line end; the
    number would be read as a shorter one (a static rover 1000 km off, silently); the epoch is left out."""
    data = (MOSAIC / "rover.obs").read_bytes().rstrip(b"\n")
    last_line = data.rfind(b"\n") + 1
    p = tmp_path / "tail.obs"
    p.write_bytes(data[:last_line + 3 + 16 + 7])               # 7 characters into the second value
    hdr, _ = read_rinex_obs(p)
    assert hdr["last_epoch_cut"].endswith("'s last record line is cut in the middle of a value")
    whole = tmp_path / "whole_no_newline.obs"
    whole.write_bytes(data)                                    # a whole file without its final line end: as it is
    assert "last_epoch_cut" not in read_rinex_obs(whole)[0]


def test_each_read_says_its_own_cut_and_the_fallback_reader_too(tmp_path):
    """The cut is recorded per read of a path (a whole file read again there is not said to be cut), and the
    line-by-line reader a fast one falls back to says it as well (a blank line after the header sends it there)."""
    p, _ = _cut(tmp_path, 29)
    cut_bytes = p.read_bytes()
    assert "last_epoch_cut" in read_rinex_obs(p)[0]
    p.write_bytes((MOSAIC / "rover.obs").read_bytes())
    assert "last_epoch_cut" not in read_rinex_obs(p)[0]
    end = cut_bytes.find(b"END OF HEADER")
    end = cut_bytes.find(b"\n", end) + 1
    p.write_bytes(cut_bytes[:end] + b"\n" + cut_bytes[end:])
    assert "last_epoch_cut" in read_rinex_signals(p, ["G:L1"])[0]
