"""io/log_sequence.expand_paths: names and patterns to files, every refusal naming where the name came from."""

from __future__ import annotations

import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.log_sequence import expand_paths


def test_names_and_patterns_become_files_in_name_order(tmp_path):
    for n in ("b.obs", "a.obs", "c.nav"):
        (tmp_path / n).write_text("x")
    assert expand_paths([str(tmp_path / "*.obs"), str(tmp_path / "c.nav")], "--rinex r") == \
        [str(tmp_path / "a.obs"), str(tmp_path / "b.obs"), str(tmp_path / "c.nav")]


def test_a_missing_file_is_named_with_where_it_was_given(tmp_path):
    # a config's missing receiver file was "PATH: cannot read: No such file or directory", without the key
    gone = tmp_path / "gone.obs"
    with pytest.raises(CdgpsError, match=r"^run\.toml: \[gnss\.antennas\.rover\] rinex: .*gone\.obs: cannot read: "
                                         r"no such file$"):
        expand_paths([str(gone)], "run.toml: [gnss.antennas.rover] rinex")


def test_a_pattern_matching_nothing_and_a_file_given_twice_are_refused(tmp_path):
    (tmp_path / "a.obs").write_text("x")
    with pytest.raises(CdgpsError, match=r"--rinex r: the pattern .* matches no file"):
        expand_paths([str(tmp_path / "*.crx")], "--rinex r")
    with pytest.raises(CdgpsError, match=r"--rinex r: the file .*a\.obs is given twice"):
        expand_paths([str(tmp_path / "a.obs"), str(tmp_path / "a*.obs")], "--rinex r")
