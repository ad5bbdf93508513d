"""GLONASS ephemerides from a u-blox log's RXM-SFRBX strings as a navigation source (issue 28 item 3).

The real F9 log of pygnssutils (``tests/data/pygpsdata_testobsnavdata.log``: RXM-RAWX with GLONASS L1OF and 491
GLONASS strings, no navigation file) carries 12 GPS/Galileo/BeiDou and 8 GLONASS ephemerides
(``tests/io/test_sfrbx_glonass.py`` checks those records against the log's own pseudoranges).  Before session 28 the
ingest and ``rtk`` decoded the log's strings of every system but GLONASS, so a GLONASS-anchored run was refused
("the navigation data do not cover the observations").  The independent check of ``rtk`` is the zero baseline: the
log against a copy of itself must land on the base position given.
"""

import json
import shutil

import numpy as np
import pytest

from cdgps_cli.config.structure import load_gnss_config
from cdgps_cli.io import gnss_archive, gnss_hours
from cdgps_cli.pipeline import gnss_ingest
from tests._shared import REPO_ROOT, run_cli

LOG = REPO_ROOT / "tests" / "data" / "pygpsdata_testobsnavdata.log"
XYZ = (3803656.044, -148801.224, 5100650.407)
"""The log's position from its GPS, Galileo and BeiDou pseudoranges (tests/io/test_sfrbx_real.py's fit), m."""


def _config(tmp_path, signals) -> object:
    p = tmp_path / "job.toml"
    p.write_text(f'[gnss]\nsignals = {json.dumps(signals)}\n[gnss.antennas.f9]\nubx = "{LOG}"\n')
    return p


def test_a_glonass_run_from_a_ublox_log_alone(tmp_path, monkeypatch):
    """Ingest anchored on GLONASS G1, no navigation file: the log's GLONASS strings give 8 ephemerides, and the run is
    the same hour by hour (blocks of 20 s) and whole."""
    cfg = load_gnss_config(_config(tmp_path, ["R:G1"]))
    monkeypatch.setattr(gnss_archive, "OBS_BLOCK_S", 20.0)
    s = gnss_ingest.ingest_gnss(cfg, tmp_path / "hours.mcap")
    assert s["reading"]["hour_by_hour"] and s["reading"]["blocks"] >= 4
    assert s["ephemerides"] == 20 and s["ephemeris_satellites"] == 20
    monkeypatch.setattr(gnss_hours, "hourly_inputs", lambda *a, **k: None)
    w = gnss_ingest.ingest_gnss(cfg, tmp_path / "whole.mcap")
    assert (tmp_path / "hours.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()
    assert {k: v for k, v in w.items() if k not in ("output", "reading")} == \
        {k: v for k, v in s.items() if k not in ("output", "reading")}


@pytest.mark.parametrize("signals", ["R:G1", "R:G1,E:E1"])
def test_rtk_on_glonass_from_the_logs_strings(tmp_path, signals):
    """``rtk`` with GLONASS from the logs alone (no --nav), zero baseline: every epoch used, the rover on the base."""
    shutil.copy(LOG, tmp_path / "rover.log")
    r = run_cli("rtk", "--base", LOG, "--rover", tmp_path / "rover.log", "--signals", signals, "--glonass-fix",
                "--base-xyz", *map(str, XYZ), "-o", tmp_path / "r.pos", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["epochs"] == 75 and s["epoch_pairing"]["used"] == 75 and "R:G1" in s["signals"]
    assert np.linalg.norm(np.array(s["last_xyz_m"]) - XYZ) < 0.05
