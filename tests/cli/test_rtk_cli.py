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


def test_hold_after_fixes_below_one_is_refused_naming_the_option(tmp_path):
    """Review finding: hold_after_fixes = 0 held a fix that did not exist yet (TypeError); it is refused
    by the CLI (--hold-after-fixes), by the options check and by solve_rtk, naming the option."""
    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.estimation.rtk_multi import solve_rtk
    from cdgps_cli.pipeline.gnss_multi import rtk_from_files

    msg = _run(tmp_path, "--base", BASE, "--rover", BASE, "--nav", str(GE / "RINEX_GN_Spirent.23N"), "--signals", "G:L1",
               "--fix-and-hold", "--hold-after-fixes", "0")
    assert "--hold-after-fixes" in msg and "0" in msg
    for bad in (0, -3, 2.5, True):
        with pytest.raises(CdgpsError, match="hold_after_fixes"):
            rtk_from_files(BASE, BASE, [], tmp_path / "x.csv", options={"fix_and_hold": True, "hold_after_fixes": bad})
    with pytest.raises(CdgpsError, match="hold_after_fixes"):
        solve_rtk(None, None, (1.0, 2.0, 3.0), (1.0, 2.0, 3.0), options={"fix_and_hold": True, "hold_after_fixes": 0})
    assert list(tmp_path.iterdir()) == []


def test_a_bad_base_position_is_named_before_the_rover_is_placed(tmp_path):
    """Review finding: a rover without a position is placed by single-point positioning started at
    the base; a base position off the Earth (a typo) gave "rover: single-point position is not
    solvable".  The base position is checked first and named."""
    ms = REPO_ROOT / ".." / "shared" / "data" / "real-pairs" / "mosaic-static"
    if not ms.exists():
        pytest.skip("../shared/data/real-pairs absent")
    lines = (ms / "rover.obs").read_text().splitlines(keepends=True)
    lines = [f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}{'':18s}APPROX POSITION XYZ\n" if "APPROX POSITION XYZ" in ln else ln
             for ln in lines]
    src = tmp_path.parent / f"{tmp_path.name}_in"
    src.mkdir()
    rover = src / "rover_no_position.obs"
    rover.write_text("".join(lines))
    msg = _run(tmp_path, "--base", str(ms / "base.obs"), "--rover", str(rover), "--nav", str(ms / "base.nav"),
               "--signals", "G:L1", "--base-xyz", "-3817681", "3562839", "36501590")
    assert "base.obs (base): position from --base-xyz is" in msg and "km from the Earth's centre" in msg
    assert "single-point" not in msg
