"""`cdgps rtk` bad input (issue 14 item 7): clear message naming the file and what was expected,
exit 2, no traceback, nothing written."""

from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from tests._shared import REPO_ROOT

GE = REPO_ROOT / ".." / "shared" / "data" / "rinex-ge"
GEONET = REPO_ROOT / ".." / "shared" / "data" / "rinex"
pytestmark = pytest.mark.skipif(not GE.exists() or not GEONET.exists(), reason="../shared/data absent")
BASE = str(GE / "Base-static_MO_Spirent.obs")


def _run(tmp_path: Path, *args):
    out = tmp_path / "rtk.csv"
    res = CliRunner().invoke(main, ["rtk", *args, "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert not out.exists() and list(tmp_path.iterdir()) == []
    return res.output


def test_navigation_missing_a_system(tmp_path):
    msg = _run(tmp_path, "--base", BASE, "--rover", BASE, "--nav", str(GE / "RINEX_GN_Spirent.23N"), "--signals", "G:L1,E:E1")
    assert "RINEX_GN_Spirent.23N) have no Galileo ephemerides" in msg


def test_frequency_the_receivers_do_not_share(tmp_path):
    msg = _run(tmp_path, "--base", BASE, "--rover", str(GEONET / "30400920.05o"), "--nav", str(GE / "RINEX_GN_Spirent.23N"),
               "--signals", "G:L1,G:L5")
    assert "30400920.05o: signal(s) asked for but absent" in msg and "G:L5" in msg and "the file has L1 C1 L2 P2" in msg


def test_constellation_not_shared_and_unknown_signal(tmp_path):
    msg = _run(tmp_path, "--base", BASE, "--rover", str(GEONET / "30400920.05o"), "--nav", str(GE / "RINEX_GN_Spirent.23N"),
               "--signals", "G:L1,E:E1")
    assert "30400920.05o" in msg and "E:E1 (Galileo" in msg
    msg = _run(tmp_path, "--base", BASE, "--rover", BASE, "--nav", str(GE / "RINEX_GN_Spirent.23N"), "--signals", "G:L7")
    assert "unknown signal 'G:L7'" in msg


def test_beidou_glonass_signals_are_accepted_and_refusals_name_what_is_missing(tmp_path):
    data = REPO_ROOT / "tests" / "data"
    p433 = str(data / "P433_lli_subset.crx")                       # real Septentrio file: G E S R C, 2019-01-01
    # a navigation file of another day: BeiDou/GLONASS are read, the coverage check names the gap
    msg = _run(tmp_path, "--base", p433, "--rover", p433, "--nav", str(data / "MOJN00DNK_R_20201770000_subset.rnx"),
               "--signals", "C:B1I,C:B2I,R:G1")
    assert "no observation is covered by the navigation data" in msg and "C08 C19" in msg
    # a navigation file without BeiDou
    msg = _run(tmp_path, "--base", p433, "--rover", p433, "--nav", str(data / "BRDM00DLR_R_20130010000_01D_MN.rnx"),
               "--signals", "C:B1I")
    assert "BRDM00DLR_R_20130010000_01D_MN.rnx" in msg and "C" in msg
    # rinex-ge has no BeiDou observation types
    msg = _run(tmp_path, "--base", BASE, "--rover", BASE, "--nav", str(GE / "RINEX_GN_Spirent.23N"), "--signals", "C:B1I")
    assert "C:B1I (BeiDou" in msg and "absent from the observation types" in msg
