"""``rtk --pos-frame`` (RTKLIB's out-solformat): a .pos file in latitude/longitude/height, ECEF or the baseline's
east/north/up, the same solution in each (issue 28 item 5: ".pos … as lat/lon/height, ECEF or ENU").

Independent check: RTKLIB's ``pos2kml`` (Debian 2.4.3 b34) read the ECEF file of the mosaic pair to the same track and
reference point as the lat/lon/height file once its comment line said ``(x/y/z-ecef=`` and its ``ref pos`` was ECEF, as
``rnx2rtkp`` writes them (before, it read the ECEF coordinates as degrees); ``pos2kml`` places no ENU file right, its
own either, so the ENU file is checked here against the ECEF one."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.solution_formats import read_pos
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic
from cdgps_cli.pipeline.gnss_multi import validate_options
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
BASE_XYZ = np.array([-3817680.7270, 3562839.5216, 3650159.2407])          # its header position (DELTA H/E/N 0)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    if not MOSAIC.exists():
        pytest.skip("../shared/data absent")
    d = tmp_path_factory.mktemp("frames")
    out = {}
    for f in ("llh", "xyz", "enu"):
        r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", MOSAIC / "rover.obs", "--nav",
                    MOSAIC / "base.nav", "--signals", "G:L1", "-o", d / f"{f}.pos", *(("--pos-frame", f) if f != "llh" else ()))
        assert r.exit_code == 0, r.output
        out[f] = (read_pos(d / f"{f}.pos"), (d / f"{f}.pos").read_text())
    return out


def test_the_three_frames_hold_one_solution(frames):
    llh, xyz, enu = (frames[f][0] for f in ("llh", "xyz", "enu"))
    assert (llh["frame"], xyz["frame"], enu["frame"]) == ("llh", "xyz", "enu")
    for k in ("time_gps_s", "q", "ns", "age_s", "ratio"):
        assert np.array_equal(llh[k], xyz[k]) and np.array_equal(llh[k], enu[k])
    lat, lon, h = ecef_to_geodetic(xyz["coords"])
    assert np.abs(np.degrees(lat) - llh["coords"][:, 0]).max() < 2e-9          # the columns' rounding: 1e-9 deg, 0.1 mm
    assert np.abs(np.degrees(lon) - llh["coords"][:, 1]).max() < 2e-9
    assert np.abs(h - llh["coords"][:, 2]).max() < 2e-4
    assert np.abs(ecef_to_enu(xyz["coords"], BASE_XYZ) - enu["coords"]).max() < 2e-4
    # σ: the ECEF file's three σ are those of the same covariance as the llh file's (north, east, up) σ
    s_xyz, s_llh = xyz["sd"][:, :3], llh["sd"][:, :3]
    rounding = 2 * 5e-5 * (s_xyz.sum(axis=1) + s_llh.sum(axis=1))            # each σ written to 0.1 mm
    assert (np.abs(np.sum(s_xyz**2, axis=1) - np.sum(s_llh**2, axis=1)) <= rounding + 1e-12).all()


def test_an_ecef_file_says_so_as_rnx2rtkp_does(frames):
    text = frames["xyz"][1]
    assert "% (x/y/z-ecef=WGS84,Q=1:fix,2:float,5:single,ns=# of satellites)" in text
    assert "% ref pos   : -3817680.7270 3562839.5216 3650159.2407" in text
    assert "% ref pos   : 35.13470" in frames["llh"][1] and "% ref pos   : 35.13470" in frames["enu"][1]


def test_a_frame_for_another_output_or_an_unknown_one_is_refused(tmp_path):
    r = run_cli("-q", "rtk", "--base", "b.obs", "--rover", "r.obs", "--pos-frame", "xyz", "-o", tmp_path / "x.csv")
    assert r.exit_code == 2 and "x.csv: pos_frame 'xyz' (--pos-frame) is the coordinates of a .pos output" in r.output
    assert not (tmp_path / "x.csv").exists()
    with pytest.raises(CdgpsError, match=r"pos_frame: expected one of 'llh', 'xyz', 'enu', got 'ned'"):
        validate_options({"pos_frame": "ned"})
    with pytest.raises(CdgpsError, match=r"iono_threshold_km: expected a baseline length in km >= 0, got -1"):
        validate_options({"iono_threshold_km": -1})


def test_static_mode_runs_forward_unless_a_direction_is_given():
    """Static mode is one forward pass by default (RTKLIB's), and runs the direction given (once refused; before that
    it ran forward and said "forward": ``tests/estimation/test_rtk_static_directions.py``)."""
    assert validate_options({"mode": "static"})["direction"] == "forward"
    for d in ("forward", "backward", "combined"):
        assert validate_options({"mode": "static", "direction": d})["direction"] == d
    assert validate_options({"mode": "kinematic"})["direction"] == "combined"
    with pytest.raises(CdgpsError, match=r"direction: expected 'forward', 'backward' or 'combined', got 'both'"):
        validate_options({"mode": "static", "direction": "both"})


def test_rtk_json_says_what_was_written_and_how(tmp_path):
    """``rtk --json`` names its output, mode, frame and the base position it used (a new user's run had to look
    them up in the file)."""
    import json as _json
    m = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
    if not m.exists():
        pytest.skip("../shared/data/real-pairs absent")
    out = tmp_path / "s.pos"
    r = run_cli("-q", "rtk", "--base", m / "base.obs", "--rover", m / "rover.obs", "--nav", m / "base.nav", "--signals",
                "G:L1", "--mode", "static", "--pos-frame", "enu", "-o", out, "--json")
    assert r.exit_code == 0, r.output
    s = _json.loads(r.stdout)
    assert s["output"] == str(out) and s["mode"] == "static" and s["pos_frame"] == "enu" and s["direction"] == "forward"
    assert len(s["base_xyz_m"]) == 3 and 6.3e6 < float(np.linalg.norm(s["base_xyz_m"])) < 6.4e6


@pytest.mark.parametrize("suffix", [".kml", ".KMZ", ".gpx"])
def test_an_output_in_a_format_rtk_does_not_write_is_refused(tmp_path, suffix):
    """``-o x.kml`` wrote CSV into a file named .kml: refused before any file is read."""
    out = tmp_path / f"x{suffix}"
    r = run_cli("-q", "rtk", "--base", "b.obs", "--rover", "r.obs", "-o", out)
    assert r.exit_code == 2 and f"x{suffix}: rtk does not write" in r.output and not out.exists()
