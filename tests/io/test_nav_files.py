"""Navigation files one per system (RINEX 3 ``…GN`` GPS, ``…EN`` Galileo, as the Spirent set and many
receivers write them): a reader that wants GPS skips a Galileo-only file beside a GPS one instead of
refusing it (`cdgps config` refused both the pair and the Galileo file alone), and says clearly when
no file holds what is needed."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.gnss_run import merge_nav
from cdgps_cli.io.rinex import nav_file_systems

GE = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "rinex-ge"
pytestmark = pytest.mark.skipif(not GE.exists(), reason="../shared/data/rinex-ge absent")
GPS_NAV, GAL_NAV = GE / "RINEX_GN_Spirent.23N", GE / "RINEX_EN_Spirent.23L"
BASE, ROVER = GE / "Base-static_MO_Spirent.obs", GE / "Rover-static-2km-east_MO_Spirent.obs"


def test_systems_of_each_file_from_its_header():
    assert nav_file_systems(GPS_NAV) == ("G",) and nav_file_systems(GAL_NAV) == ("E",)


def test_gps_merge_skips_the_galileo_file_and_both_merge_for_two_systems():
    gps = merge_nav([GAL_NAV, GPS_NAV], ("G",))
    assert set(gps["sat"].str[0]) == {"G"} and gps["sat"].nunique() == 31
    both = merge_nav([GPS_NAV, GAL_NAV], ("G", "E"))
    assert set(both["sat"].str[0]) == {"G", "E"} and len(both) == len(gps) + 26


def test_no_file_with_the_wanted_system_is_named():
    with pytest.raises(CdgpsError, match=r"RINEX_EN_Spirent.23L: Galileo\) hold no ephemerides of GPS"):
        merge_nav([GAL_NAV], ("G",))


def test_config_comments_every_system_and_the_baseline_runs(tmp_path):
    r = CliRunner().invoke(main, ["-q", "config", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}",
                                  "--nav", str(GPS_NAV), "--nav", str(GAL_NAV), "-o", str(tmp_path / "ge.toml")])
    assert r.exit_code == 0, r.output
    text = (tmp_path / "ge.toml").read_text()
    assert "31 GPS ephemerides" in text and "26 Galileo ephemerides" in text
    r = CliRunner().invoke(main, ["-q", "baseline", "--rinex", f"base={BASE}", "--rinex", f"rover={ROVER}",
                                  "--nav", str(GAL_NAV), "--nav", str(GPS_NAV), "--master", "base",
                                  "-o", str(tmp_path / "b.json")])
    assert r.exit_code == 0, r.output


def test_a_galileo_run_needs_no_gps_ephemerides(tmp_path):
    """signals = ["E:E1"] with only the Galileo navigation file: ingested and solved (E1 fixes the epochs
    and clocks; issue 28); with G:L1 among the signals the missing GPS ephemerides are named."""
    cfg = tmp_path / "gal.toml"
    body = (f'[gnss.antennas.base]\nrinex = "{BASE}"\n[gnss.antennas.rover]\nrinex = "{ROVER}"\n')
    cfg.write_text(f'[gnss]\nmaster = "base"\nnav = ["{GAL_NAV}"]\nsignals = ["E:E1"]\n' + body)
    r = CliRunner().invoke(main, ["-q", "ingest", "--config", str(cfg), "-o", str(tmp_path / "run.mcap")])
    assert r.exit_code == 0, r.output
    cfg.write_text(f'[gnss]\nmaster = "base"\nnav = ["{GAL_NAV}"]\nsignals = ["G:L1", "E:E1"]\n' + body)
    r = CliRunner().invoke(main, ["-q", "ingest", "--config", str(cfg), "-o", str(tmp_path / "run2.mcap")])
    assert r.exit_code == 2 and "no ephemerides of system(s) GPS" in r.stderr and "signals" in r.stderr, r.output
    assert not (tmp_path / "run2.mcap").exists()
