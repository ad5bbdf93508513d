"""The base antenna is its header's marker plus its ``ANTENNA: DELTA H/E/N`` (``positioning.antenna_reference_point_m``),
in ``rtk`` and in ``init`` (``baseline._a_priori_positions``), as RTKLIB's base from its header; a rover's delta is
not applied, and a note says so.

Independent check: RTKLIB (Debian ``rnx2rtkp`` 2.4.3 b34), static, GPS L1, mask 15°, ``ant2-postype=rinexhead``, on
the real mosaic pair (../shared/data/real-pairs/mosaic-static) with the base's header DELTA H/E/N edited from 0 0 0 to
0.5 / 0.1 / −0.2 m: its final static position moved from (−3817680.9841, 3562840.0678, 3650158.4574) to
(−3817681.4354, 3562840.3522, 3650158.5816) m, and not at all when the same delta was written into the rover's header.
Every shared and test pair had a delta of 0 0 0, so cdgps had never applied it: a CORS base with its antenna 5 cm above
the marker (the real 35 km DELF → ZEGV pair) put every rover 5 cm low against RTKLIB.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.gps.positioning import antenna_reference_point_m, rover_delta_note
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
MARKER = (-3817680.7270, 3562839.5216, 3650159.2407)          # the mosaic base's APPROX POSITION XYZ
RTKLIB_PLAIN = np.array([-3817680.9841, 3562840.0678, 3650158.4574])
RTKLIB_BASE_DELTA = np.array([-3817681.4354, 3562840.3522, 3650158.5816])


def test_the_delta_is_turned_from_east_north_up_at_the_marker():
    h = {"approx_position_xyz_m": MARKER, "antenna_delta_hen_m": (0.5, 0.1, -0.2)}
    moved = antenna_reference_point_m(h) - np.array(MARKER)
    assert np.allclose(moved, RTKLIB_BASE_DELTA - RTKLIB_PLAIN, rtol=0, atol=3e-4)      # RTKLIB's own shift
    assert abs(np.linalg.norm(moved) - np.sqrt(0.5**2 + 0.1**2 + 0.2**2)) < 1e-9
    lat, lon = np.radians(35.134707705), np.radians(136.977577939)                       # up: the ellipsoid normal
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    assert abs(moved @ up - 0.5) < 1e-6


def test_no_delta_leaves_the_marker_as_it_is_and_no_position_stays_none():
    for delta in (None, (0.0, 0.0, 0.0)):
        p = antenna_reference_point_m({"approx_position_xyz_m": MARKER, "antenna_delta_hen_m": delta})
        assert p.tolist() == list(MARKER)                                                  # bit for bit
    assert antenna_reference_point_m({"approx_position_xyz_m": (0.0, 0.0, 0.0), "antenna_delta_hen_m": (1, 0, 0)}) is None
    for bad in ((np.nan, 0, 0), (1e30, 0, 0), (0, 0, -1.0001e4)):
        with pytest.raises(CdgpsError, match=r"base.obs: ANTENNA: DELTA H/E/N \(.*\) is not three numbers within "
                                             r"±10000 m of the marker"):
            antenna_reference_point_m({"approx_position_xyz_m": MARKER, "antenna_delta_hen_m": bad}, "base.obs")
    assert np.isfinite(antenna_reference_point_m({"approx_position_xyz_m": MARKER, "antenna_delta_hen_m": (1e4, 0, 0)})).all()


def test_a_rover_delta_is_said_not_applied():
    assert rover_delta_note({"antenna_delta_hen_m": (0.0, 0.0, 0.0)}, "r.obs (rover)") == []
    note, = rover_delta_note({"antenna_delta_hen_m": (1.2, 0.0, 0.0)}, "r.obs (rover)")
    assert note.startswith("r.obs (rover): its header's ANTENNA: DELTA H/E/N (1.2 0 0 m) is not applied")


def _with_delta(src, dst, hen):
    lines = src.read_text().splitlines(keepends=True)
    out = [f"{hen[0]:14.4f}{hen[1]:14.4f}{hen[2]:14.4f}".ljust(60) + "ANTENNA: DELTA H/E/N\n"
           if "ANTENNA: DELTA H/E/N" in ln else ln for ln in lines]
    assert out != lines
    dst.write_text("".join(out))
    return dst


@pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")
def test_rtk_and_init_put_the_base_antenna_where_rtklib_does(tmp_path):
    base_dh = _with_delta(MOSAIC / "base.obs", tmp_path / "base_dh.obs", (0.5, 0.1, -0.2))
    rover_dh = _with_delta(MOSAIC / "rover.obs", tmp_path / "rover_dh.obs", (0.5, 0.1, -0.2))
    final = {}
    for name, base, rover in (("plain", MOSAIC / "base.obs", MOSAIC / "rover.obs"), ("base", base_dh, MOSAIC / "rover.obs"),
                              ("rover", MOSAIC / "base.obs", rover_dh)):
        out = tmp_path / f"{name}.csv"
        r = run_cli("-q", "rtk", "--base", base, "--rover", rover, "--nav", MOSAIC / "base.nav", "--signals", "G:L1",
                    "--mode", "static", "-o", out, "--json")
        assert r.exit_code == 0, r.output
        s = json.loads(r.stdout)
        final[name] = np.asarray(s["static_xyz_m"])
        notes = [w for w in s["warnings"] if "DELTA H/E/N" in w]
        assert len(notes) == (name == "rover")
        assert all(w.startswith(f"{rover_dh} (rover): its header's ANTENNA: DELTA H/E/N (0.5 0.1 -0.2 m) is not applied")
                   for w in notes)
    assert np.abs(final["plain"] - RTKLIB_PLAIN).max() < 1e-3
    assert np.abs(final["base"] - RTKLIB_BASE_DELTA).max() < 1e-3          # before: RTKLIB_PLAIN, 0.55 m away
    assert np.array_equal(final["rover"], final["plain"])
    # init (config → ingest → init): the master antenna too, and INIT records where it put it
    xyz = {}
    for name, base in (("plain", MOSAIC / "base.obs"), ("base", base_dh)):
        cfg, run, init = (tmp_path / f"{name}{x}" for x in (".toml", ".mcap", ".json"))
        for args in (("config", "--rinex", f"b={base}", "--rinex", f"r={MOSAIC / 'rover.obs'}", "--nav",
                      MOSAIC / "base.nav", "--master", "b", "-o", cfg), ("ingest", "--config", cfg, "-o", run),
                     ("init", run, "-o", init)):
            r = run_cli("-q", *args)
            assert r.exit_code == 0, (args, r.output)
        info = run_cli("info", run)
        assert info.exit_code == 0 and (("position: RINEX header APPROX POSITION XYZ, the marker (the antenna: its "
                                         "ANTENNA: DELTA H/E/N 0.5 0.1 -0.2 m from it)") in info.output) == (name == "base")
        doc = json.loads(init.read_text())
        xyz[name] = (np.asarray(doc["rovers"]["r"]["rover_ecef_m"]), np.asarray(doc["master_ecef_m"]))
    shift = antenna_reference_point_m({"approx_position_xyz_m": MARKER, "antenna_delta_hen_m": (0.5, 0.1, -0.2)}) - MARKER
    assert np.abs(xyz["base"][1] - xyz["plain"][1] - shift).max() < 1e-9
    assert np.abs(xyz["base"][0] - xyz["plain"][0] - shift).max() < 1e-3


def test_epochs_spread_keeps_the_first_the_last_and_as_many_as_asked():
    from cdgps_cli.model.gps.positioning import epochs_spread

    k = epochs_spread(601, 120)
    assert k.sum() == 120 and k[0] and k[-1]
    assert epochs_spread(100, 120).all() and epochs_spread(100, None).all() and epochs_spread(0, 5).size == 0
