"""A RINEX 3 observation file cut by its end (a logger stopped while writing it) is refused naming the file, the
line and the epoch (issue 29: "a truncated last file gets exit 2 naming the file and the time, and no partial
output"): a record count the end cuts, as before, and now also a last record line cut inside a value, which was
read as a shorter number (the real rover cut 42 bytes into its last line: a static rover about 1000 km off, 0 %
fixed, silently; io/rinex._refuse_a_value_cut_by_the_end)."""

from __future__ import annotations

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _tail_cut(tmp_path, into_line: int):
    """The real rover ending ``into_line`` characters into its last record line, without a line end."""
    data = (MOSAIC / "rover.obs").read_bytes().rstrip(b"\n")
    p = tmp_path / f"tail{into_line}.obs"
    p.write_bytes(data[:data.rfind(b"\n") + 1 + into_line])
    return p


def test_a_last_line_cut_inside_a_value_is_refused_naming_file_line_and_epoch(tmp_path):
    p = _tail_cut(tmp_path, 3 + 16 + 7)                  # 7 characters into the line's second value
    for read in (read_rinex_obs, lambda q: read_rinex_signals(q, ["G:L1", "R:G1"])):
        with pytest.raises(CdgpsError, match=r"tail26.obs, line 17445: the file ends inside a value of its last "
                                             r"record line \(epoch 2024 06 24 08 25  0.0000000\): truncated file\?"):
            read(p)
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", p, "--nav", MOSAIC / "base.nav",
                "-o", tmp_path / "x.csv")
    assert r.exit_code == 2 and "truncated file?" in r.output and not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("into", [3 + 16, 3 + 16 + 14])
def test_a_last_line_ending_on_a_value_boundary_is_read(tmp_path, into):
    """Whole values, with or without their two flag characters, and no line end at the end of the file: as it
    is (a writer that leaves out the last line end)."""
    p = _tail_cut(tmp_path, into)
    assert read_rinex_obs(p)[1]["time_gps_s"].nunique() == 301


def test_a_record_count_cut_by_the_end_is_refused_as_before(tmp_path):
    data = (MOSAIC / "rover.obs").read_bytes()
    last = data.rfind(b"\n>") + 1
    p = tmp_path / "count.obs"
    p.write_bytes(data[:data.find(b"\n", last) + 1 + 300])             # (inside a value of a record line too)
    with pytest.raises(CdgpsError, match=r"count.obs.*announces 57 satellites but the file ends"):
        read_rinex_obs(p)
