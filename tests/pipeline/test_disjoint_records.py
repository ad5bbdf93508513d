"""A base and a rover of different days (a sweep: two u-blox logs seven years apart).  ``rtk`` failed placing the
rover ("single-point position is not solvable (fewer than 4 satellites per epoch)", the other day's ephemerides);
``config`` wrote a config ``ingest`` then refused.  ``rtk`` now says "no common epochs" with both spans before it
places the rover (exit 2, nothing written), and ``config`` warns and says so in the config's comments."""

from __future__ import annotations

import pytest

from tests._shared import run_cli


@pytest.fixture(scope="module")
def days(tmp_path_factory):
    d = tmp_path_factory.mktemp("days")
    for name, start in (("a", "2024-01-01T00:00:00"), ("b", "2024-01-03T00:00:00")):
        r = run_cli("-q", "simulate-gnss", "--duration", "60", "--start", start, "-o", d / name)
        assert r.exit_code == 0, r.output
    return d


def test_rtk_names_both_spans(days, tmp_path):
    out = tmp_path / "x.pos"
    r = run_cli("-q", "rtk", "--base", days / "a" / "base.rnx", "--rover", days / "b" / "rover.rnx", "--nav",
                days / "a" / "nav.rnx", "--nav", days / "b" / "nav.rnx", "-o", out)
    assert r.exit_code == 2, r.output
    assert "no common epochs" in r.output and "2024-01-01 00:00:00" in r.output and "2024-01-03 00:00:00" in r.output
    assert "base.rnx (base) spans" in r.output and "Traceback" not in r.output and not out.exists()


def test_config_warns_and_comments(days, tmp_path):
    out = tmp_path / "c.toml"
    r = run_cli("config", "--rinex", f"base={days / 'a' / 'base.rnx'}", "--rinex", f"rover={days / 'b' / 'rover.rnx'}",
                "--nav", days / "a" / "nav.rnx", "--master", "base", "-o", out)
    assert r.exit_code == 0, r.output
    assert "no common epochs; 'cdgps ingest' refuses the pair" in r.output
    assert "rover: NO EPOCH IN COMMON with the master base" in out.read_text()
