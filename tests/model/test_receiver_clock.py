"""The receiver clock from pseudoranges (positioning.estimate_receiver_clock): one orbit pass moved to the
reception time to first order gives the clock of full passes at every reception time (the brute force
here), on a simulated pair with ms clocks and 30 s steps, and on a real u-blox rover (clock steps)."""

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from cdgps_cli.model.gps.positioning import (
    SPEED_OF_LIGHT_M_S,
    _rate_along_satellites,
    ephemeris_coverage,
    estimate_receiver_clock,
    reception_geometry,
    simulate_static_pair,
    synthetic_gps_nav,
)
from tests._shared import REPO_ROOT

T0 = gps_seconds(2024, 3, 1)
BASE = np.array([-3978242.4348, 3382841.1715, 3649902.7667])
UBLOX = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "ublox-walk"


def _clock_by_full_passes(ep, sats, t, pr, nav, rx, n_epochs, mask_rad=np.radians(10.0), passes=3):
    """Every pass evaluates the orbits at the reception times of the previous pass's clock (the method's
    definition; the median over the satellites above the mask; every epoch here has one)."""
    clk = np.zeros(n_epochs)
    for _ in range(passes):
        g = reception_geometry(nav, sats, t, t - clk[ep], rx)
        res = (pr - (g["range_m"] - SPEED_OF_LIGHT_M_S * g["sat_clock_s"] + g["trop_m"])) / SPEED_OF_LIGHT_M_S
        use = g["el_rad"] > mask_rad
        med = pd.Series(res[use]).groupby(ep[use]).median()
        clk = np.full(n_epochs, np.nan)
        clk[med.index.to_numpy()] = med.to_numpy()
    return clk


@pytest.mark.parametrize("offset_ms", [0.0, 5.0, -1.0])
def test_one_orbit_pass_gives_the_clock_of_full_passes(offset_ms):
    nav = synthetic_gps_nav(T0, 7200.0)
    lat, lon, _ = ecef_to_geodetic(BASE)
    rover = BASE + enu_matrix(lat, lon).T @ np.array([30.0, -20.0, 2.0])
    sim = simulate_static_pair(nav, BASE, rover, T0, 7200.0, 30.0, seed=3, clock_offset_ms=(offset_ms, offset_ms),
                               clock_drift_ms=(-4.0, 5.0))
    o = sim["rover"]
    t = o["time_gps_s"].to_numpy()
    _, ep = np.unique(t, return_inverse=True)
    sats, pr = o["sat"].to_numpy(), o["pseudorange_l1_m"].to_numpy()
    clk = estimate_receiver_clock(ep, sats, t, pr, nav, rover)
    ref = _clock_by_full_passes(ep, sats, t, pr, nav, rover, ep.max() + 1)
    # 30 s steps: rates one-sided at the arcs' ends (≈ 5e-11 s at 5 ms); 1e-10 s moves a satellite by < 0.1 µm
    assert np.abs(clk - ref).max() < 1e-10
    assert np.abs(clk - sim["clock_s"]["rover"]).max() < 5e-9        # and the truth, to the code noise


def test_rate_along_satellites_is_exact_on_a_parabola_where_central_and_one_sided_at_the_ends():
    sats = np.array(["G02", "G01", "G01", "G02", "G01", "G01", "G03", "G02"], dtype=object)
    t = np.array([0.0, 0.0, 1.0, 1.0, 2.0, 5.0, 4.0, 3.0])
    v = np.where(sats == "G01", 3.0 * t**2, -t**2 + 2.0 * t)
    rate = _rate_along_satellites(sats, t, v)
    # G01 at 0, 1, 2, 5: one-sided 3, central 6 (exact), the mean of the slopes 9 and 21, one-sided 21
    np.testing.assert_allclose(rate[[1, 2, 4, 5]], [3.0, 6.0, 15.0, 21.0])
    # G02 at 0, 1, 3: one-sided 1, mean of 1 and -2 is -0.5 (not the derivative 0 at t=1: unequal steps), one-sided -2
    np.testing.assert_allclose(rate[[0, 3, 7]], [1.0, -0.5, -2.0])
    assert rate[6] == 0.0                                        # G03's only row


@pytest.mark.skipif(not UBLOX.exists(), reason="../shared/data/real-pairs absent")
def test_a_real_ublox_rover_gets_the_clock_of_full_passes():
    from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
    nav = read_rinex_nav(UBLOX / "gnss_1730_convbin.nav")
    header, obs = read_rinex_obs(UBLOX / "gnss_1730_convbin.obs")
    o = obs[obs["sat"].str.startswith("G") & np.isfinite(obs["pseudorange_l1_m"].to_numpy())]
    o = o[ephemeris_coverage(nav, o["sat"].to_numpy(), o["time_gps_s"].to_numpy())]
    t = o["time_gps_s"].to_numpy()
    _, ep = np.unique(t, return_inverse=True)
    rx = np.asarray(header["approx_position_xyz_m"], dtype=float)
    sats, pr = o["sat"].to_numpy(), o["pseudorange_l1_m"].to_numpy()
    clk = estimate_receiver_clock(ep, sats, t, pr, nav, rx)
    ref = _clock_by_full_passes(ep, sats, t, pr, nav, rx, ep.max() + 1)
    have = np.isfinite(ref)
    assert have.mean() > 0.95
    assert np.abs(clk[have] - ref[have]).max() < 1e-11          # 4 Hz rows: the rates are central almost everywhere
