"""``rtk --antex``: the receiver antennas' phase-centre models taken out of the observations
(``pipeline.antenna_models``, ``gnss_multi._antenna_models``).

Simulator truth: the simulator observes each receiver at its phase centre; placed there, 7 and 16 cm above the antenna
reference points (and off them by millimetres sideways), with the base held at its reference point, the rover's
fixed position is off by the difference of the offsets without the model and at its reference point with it.  The
real pair DELF → ZEGV (tests/data/georust-delf-zegv) takes the options through the command.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _shared import run_cli

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.core.signals import signal
from cdgps_cli.estimation.rtk_multi import receiver_geometry, solve_rtk
from cdgps_cli.io.antex import read_antex
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic, enu_matrix
from cdgps_cli.model.gps.positioning import synthetic_nav
from cdgps_cli.pipeline.antenna_models import with_antenna_model
from cdgps_cli.sim.gnss_signals import simulate_receiver_signals
from tests.io.test_antex import antenna_block, write_antex

DATA = Path(__file__).resolve().parents[1] / "data" / "georust-delf-zegv"
#: north, east, up (mm) of the two antennas' phase centres above their reference points, the same on L1 and L2
PCO_MM = {"BASEANT": (1.0, -2.0, 70.0), "ROVERANT": (-3.0, 1.5, 160.0)}


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    p = tmp_path_factory.mktemp("antex") / "two.atx"
    write_antex(p, [antenna_block(f"{name:<16}NONE", {f: (neu, np.zeros(19)) for f in ("G01", "G02")})
                    for name, neu in PCO_MM.items()])
    m = read_antex(p)
    return m[("BASEANT", "NONE")], m[("ROVERANT", "NONE")]


def _at_phase_centre(x, name):
    n, e, u = np.array(PCO_MM[name]) * 1e-3
    return x + np.array([e, n, u]) @ enu_matrix(*ecef_to_geodetic(x)[:2])


def test_with_the_model_the_rover_is_placed_at_its_reference_point(models):
    t0 = gps_seconds(2024, 3, 1)
    nav = synthetic_nav("G", t0, 700.0, seed=3)
    xb = np.array([-3978242.4, 3382841.2, 3649902.8])
    xr = xb + np.array([600.0, 800.0, 5.0]) @ enu_matrix(*ecef_to_geodetic(xb)[:2])
    geo = []
    for k, (x, name) in enumerate(((xb, "BASEANT"), (xr, "ROVERANT"))):
        o = simulate_receiver_signals(nav, _at_phase_centre(x, name), t0, 60, 10.0, ("G:L1", "G:L2"), seed=k + 1,
                                      clock_drift_ms=0.3)["obs"]
        geo.append(receiver_geometry(o.assign(wavelength_m=[signal(g).wavelength_m for g in o["signal"]]), nav, x))
    opt = {"mode": "static", "code_noise": "model", "age_noise": "model", "direction": "forward"}
    got = {}
    for label, (gb, gr) in (("raw", geo), ("model", (with_antenna_model(geo[0], models[0], xb),
                                                     with_antenna_model(geo[1], models[1], xr)))):
        res = solve_rtk(gb, gr, xb, xr, options=opt)
        assert res["fixed"][-1], label
        got[label] = np.asarray(ecef_to_enu(res["fixed_xyz_m"][-1], xr))
    np.testing.assert_allclose(got["model"], 0.0, atol=0.003)
    (nb, eb, ub), (nr, er, ur) = (np.array(PCO_MM[n]) * 1e-3 for n in ("BASEANT", "ROVERANT"))
    np.testing.assert_allclose(got["raw"], [er - eb, nr - nb, ur - ub], atol=0.003)      # +9 cm of height


def test_the_model_is_taken_out_of_phase_and_code_alike_and_the_table_is_otherwise_unchanged(models):
    import pandas as pd

    g = pd.DataFrame({"signal": ["G:L1", "G:L2"], "phase_cycles": [1.0e7, 2.0e7], "pseudorange_m": [2.2e7, 2.2e7],
                      "wavelength_m": [0.19, 0.244], "sx": [0.0, 2.0e7], "sy": [0.0, 0.0], "sz": [2.6e7, 1.0e7],
                      "el_rad": [1.0, 0.3]})
    g.attrs = {"note": 1}
    x = np.array([0.0, 0.0, 6.357e6])
    out = with_antenna_model(g, models[1], x)
    d = g["pseudorange_m"] - out["pseudorange_m"]
    np.testing.assert_allclose((g["phase_cycles"] - out["phase_cycles"]) * g["wavelength_m"], d, rtol=1e-6)
    assert d[0] == pytest.approx(-0.160, abs=1e-6)            # the satellite at the zenith: the up offset
    assert out.attrs == {"note": 1} and list(out.columns) == list(g.columns)


def _antex_for_delf_zegv(tmp_path, names):
    p = tmp_path / "dz.atx"
    write_antex(p, [antenna_block(n, {f: ((0.0, 0.0, up), np.zeros(19)) for f in ("G01", "G02")})
                    for n, up in names.items()])
    return p


def test_rtk_takes_the_antennas_from_the_headers_or_as_named(tmp_path):
    """The real 35 km pair: DELF's header names TRM29659.00 with radome UNAV, ZEGV's SEPCHOKE_B3E6 SPKE."""
    args = ("rtk", "--base", DATA / "delf0010.21d", "--rover", DATA / "zegv0010.21d", "--nav", DATA / "cbw10010.21n.gz",
            "--json", "-q", "--iono-threshold-km", 100)
    atx = _antex_for_delf_zegv(tmp_path, {"TRM29659.00     NONE": 92.0, "SEPCHOKE_B3E6   SPKE": 95.0})
    r = run_cli(*args, "-o", tmp_path / "a.csv", "--antex", atx)
    assert r.exit_code == 0, r.output
    s = json.loads(r.output[r.output.index("{"):])
    assert s["antennas"] == {"antex": str(atx), "base": "TRM29659.00 NONE", "rover": "SEPCHOKE_B3E6 SPKE"}
    assert any("radome UNAV" in w and "TRM29659.00 NONE is used" in w for w in s["warnings"]), s["warnings"]
    r = run_cli(*args, "-o", tmp_path / "b.csv", "--antex", atx, "--rover-antenna", "none", "--base-antenna",
                "SEPCHOKE_B3E6 SPKE")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output[r.output.index("{"):])["antennas"]["rover"] is None
    # both named none: no model, and the .pos header claims none; "none" without a file is no error
    pos = tmp_path / "n.pos"
    r = run_cli(*args, "-o", pos, "--antex", atx, "--base-antenna", "none", "--rover-antenna", "none")
    assert r.exit_code == 0 and "receiver antenna models" not in pos.read_text(), r.output
    r = run_cli(*args, "-o", tmp_path / "m.pos", "--antex", atx)
    assert r.exit_code == 0 and f"receiver antenna models from {atx}" in (tmp_path / "m.pos").read_text(), r.output
    assert run_cli(*args, "-o", tmp_path / "o.csv", "--rover-antenna", "none").exit_code == 0
    # without a file: a warning that the two antennas differ
    r = run_cli(*args, "-o", tmp_path / "c.csv")
    assert r.exit_code == 0, r.output
    warn = json.loads(r.output[r.output.index("{"):])["warnings"]
    assert any(w.startswith("the antennas differ") and "TRM29659.00 UNAV" in w and "SEPCHOKE_B3E6 SPKE" in w
               and "--antex" in w for w in warn), warn
    # an antenna the file has not, an antenna named without a file, a file that is no ANTEX: exit 2, nothing written
    only = _antex_for_delf_zegv(tmp_path, {"TRM29659.00     NONE": 92.0})
    for extra, words in ((("--antex", only), ("no calibration of", "SEPCHOKE_B3E6 SPKE", "--rover-antenna")),
                         (("--base-antenna", "X"), ("--base-antenna 'X': no --antex file",)),
                         (("--antex", DATA / "delf0010.21d"), ("not an ANTEX file",))):
        out = tmp_path / "bad.csv"
        r = run_cli(*args, "-o", out, *extra)
        text = " ".join(r.output.split())
        assert r.exit_code == 2 and "Traceback" not in r.output and not out.exists(), r.output
        assert all(w in text for w in words), (words, text)


def test_a_u_blox_log_s_own_position_is_named_for_what_gave_it():
    """A u-blox log has no APPROX POSITION XYZ: the warning that the rover's origin moved names its RTCM 1005/1006
    position (a review run of the M8P base log was told of its "APPROX POSITION XYZ")."""
    from cdgps_cli.pipeline.gnss_multi import _origin_moved_note

    x = np.array([3774090.1, -601663.0, 5089319.2])
    ubx = _origin_moved_note("base1.ubx", x, np.array([0.0, 0.0, 8.3]), False, "its static float solution",
                             header_source="RTCM 1005/1006 position")
    assert ubx.startswith("base1.ubx (rover): its RTCM 1005/1006 position is 8.3 m") and "APPROX" not in ubx
    assert "its APPROX POSITION XYZ is" in _origin_moved_note("r.obs", x, np.array([0.0, 0.0, 8.3]), False)


def test_the_rover_is_placed_whatever_rtk_only_options_are_given():
    """The rover's origin is placed by the static engine's float (``gnss_multi._static_float_offset``), which has no
    wet-delay or antenna options: given them (``--tropo-threshold-km``, ``--antex``), it used to refuse, and the
    placement was skipped without a word; rtk's options the engine has not are now left out of what it is given."""
    from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS
    from cdgps_cli.io.rinex import read_rinex_nav
    from cdgps_cli.io.rinex_signals import read_rinex_signals
    from cdgps_cli.pipeline.gnss_multi import _static_float_offset
    from tests._shared import MOSAIC_DIR

    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    nav = read_rinex_nav(MOSAIC_DIR / "base.nav", systems=("G",))
    bx = np.array([-3817681.1213, 3562839.4311, 3650159.1593])
    _, b = read_rinex_signals(MOSAIC_DIR / "base.obs", ["G:L1"])
    h, r = read_rinex_signals(MOSAIC_DIR / "rover.obs", ["G:L1"])
    rx = np.asarray(h["approx_position_xyz_m"], float) + np.array([6.0, 0.0, 0.0])     # an origin 6 m off
    gb, gr = receiver_geometry(b, nav, bx), receiver_geometry(r, nav, rx)
    opt = {**MULTI_GNSS_DEFAULTS, "signals": ("G:L1",), "tropo_threshold_km": 0.0, "antex": "x.atx",
           "rover_antenna": "none"}
    moved, to, _ = _static_float_offset(gb, gr, bx, rx, opt)
    assert to == "its static float solution" and 5.0 < np.linalg.norm(moved) < 7.0, (moved, to)
