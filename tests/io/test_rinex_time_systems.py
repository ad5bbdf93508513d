"""Observation epochs in BeiDou or GLONASS time (RINEX 'TIME OF FIRST OBS'): read into GPS time by every reader.

A BeiDou-only receiver writes BDT, a GLONASS-only one GLONASST, and a RINEX 3 file whose header names no time system
is in its satellite system's own.  Before, `config`/`ingest` refused such files and `rtk` read their tags as GPS
time (14 s or 3 h off).  The files here are the real mosaic-X5 rover of ../shared/data rewritten with Python's
datetime: every epoch line and the TIME OF FIRST OBS line moved into the other time scale, nothing else changed.
"""

import datetime as dt
import json

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.rinex import epoch_time_system, read_rinex_obs, to_gps_time_s
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT / ".." / "shared" / "data" / "real-pairs" / "mosaic-static"
need_shared = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")

#: the file's time scale minus GPS time on 2024-06-24: BDT = GPST − 14 s; GLONASST = UTC + 3 h = GPST − 18 s + 3 h
AHEAD_OF_GPS_S = {"BDT": -14.0, "GLO": 3 * 3600.0 - 18.0}


def _moved(when: dt.datetime, seconds: float) -> dt.datetime:
    return when + dt.timedelta(seconds=seconds)


def _in_time_system(text: str, system: str, label: str | None = None) -> str:
    """``text`` (a RINEX 3 observation file in GPS time) with its epochs in ``system`` and its TIME OF FIRST OBS
    naming ``label`` (default ``system``; "" leaves the field blank)."""
    shift = AHEAD_OF_GPS_S[system]
    out, head = [], True
    for ln in text.splitlines():
        if head and ln[60:].startswith("TIME OF FIRST OBS"):
            f = [int(ln[i:i + 6]) for i in (0, 6, 12, 18, 24)]
            t = _moved(dt.datetime(*f), float(ln[30:43]) + shift)
            sec = t.second + t.microsecond / 1e6
            name = system if label is None else label
            ln = f"{t.year:6d}{t.month:6d}{t.day:6d}{t.hour:6d}{t.minute:6d}{sec:13.7f}     {name:3s}".ljust(60) + ln[60:]
        elif head and ln[60:].startswith("END OF HEADER"):
            head = False
        elif not head and ln.startswith(">"):
            f = [int(ln[i:i + w]) for i, w in ((2, 4), (7, 2), (10, 2), (13, 2), (16, 2))]
            t = _moved(dt.datetime(*f), float(ln[18:29]) + shift)
            sec = t.second + t.microsecond / 1e6
            ln = f"> {t.year:4d} {t.month:02d} {t.day:02d} {t.hour:02d} {t.minute:02d}{sec:11.7f}" + ln[29:]
        out.append(ln)
    return "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def rovers(tmp_path_factory):
    """The rover in GPS time as recorded, and rewritten into BDT and GLONASST."""
    d = tmp_path_factory.mktemp("time_systems")
    text = (MOSAIC / "rover.obs").read_text()
    out = {"GPS": MOSAIC / "rover.obs"}
    for system in AHEAD_OF_GPS_S:
        out[system] = d / f"rover_{system}.obs"
        out[system].write_text(_in_time_system(text, system))
    return out


def test_offsets_against_the_calendar():
    """BDT's epoch is GPS week 1356 + 14 s; GLONASST is UTC + 3 h, so across the leap second of 2016-12-31 its
    02:59:59 and 03:00:00 are 17 and 18 s behind GPS time."""
    assert to_gps_time_s(gps_seconds(2006, 1, 1, 0, 0, 0.0), "BDT") == 1356 * 604800 + 14
    assert to_gps_time_s(gps_seconds(2017, 1, 1, 2, 59, 59.0), "GLO") == gps_seconds(2017, 1, 1, 0, 0, 16.0)
    assert to_gps_time_s(gps_seconds(2017, 1, 1, 3, 0, 0.0), "GLO") == gps_seconds(2017, 1, 1, 0, 0, 18.0)
    t = np.array([gps_seconds(2024, 6, 24, 8, 20, 0.5)])
    np.testing.assert_array_equal(to_gps_time_s(t, "GPS"), t)
    np.testing.assert_array_equal(to_gps_time_s(t, "GAL"), t)


def test_a_header_without_a_time_system_is_in_its_systems_own():
    assert epoch_time_system({"time_system": None, "satellite_system": "R"}) == "GLO"
    assert epoch_time_system({"time_system": None, "satellite_system": "C"}) == "BDT"
    assert epoch_time_system({"time_system": None, "satellite_system": "M"}) == "GPS"
    assert epoch_time_system({"time_system": "GPS", "satellite_system": "R"}) == "GPS"


@need_shared
@pytest.mark.parametrize("system", sorted(AHEAD_OF_GPS_S))
def test_both_readers_return_the_recorded_gps_epochs(rovers, system):
    for read in (lambda p: read_rinex_signals(p, ["G:L1", "E:E1", "C:B1I"]), read_rinex_obs):
        h0, ref = read(rovers["GPS"])
        h, got = read(rovers[system])
        assert list(got.columns) == list(ref.columns)
        for col in ref.columns:
            np.testing.assert_array_equal(got[col].to_numpy(), ref[col].to_numpy())
        assert h["time_first_obs_gps_s"] == h0["time_first_obs_gps_s"]
        assert h["epochs_time_system"] == f"{system} (converted to GPS time)" and "epochs_time_system" not in h0


@need_shared
@pytest.mark.parametrize("system", sorted(AHEAD_OF_GPS_S))
def test_rtk_and_init_solve_as_in_gps_time(rovers, tmp_path, system):
    """Every .pos row as from the file in GPS time; `init` (which refused these files) the same integers and rover."""
    rows = {}
    for name in ("GPS", system):
        out = tmp_path / f"{name}.pos"
        r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", rovers[name], "--nav", MOSAIC / "base.nav",
                    "--signals", "G:L1,E:E1", "-o", out)
        assert r.exit_code == 0, r.output
        rows[name] = [ln for ln in out.read_text().splitlines() if not ln.startswith("%")]
    assert rows[system] == rows["GPS"] and len(rows["GPS"]) == 301
    inits = {}
    for name in ("GPS", system):
        cfg, run, init = (tmp_path / f"{name}.{x}" for x in ("toml", "mcap", "json"))
        for args in (("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rovers[name]}",
                      "--nav", MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1,E:E1", "-o", cfg),
                     ("ingest", "--config", cfg, "-o", run), ("init", run, "-o", init)):
            r = run_cli("-q", *args)
            assert r.exit_code == 0, r.output
        inits[name] = json.loads(init.read_text())["rovers"]["rover"]
    for key in ("rover_ecef_m", "n_fixed", "epochs"):
        assert inits[system][key] == inits["GPS"][key], key
    r = run_cli("info", tmp_path / f"{system}.mcap")        # info says so, beside the GPS times of the epochs
    line = next(ln for ln in r.output.splitlines() if f"rover_{system}.obs" in ln)
    assert line.endswith(f"; epochs in {system} (converted to GPS time)") and "2024-06-24 08:20:00 GPST" in line


@need_shared
def test_a_time_system_not_read_is_refused_by_line(tmp_path):
    bad = tmp_path / "rover_irn.obs"
    bad.write_text(_in_time_system((MOSAIC / "rover.obs").read_text(), "BDT", label="IRN"))
    line = next(i for i, ln in enumerate(bad.read_text().splitlines(), 1) if "TIME OF FIRST OBS" in ln)
    with pytest.raises(CdgpsError, match=rf"rover_irn\.obs, line {line}: time system 'IRN' .* not read"):
        read_rinex_signals(bad, ["G:L1"])
    r = run_cli("rtk", "--base", MOSAIC / "base.obs", "--rover", bad, "--nav", MOSAIC / "base.nav", "-o", tmp_path / "x.pos")
    assert r.exit_code == 2 and "IRN" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "x.pos").exists()
