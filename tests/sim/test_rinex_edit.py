"""sim/rinex_edit: edits of a real RINEX 3 file change exactly what they say."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex_signals import read_rinex_signals
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, range_change_of_motion
from tests._shared import REPO_ROOT

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
SIGS = ["G:L1", "G:L2", "E:E1", "R:G1"]


@pytest.fixture(scope="module")
def head():
    """The header and first 20 epochs of the real base file (a smaller file for these tests)."""
    lines = (MOSAIC / "base.obs").read_text().splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    out, i = lines[:end], end
    for _ in range(20):
        n = int(lines[i][32:35])
        out += lines[i:i + 1 + n]
        i += 1 + n
    return "\n".join(out) + "\n"


def _read(tmp_path, text, name):
    p = tmp_path / name
    p.write_text(text)
    return read_rinex_signals(p, SIGS)[1]


def test_no_edit_is_the_same_text(head):
    assert edit_rinex3_obs(head) == head


def test_clock_offset_moves_tags_and_every_observation_by_c_delta(tmp_path, head):
    delta = -0.0093
    a = _read(tmp_path, head, "a.obs")
    b = _read(tmp_path, edit_rinex3_obs(head, clock_offset_s=lambda t: delta), "b.obs")
    assert len(a) == len(b)
    np.testing.assert_allclose(b["time_gps_s"] - a["time_gps_s"], delta, atol=1e-6)
    c = 299792458.0
    np.testing.assert_allclose(b["pseudorange_m"] - a["pseudorange_m"], c * delta, atol=1.5e-3)
    # cycles: c·δ/λ on every signal, GLONASS at its own FDMA wavelength
    np.testing.assert_allclose((b["phase_cycles"] - a["phase_cycles"]) * a["wavelength_m"], c * delta, atol=1.5e-3 * 0.25)
    assert (a["signal"] == "R:G1").any()


def test_a_clock_step_in_the_codes_alone(tmp_path, head):
    """code_clock_s: tags unchanged; every range takes its change over δ earlier, −ρ̇ δ with ρ̇ = −λ D from the
    satellite's Doppler (independently: the next epoch's phase change, 1 s, gives ρ̇ to its acceleration, < 1 mm
    over 1 ms); the codes c·δ more."""
    delta = 1e-3
    a = _read(tmp_path, head, "a.obs")
    b = _read(tmp_path, edit_rinex3_obs(head, code_clock_s=lambda t: delta), "b.obs")
    assert len(a) == len(b) and (b["time_gps_s"] == a["time_gps_s"]).all()
    g = (a["signal"] == "G:L1").to_numpy()
    dphi_m = ((b["phase_cycles"] - a["phase_cycles"]) * a["wavelength_m"]).to_numpy()[g]
    dcode = (b["pseudorange_m"] - a["pseudorange_m"]).to_numpy()[g]
    np.testing.assert_allclose(dcode - dphi_m, 299792458.0 * delta, atol=2e-3)       # the codes' step alone
    # the range change over 1 ms against the phases' own rate (one epoch to the next, same satellite)
    t = a["time_gps_s"].to_numpy()[g]
    sat = a["sat"].to_numpy()[g]
    phi = (a["phase_cycles"] * a["wavelength_m"]).to_numpy()[g]
    rate = {}
    for s_ in np.unique(sat):
        k = np.flatnonzero(sat == s_)
        rate[s_] = np.diff(phi[k])[0] / np.diff(t[k])[0]
    expected = np.array([-rate[s_] * delta for s_ in sat])
    np.testing.assert_allclose(dphi_m, expected, atol=3e-3)
    assert np.abs(dphi_m).max() > 0.05                                                # ranges do move (m)


def test_keep_and_motion(tmp_path, head):
    a = _read(tmp_path, head, "a.obs")
    t0 = a["time_gps_s"].min()
    b = _read(tmp_path, edit_rinex3_obs(head, keep=lambda t: round(t - t0) % 3 == 0), "b.obs")
    assert sorted(b["time_gps_s"].unique()) == [t for t in sorted(a["time_gps_s"].unique()) if round(t - t0) % 3 == 0]
    # a constant 1 m rise changes each satellite's range by −sin(el) (to ~1e-5 m)
    from cdgps_cli.io.rinex import read_rinex_nav
    from cdgps_cli.model.gps.orbits import azimuth_elevation, sat_position_ecef, select_ephemeris
    nav = read_rinex_nav(MOSAIC / "base.nav", systems=("G",))
    xyz = np.array([-3817681.1213, 3562839.4311, 3650159.1593])
    m = _read(tmp_path, edit_rinex3_obs(head, range_change_m=range_change_of_motion(nav, xyz, lambda t: (0.0, 0.0, 1.0))), "m.obs")
    g = a["signal"] == "G:L1"
    d_m = (m["phase_cycles"] - a["phase_cycles"])[g].to_numpy() * a["wavelength_m"][g].to_numpy()
    sats, t = a["sat"][g].to_numpy(), a["time_gps_s"][g].to_numpy()
    el = np.array([azimuth_elevation(xyz, sat_position_ecef(select_ephemeris(nav, s, np.array([tt])), np.array([tt]))[0].reshape(3))[1]
                   for s, tt in zip(sats, t)])
    np.testing.assert_allclose(d_m, -np.sin(el).reshape(-1), atol=2e-3)
    np.testing.assert_allclose((m["pseudorange_m"] - a["pseudorange_m"])[g], -np.sin(el).reshape(-1), atol=2e-3)


def test_refuses_rinex2_and_cut_records():
    with pytest.raises(CdgpsError, match="RINEX 3 observation file is needed"):
        edit_rinex3_obs((REPO_ROOT / "tests" / "data" / "07590920.05o").read_text())
    with pytest.raises(CdgpsError, match="the epoch announces"):
        edit_rinex3_obs(("3.04".rjust(9) + " " * 11 + "OBSERVATION DATA".ljust(40) + "RINEX VERSION / TYPE\n"
                         + " " * 60 + "END OF HEADER\n> 2024 06 24 08 20  0.0000000  0  2\nG01\n"))
