"""``rtk --start-time / --end-time`` (RTKLIB's -ts / -te): the rover epochs solved, the base read wider by its
maximum age; the epochs left out counted with their reason; bad times refused naming the option.

Checked on the real car pair: its standing end segment (06:35:12–06:35:59) solved from the whole files with a window
lands where the same segment cut out of the files by hand does (tests/pipeline/test_qzss.py), and where RTKLIB's
G+E+J L1 static solution of that segment is (the pair's README)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds, parse_gps_time
from cdgps_cli.measurement.time_window import OUTSIDE_WINDOW
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s
from tests._shared import REPO_ROOT, run_cli

CAR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "geonet-car"
BASE_XYZ = ("-3959400.631", "3385704.533", "3667523.111")


def test_gps_times_in_rtklib_and_iso_forms():
    t = gps_seconds(2021, 9, 22, 6, 35, 12)
    for text in ("2021/09/22 06:35:12", "2021-09-22T06:35:12", "2021-09-22 06:35:12", " 2021/09/22 06:35:12.0 "):
        assert parse_gps_time(text, "--x") == t
    assert parse_gps_time("2021/09/22 06:35:12.25", "--x") == t + 0.25
    assert parse_gps_time("2021/09/22 06:35:12.123456789", "--x") == t + 0.123456789
    assert parse_gps_time("2021/09/22 06:35", "--x") == t - 12
    for bad in ("06:35:12", "2021/13/22 06:35:12", "2021/09/22 06:35:12.x", "2021/09/22 06:35:12.5.5", "yesterday", "",
                "2021-09-22", "2021/09/22 06:35:12.\u00b2", "2021/09/22 06:35:12.\u0665", "2021/9/22 06:35:12",
                "2021/09-22 06:35:12", "2021/09/22 24:00:00", "2021/09/22 06:35:60"):
        with pytest.raises(CdgpsError, match="--x expects a GPS date and time"):
            parse_gps_time(bad, "--x")
    with pytest.raises(CdgpsError, match="before GPS time began"):
        parse_gps_time("1979/12/31 23:59:59", "--x")


def test_the_window_takes_tags_as_rtklib_does_and_counts_every_file_epoch_outside():
    """RTKLIB keeps an epoch at most DTTOL (25 ms) before -ts and less than DTTOL after -te: u-blox tags 2 ms before
    the second belong to it.  The epochs of the file outside the window are counted as such, those without a phase
    among them too (not as epochs without a phase)."""
    from cdgps_cli.io.rinex_signals import EpochTimes
    from cdgps_cli.pipeline.gnss_multi import _time_window, validate_options

    t0 = gps_seconds(2021, 9, 22, 6, 35, 0)
    tags = t0 + np.arange(30) - 0.002
    r = pd.DataFrame({"time_gps_s": tags, "sat": "G01"})
    b = pd.DataFrame({"time_gps_s": t0 + np.arange(0, 30, 5.0), "sat": "G01"})
    code_only = t0 + np.array([0.5, 13.5])                     # two epochs of the file without a phase
    hr = {"file_epochs": 32, "file_epoch_times": EpochTimes(np.sort(np.r_[tags, code_only]))}
    opt = validate_options({"start_gps_s": t0 + 12, "end_gps_s": t0 + 20, "max_age_s": 4.0})
    b2, r2, hr2, n_out = _time_window(b, r, hr, opt, "base.obs", "rover.obs")
    assert r2["time_gps_s"].tolist() == (tags[12:21]).tolist()          # 06:35:11.998 … 06:35:19.998: 9 epochs
    assert b2["time_gps_s"].tolist() == (t0 + np.array([10.0, 15.0, 20.0])).tolist()
    assert n_out == 32 - 9 - 1 and hr2["file_epochs"] == 10               # 13.5 s is inside: left without a phase
    opt = validate_options({"start_gps_s": t0 + 100, "max_age_s": 4.0})
    with pytest.raises(CdgpsError, match=r"rover.obs \(rover\): no epoch in the window asked for \(2021-09-22 "
                                         r"06:36:40 GPST – its end"):
        _time_window(b, r, hr, opt, "base.obs", "rover.obs")
    opt = validate_options({"end_gps_s": t0 - 100, "max_age_s": 4.0})
    with pytest.raises(CdgpsError, match="window asked for \\(its start – 2021-09-22 06:33:20 GPST"):
        _time_window(b, r, hr, opt, "base.obs", "rover.obs")
    opt = validate_options({"start_gps_s": t0 + 26.5, "max_age_s": 1.0})
    with pytest.raises(CdgpsError, match=r"base.obs \(base\): no epoch in the window asked for or within max_age_s "
                                         r"\(1 s\) of it .*its epochs span 2021-09-22 06:35:00 GPST – 2021-09-22 "
                                         r"06:35:25 GPST"):
        _time_window(b, r, hr, opt, "base.obs", "rover.obs")


def _rtk(tmp_path, *extra, base="3034265G.21O", rover="SEPT265G.21O"):
    base = base if str(base).startswith("/") else CAR / base
    rover = rover if str(rover).startswith("/") else CAR / rover
    return run_cli("rtk", "--base", base, "--rover", rover, "--nav", CAR / "SEPT2650.21P", "--base-xyz", *BASE_XYZ,
                   "--signals", "G:L1,E:E1,J:L1", "--mode", "static", "--direction", "combined", "--pos-frame", "enu",
                   *extra, "--json")


def _last(path):
    line = [ln.split() for ln in path.read_text().splitlines() if not ln.startswith("%")][-1]
    return np.array(line[2:5], dtype=float), int(line[5])


@pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent")
def test_the_car_end_segment_by_window_equals_it_cut_by_hand(tmp_path):
    r = _rtk(tmp_path, "--start-time", "2021/09/22 06:35:12", "--end-time", "2021-09-22T06:35:59", "-o",
             tmp_path / "window.pos")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["epochs"] == 48 and s["fixed_epochs"] == 48
    assert s["epoch_pairing"]["dropped"] == {OUTSIDE_WINDOW: 312} and s["epoch_pairing"]["rover_epochs"] == 360
    cut = {}
    for who, name in (("base", "3034265G.21O"), ("rover", "SEPT265G.21O")):
        text = (CAR / name).read_text()
        t0 = epoch_times_gps_s(text)[0]
        cut[who] = tmp_path / f"{who}.obs"
        cut[who].write_text(edit_rinex3_obs(text, keep=lambda t, t0=t0: 312.0 <= t - t0 <= 359.5))
    r = _rtk(tmp_path, "-o", tmp_path / "cut.pos", base=cut["base"], rover=cut["rover"])
    assert r.exit_code == 0, r.output
    (a, qa), (b, qb) = _last(tmp_path / "window.pos"), _last(tmp_path / "cut.pos")
    assert qa == qb == 1 and np.abs(a - b).max() < 1e-4, (a, b)
    assert ("rover epochs 2021-09-22 06:35:12 GPST – 2021-09-22 06:35:59 GPST (--start-time / --end-time)"
            in (tmp_path / "window.pos").read_text().splitlines()[0])
    assert np.abs(a - np.array([5049.078, 1691.873, -1.356])).max() < 0.002     # RTKLIB's G+E+J L1 static


@pytest.mark.skipif(not CAR.exists(), reason="../shared/data/real-pairs absent")
@pytest.mark.parametrize("args, said", [
    (("--start-time", "2021/09/22 25:00:00"), "--start-time expects a GPS date and time"),
    (("--end-time", "06:35"), "--end-time expects a GPS date and time"),
    (("--start-time", "2021/09/23 00:00"), "no epoch in the window asked for (2021-09-23 00:00:00 GPST – its end"),
    (("--start-time", "2021/09/22"), "--start-time expects a GPS date and time"),
    (("--start-time", "2021/09/22 07:00", "--end-time", "2021/09/22 06:00"),
     "end_gps_s (--end-time): expected at or after start_gps_s (--start-time"),
    (("--end-time", "2021/09/21 00:00"), "no epoch in the window asked for (its start – 2021-09-21 00:00:00 GPST"),
])
def test_a_bad_window_is_refused_naming_it(tmp_path, args, said):
    out = tmp_path / "x.pos"
    r = _rtk(tmp_path, *args, "-o", out)
    assert r.exit_code == 2 and said in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()
    if "no epoch" in said:
        assert "its epochs span 2021-09-22 06:30:00 GPST – 2021-09-22 06:35:59 GPST" in r.output
