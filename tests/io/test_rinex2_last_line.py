"""A RINEX 2 observation file whose last satellite's record lacks only its last line, a line of blank fields (a tool
that strips trailing white space drops it with the file's last line): read as if the line were there.  A real EUREF
file in a GNSS library's test data (ROVN, 2021-01-01) was refused by every reader ("announces 20 satellites × 3
lines but the file ends"), where RTKLIB reads it; a record missing a whole satellite is still refused."""

from __future__ import annotations

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import REPO_ROOT

SUBSET = REPO_ROOT / "tests" / "data" / "mosaic-base-rinex211-subset.obs"      # 9 types: 2 lines per satellite


def _without_last_lines(tmp_path, n: int, name: str):
    lines = SUBSET.read_text().splitlines(keepends=True)
    assert lines[-1].strip() == "" and lines[-2].strip()                 # the last satellite's second line is blank
    p = tmp_path / name
    p.write_text("".join(lines[:-n]))
    return p


def test_a_last_blank_line_dropped_reads_as_the_whole_file(tmp_path):
    short = _without_last_lines(tmp_path, 1, "short.obs")
    for read in (lambda p: read_rinex_obs(p), lambda p: read_rinex_signals(p, ["G:L1", "G:L2", "E:E1"])):
        (info, got), (whole_info, whole) = read(short), read(SUBSET)
        assert got.equals(whole) and info["end_padded_lines"] == 1 and "end_padded_lines" not in whole_info
    stripped = tmp_path / "stripped.obs"                                 # the last line's white space gone, not the line
    stripped.write_text(SUBSET.read_text().rstrip(" \n") + "\n")
    assert read_rinex_obs(stripped)[1].equals(read_rinex_obs(SUBSET)[1])


def test_a_record_missing_a_whole_satellite_or_cut_in_a_value_is_still_refused(tmp_path):
    cut = _without_last_lines(tmp_path, 2, "cut.obs")
    lines = SUBSET.read_text().splitlines(keepends=True)
    inside = tmp_path / "inside.obs"                  # the last satellite's first line cut inside its L1 phase
    inside.write_text("".join(lines[:-2]) + lines[-2][:24])
    for path in (cut, inside):
        for read in (lambda p: read_rinex_obs(p), lambda p: read_rinex_signals(p, ["G:L1"])):
            with pytest.raises(CdgpsError, match=f"{path.name}.*ends"):
                read(path)


def test_the_commands_say_what_was_read_as_blank(tmp_path):
    """``ingest`` and ``rtk`` warn of the lines given back (blank fields, or a cut that lost the last types)."""
    from cdgps_cli.io.gnss_run import _receiver_warnings, read_receiver_file
    from cdgps_cli.pipeline.gnss_multi import _read_observations
    short = _without_last_lines(tmp_path, 1, "short.obs")
    said: list = []
    _read_observations(short, ["G:L1"], {}, "base", said)
    assert any("ends 1 line(s) short at the end of the file" in w for w in said), said
    said = _receiver_warnings("base", short, read_receiver_file("base", "rinex", short))
    assert any("ends 1 line(s) short at the end of the file" in w for w in said), said
