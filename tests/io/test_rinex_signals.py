"""Multi-signal RINEX reading (io/rinex_signals.py) and Galileo navigation records; bad input."""

from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import REPO_ROOT

GE = REPO_ROOT / ".." / "shared" / "data" / "rinex-ge"
HDR = """     3.04           OBSERVATION DATA    M: MIXED            RINEX VERSION / TYPE
R    4 C1C L1C C2C L2C                                      SYS / # / OBS TYPES
G    2 C1C L1C                                              SYS / # / OBS TYPES
                                                            END OF HEADER
> 2023 01 08 10 00  0.0000000  0  2
R01  20028872.875 9 105252416.357 9  20028871.910 8  82014855.350 8
G05  20028872.875 9 105252416.357 9
"""


def test_missing_signal_and_glonass_slots(tmp_path: Path):
    p = tmp_path / "x.obs"
    p.write_text(HDR)
    with pytest.raises(CdgpsError, match=r"x.obs: signal\(s\) asked for but absent.*E:E1.*Galileo"):
        read_rinex_signals(p, ["G:L1", "E:E1"])
    with pytest.raises(CdgpsError, match="GLONASS frequency numbers absent for R01.*GLONASS SLOT / FRQ #"):
        read_rinex_signals(p, ["R:G1"])
    p.write_text(HDR.replace("                                                            END OF HEADER",
                             f"{'  1 R01  1':<60}GLONASS SLOT / FRQ #\n"
                             "                                                            END OF HEADER"))
    _, df = read_rinex_signals(p, ["R:G1", "R:G2", "G:L1"])
    lam = dict(zip(df["signal"] + df["sat"], df["wavelength_m"]))
    assert abs(lam["R:G1R01"] - 299792458.0 / (1602e6 + 0.5625e6)) < 1e-12
    assert abs(lam["R:G2R01"] - 299792458.0 / (1246e6 + 0.4375e6)) < 1e-12


@pytest.mark.skipif(not GE.exists(), reason="../shared/data/rinex-ge absent")
def test_galileo_nav_and_missing_system():
    nav = read_rinex_nav(GE / "RINEX_EN_Spirent.23L", systems=("E",))
    assert nav["sat"].str.startswith("E").all() and len(nav) > 10
    with pytest.raises(CdgpsError, match=r"system 'E'; GPS \('G'\) or mixed"):
        read_rinex_nav(GE / "RINEX_EN_Spirent.23L")
    g = nav.iloc[0]
    from cdgps_cli.model.gps.orbits import sat_position_ecef
    xyz, _ = sat_position_ecef(g, g["toe_gps_s"])
    assert 29.5e6 < np.linalg.norm(xyz) < 30.0e6   # Galileo orbit radius ≈ 29 600 km


def test_glonass_frequency_numbers_packed_without_blanks():
    # demo3.10o (RINEX 3.01) writes "  3 R11 -5R19 +3R23 -6": entries found by pattern, not column
    hdr, obs = read_rinex_signals(REPO_ROOT / "tests" / "data" / "demo3.10o", ["R:G1"])
    assert hdr["glonass_slots"] == {"R11": -5, "R19": 3, "R23": -6}
    assert set(obs["sat"]) <= {"R11", "R19", "R23"} and len(obs) > 0
    lam = obs.groupby("sat")["wavelength_m"].first()
    assert lam["R11"] == pytest.approx(299792458.0 / (1602e6 - 5 * 0.5625e6))


def test_rinex2_glonass_observations_with_frequency_numbers_from_elsewhere():
    path = REPO_ROOT / "tests" / "data" / "demo.10o"         # RINEX 2.11, G R S, no frequency numbers
    with pytest.raises(CdgpsError, match=r"GLONASS frequency numbers absent for R\d\d"):
        read_rinex_signals(path, ["R:G1"])
    k = {f"R{n:02d}": (n % 13) - 7 for n in range(1, 25)}
    hdr, obs = read_rinex_signals(path, ["G:L1", "R:G1"], glonass_k=k)
    assert hdr["signal_codes"]["R:G1"] == ["L1", "C1", "P1"] and set(obs["sat"].str[0]) == {"G", "R"}
    r = obs[obs["signal"] == "R:G1"]
    lam = 299792458.0 / (1602e6 + r["sat"].map(k).to_numpy() * 0.5625e6)
    assert np.allclose(r["wavelength_m"], lam) and r["pseudorange_m"].notna().all()
    # the same GLONASS satellites and epochs as the RINEX 3.01 version of the file
    _, r3 = read_rinex_signals(REPO_ROOT / "tests" / "data" / "demo3.10o", ["R:G1"])
    m = r.merge(r3, on=["time_gps_s", "sat"])
    assert len(m) == len(r) == len(r3) and (m["phase_cycles_x"] == m["phase_cycles_y"]).all()
    assert (m["pseudorange_m_x"] == m["pseudorange_m_y"]).all()


def test_a_truncated_file_names_the_epoch_line(tmp_path: Path):
    """An epoch announcing more satellites than the file still has (a log cut off) is an error
    naming the file and the epoch's line, for RINEX 3 and RINEX 2; a malformed count too."""
    p = tmp_path / "cut.obs"
    p.write_text(HDR.rsplit("G05", 1)[0])                       # the second satellite's line is gone
    with pytest.raises(CdgpsError, match=r"cut.obs:5: the epoch announces 2 satellites but the file ends after 1"):
        read_rinex_signals(p, ["G:L1"])
    p.write_text(HDR.replace("  0  2\n", "  0  x\n"))
    with pytest.raises(CdgpsError, match=r"cut.obs:5: malformed epoch line"):
        read_rinex_signals(p, ["G:L1"])
    lines = (REPO_ROOT / "tests" / "data" / "07590920.05o").read_text().splitlines(keepends=True)
    p2 = tmp_path / "cut.05o"
    p2.write_text("".join(lines[:-3]))
    with pytest.raises(CdgpsError, match=r"cut.05o:\d+: the epoch announces \d+ satellites but the file ends"):
        read_rinex_signals(p2, ["G:L1", "G:L2"])
    _, whole = read_rinex_signals(REPO_ROOT / "tests" / "data" / "07590920.05o", ["G:L1", "G:L2"])
    assert len(whole) > 0


V3_EPOCH = "> 2023 01 08 10 00  0.0000000  0  2"


@pytest.mark.parametrize("epoch, why", [
    ("> 2023 01 08 10 00 61.0000000  0  2", r"second must be in \[0, 61\), got 61.0"),
    ("> 2023 01 08 25 00  0.0000000  0  2", "hour must be in 0..23, got 25"),
    ("> 2023 01 08 10 60  0.0000000  0  2", "minute must be in 0..59, got 60"),
    ("> 2023 13 08 10 00  0.0000000  0  2", "month must be in 1..12"),
])
def test_impossible_epoch_time_refused_by_both_readers(tmp_path: Path, epoch, why):
    # second 61 used to be read as the next minute's second 1 (rtk bridged the wrong base epoch: fixed 99 % -> 0 %)
    p = tmp_path / "t.obs"
    p.write_text(HDR.replace(V3_EPOCH, epoch))
    with pytest.raises(CdgpsError, match=rf"t\.obs:5: malformed epoch line .*: {why}"):
        read_rinex_signals(p, ["G:L1"])
    from cdgps_cli.io.rinex import read_rinex_obs
    with pytest.raises(CdgpsError, match=rf"t\.obs, line 5: malformed epoch date/time .*: {why}"):
        read_rinex_obs(p)


def test_leap_second_60_is_still_read(tmp_path: Path):
    p = tmp_path / "t.obs"
    p.write_text(HDR.replace(V3_EPOCH, "> 2023 01 08 10 00 60.5000000  0  2"))
    _, df = read_rinex_signals(p, ["G:L1"])
    assert df["time_gps_s"].iloc[0] % 60 == pytest.approx(0.5)


@pytest.mark.parametrize("raw", ["@@g", "X05", "G x"])
def test_garbage_satellite_record_refused_not_skipped(tmp_path: Path, raw):
    # a record whose first three columns are no satellite was skipped as another system's, unseen
    p = tmp_path / "s.obs"
    p.write_text(HDR.replace("G05  20028872", raw + "  20028872"))
    with pytest.raises(CdgpsError, match=rf"s\.obs:7: malformed satellite identifier '{raw}' at the start of an "
                                         r"observation record \(a system letter"):
        read_rinex_signals(p, ["G:L1"])


def test_epoch_announcing_more_satellites_than_it_holds_is_named(tmp_path: Path):
    # an epoch line where a satellite record was due was called a "malformed satellite identifier '> 2'"
    p = tmp_path / "n.obs"
    two = HDR.replace("G05  20028872.875 9 105252416.357 9\n", "")
    p.write_text(two + "> 2023 01 08 10 00  1.0000000  0  1\nG05  20028872.875 9 105252416.357 9\n")
    with pytest.raises(CdgpsError, match=r"n\.obs:7: an epoch line where satellite record 2 of 2 of the epoch at "
                                         r"line 5 was expected \(the epoch announces more satellites"):
        read_rinex_signals(p, ["G:L1"])


def test_rinex2_short_or_garbage_satellite_list_named(tmp_path: Path):
    # a RINEX 2 satellite list shorter than the count (an epoch line cut) ended in an IndexError traceback
    from tests.io._rinex_edit import edited_copy
    src = REPO_ROOT / "tests" / "data" / "07590920.05o"
    for name, edit in (("short", lambda ln: ln[:41]), ("letter", lambda ln: ln[:32] + "X03" + ln[35:])):
        def cut(lines, end):
            lines[end + 1] = edit(lines[end + 1])
        (tmp_path / name).mkdir()
        p = edited_copy(tmp_path / name, src, cut)
        with pytest.raises(CdgpsError, match=r"07590920\.05o:18: malformed satellite identifier '(|X03)' \(satellite "
                                             r"[14] of the 8 the epoch line announces\)"):
            read_rinex_signals(p, ["G:L1"])


def test_epochs_out_of_time_order_are_noted_for_the_caller(tmp_path: Path):
    # rtk read a file with two epochs swapped in time order without a word (ingest and baseline now read it in time order too, with the same warning)
    from tests.io._rinex_edit import edited_copy
    from cdgps_cli.io import rinex_signals

    src = REPO_ROOT / "tests" / "data" / "07590920.05o"

    def swap(lines, end):
        lines[end + 1:end + 19] = lines[end + 10:end + 19] + lines[end + 1:end + 10]

    p = edited_copy(tmp_path, src, swap)
    for fast in (True, False):
        rinex_signals.FAST_PARSE = fast
        try:
            _, df = read_rinex_signals(p, ["G:L1"])
            _, ok = read_rinex_signals(src, ["G:L1"])
        finally:
            rinex_signals.FAST_PARSE = True
        assert df.attrs["epochs_out_of_order"] == (1, ok["time_gps_s"].iloc[0]) and "epochs_out_of_order" not in ok.attrs
        assert df.equals(ok)


def test_a_gps_only_rinex_2_file_holds_no_glonass_signal():
    """RINEX 2's observation types serve every system of the file: a "G (GPS)" file (GEONET 3040) lists GPS
    signals only (before: GLONASS too, and rtk warned that GLONASS signals held by both files were not used),
    a mixed one GPS and GLONASS."""
    from cdgps_cli.io.rinex_signals import signals_in_file
    r2 = REPO_ROOT / ".." / "shared" / "data" / "rinex"
    if not (r2 / "30400920.05o").exists():
        pytest.skip("../shared/data/rinex absent")
    assert signals_in_file(r2 / "30400920.05o") == ["G:L1", "G:L2"]
    assert signals_in_file(r2 / "demo.10o") == ["G:L1", "G:L2", "R:G1", "R:G2"]
