"""BeiDou and GLONASS broadcast orbits (issue 14 items 1–2) against independent computations.

* Time scales: BDT and GLONASST against calendar arithmetic.
* BeiDou GEO rotation against the direct product of the ICD's rotation matrices.
* Real broadcast records (MOJN00DNK, 2020-06-25; BRDM00DLR, 2013-01-01): two consecutive records of
  one satellite, each evaluated at the time between them, agree to metres — the orbit algorithm,
  the time scales and GM/ω_e of each system must all be right for that; a BeiDou GEO comes out
  geostationary over its slot (58.75° E for C05); the GEO record through the MEO algorithm does not.
* GLONASS: the integrated state reaches the next record's broadcast state; the integrated velocity
  is the finite difference of the integrated positions; with J₂ and the luni-solar terms off, the
  rotating-frame integration equals an analytic Kepler orbit in the inertial frame.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import bdt_to_gps_s, glonasst_to_gps_s, gps_seconds
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.model.gps import glonass_orbit
from cdgps_cli.model.gps.orbits import (BEIDOU_GEO_TILT_RAD, beidou_geo_rotation, ecef_to_geodetic, sat_position_ecef,
                                        select_ephemeris)
from tests._shared import REPO_ROOT

DATA = REPO_ROOT / "tests" / "data"
MOJN = DATA / "MOJN00DNK_R_20201770000_subset.rnx"
BRDM = DATA / "BRDM00DLR_R_20130010000_01D_MN.rnx"
GLO2 = DATA / "brdc3050_subset.12g"


@pytest.fixture(scope="module")
def nav():
    return read_rinex_nav(MOJN, systems=("G", "C", "R"))


def test_time_scales_against_the_calendar():
    # BDT epoch 2006-01-01 00:00:00 UTC = 00:00:14 GPST (14 leap seconds in 2006)
    assert bdt_to_gps_s(0, 0.0) == gps_seconds(2006, 1, 1, 0, 0, 14)
    assert bdt_to_gps_s(755, 345600.0) == gps_seconds(2020, 6, 25, 0, 0, 14)
    # GLONASST = UTC + 3 h; GPST = UTC + 18 s in 2020
    assert glonasst_to_gps_s(gps_seconds(2020, 6, 25, 3, 15, 0), 18) == gps_seconds(2020, 6, 25, 0, 15, 18)


def test_geo_rotation_is_the_icd_matrix_product():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(7, 3)) * 4e7
    th = rng.uniform(-0.3, 0.3, size=7)
    p = BEIDOU_GEO_TILT_RAD
    rx = np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]])
    want = np.array([np.array([[np.cos(t), np.sin(t), 0], [-np.sin(t), np.cos(t), 0], [0, 0, 1]]) @ rx @ v
                     for t, v in zip(th, x)])
    assert np.allclose(beidou_geo_rotation(x, th), want, rtol=0, atol=1e-6)
    assert np.isclose(np.degrees(BEIDOU_GEO_TILT_RAD), -5.0)


def test_beidou_records_are_dated_in_gps_time(nav):
    r = nav[(nav["sat"] == "C05") & (nav["toe_sow_s"] == 345600)].iloc[0]
    assert r["week"] == 755 and r["toc_gps_s"] == gps_seconds(2020, 6, 25, 0, 0, 14) == r["toe_gps_s"]
    assert r["iode"] == 1 and r["iodc"] == 0 and r["tgd_s"] == pytest.approx(1e-10) and r["sv_health"] == 0
    assert r["transmit_gps_s"] == bdt_to_gps_s(755, 345627.6)


def _midpoint_gap_m(nav, sat):
    recs = nav[nav["sat"] == sat].sort_values("toe_gps_s")
    gaps = []
    for (_, a), (_, b) in zip(recs.iloc[:-1].iterrows(), recs.iloc[1:].iterrows()):
        if b["toe_gps_s"] - a["toe_gps_s"] > 7200:
            continue
        t = 0.5 * (a["toe_gps_s"] + b["toe_gps_s"])
        gaps.append(np.linalg.norm(sat_position_ecef(a, t)[0] - sat_position_ecef(b, t)[0]))
    assert gaps, sat
    return max(gaps)


@pytest.mark.parametrize("sat", ["C05", "C06", "C11", "C20"])
def test_consecutive_beidou_records_agree(nav, sat):
    assert _midpoint_gap_m(nav, sat) < 3.0       # GEO C05, IGSO C06, MEO C11 (BDS-2), C20 (BDS-3): 0.07-0.5 m


def test_beidou_geo_is_geostationary_over_its_slot(nav):
    recs = nav[nav["sat"] == "C05"]
    r = recs.iloc[0]
    t = r["toe_gps_s"] + np.arange(-3600.0, 3601.0, 600.0)
    xyz, _ = sat_position_ecef(r, t)
    lat, lon, h = ecef_to_geodetic(xyz)
    assert np.all(np.abs(np.linalg.norm(xyz, axis=1) - 42164e3) < 100e3)
    assert np.all(np.abs(np.degrees(lat)) < 2.0) and np.all(np.abs(np.degrees(lon) - 58.75) < 1.0)
    assert np.ptp(xyz, axis=0).max() < 200e3       # a ~1.5° inclined GEO: tens of km in 2 h (a MEO: 10⁴ km)
    as_meo = r.copy()
    as_meo["sat"] = "C30"                                         # the same elements through the MEO algorithm
    assert np.linalg.norm(sat_position_ecef(as_meo, t)[0] - xyz, axis=1).min() > 1000e3


def test_glonass_records_are_read_in_si_units_and_gps_time(nav):
    r = nav[(nav["sat"] == "R01")].iloc[0]
    assert r["toe_gps_s"] == gps_seconds(2020, 6, 25, 0, 15, 18) == r["toc_gps_s"]
    assert r["x_m"] == pytest.approx(1.682726318359e7) and r["vy_m_per_s"] == pytest.approx(1820.017814636)
    assert r["ay_m_per_s2"] == pytest.approx(9.313225746155e-7) and r["glonass_k"] == 1 and r["sv_health"] == 0
    assert r["af0_s"] == pytest.approx(6.356183439493e-05) and np.isnan(r["sqrt_a_sqrt_m"])
    assert r["transmit_gps_s"] == gps_seconds(2020, 6, 25, 0, 0, 18)       # frame time 345600 s of the UTC week


@pytest.mark.parametrize("path,sats", [(MOJN, ["R01", "R02", "R08"]), (BRDM, ["R01", "R02"]), (GLO2, ["R03", "R04"])])
def test_glonass_integration_reaches_the_next_record(path, sats):
    nav = read_rinex_nav(path, systems=("R",))
    for sat in sats:
        recs = nav[nav["sat"] == sat].sort_values("toe_gps_s")
        a, b = recs.iloc[0], recs.iloc[1]
        assert b["toe_gps_s"] - a["toe_gps_s"] == 1800
        end = glonass_orbit.glonass_position(a[["x_m", "y_m", "z_m", "vx_m_per_s", "vy_m_per_s", "vz_m_per_s"]].to_numpy(float)[None],
                                             a[["ax_m_per_s2", "ay_m_per_s2", "az_m_per_s2"]].to_numpy(float)[None], [1800.0])[0]
        want = b[["x_m", "y_m", "z_m", "vx_m_per_s", "vy_m_per_s", "vz_m_per_s"]].to_numpy(float)
        assert np.linalg.norm(end[:3] - want[:3]) < 10.0, sat        # 30 min of integration: 0.4-3.7 m
        assert np.linalg.norm(end[3:] - want[3:]) < 0.02, sat
        assert _midpoint_gap_m(nav, sat) < 3.0, sat                      # 15 min each way: 0.5-1.3 m


def test_glonass_velocity_is_the_derivative_of_the_position(nav):
    r = nav[nav["sat"] == "R02"].iloc[0]
    s0 = r[["x_m", "y_m", "z_m", "vx_m_per_s", "vy_m_per_s", "vz_m_per_s"]].to_numpy(float)[None].repeat(3, 0)
    acc = r[["ax_m_per_s2", "ay_m_per_s2", "az_m_per_s2"]].to_numpy(float)[None].repeat(3, 0)
    s = glonass_orbit.glonass_position(s0, acc, [600.0 - 0.5, 600.0, 600.0 + 0.5], max_step_s=10.0)
    assert np.abs((s[2, :3] - s[0, :3]) / 1.0 - s[1, 3:]).max() < 1e-4


def _kepler(r0, v0, dt, gm):
    """Analytic two-body propagation (classical elements), inertial frame."""
    h = np.cross(r0, v0)
    r = np.linalg.norm(r0)
    evec = np.cross(v0, h) / gm - r0 / r
    e = np.linalg.norm(evec)
    a = 1.0 / (2.0 / r - v0 @ v0 / gm)
    p_hat = evec / e
    q_hat = np.cross(h, p_hat) / np.linalg.norm(h)
    cos_e0 = (1 - r / a) / e
    sin_e0 = (r0 @ v0) / (e * np.sqrt(gm * a))
    e0 = np.arctan2(sin_e0, cos_e0)
    m = e0 - e * np.sin(e0) + np.sqrt(gm / a**3) * dt
    big = m
    for _ in range(50):
        big = big - (big - e * np.sin(big) - m) / (1 - e * np.cos(big))
    return a * (np.cos(big) - e) * p_hat + a * np.sqrt(1 - e * e) * np.sin(big) * q_hat


def test_rotating_frame_integration_equals_an_inertial_kepler_orbit(monkeypatch, nav):
    monkeypatch.setattr(glonass_orbit, "J2_GLONASS", 0.0)
    r = nav[nav["sat"] == "R01"].iloc[0]
    s0 = r[["x_m", "y_m", "z_m", "vx_m_per_s", "vy_m_per_s", "vz_m_per_s"]].to_numpy(float)
    w = glonass_orbit.OMEGA_E_GLONASS
    v_in = s0[3:] + np.cross([0.0, 0.0, w], s0[:3])
    for dt in (-900.0, 450.0, 1800.0):
        got = glonass_orbit.glonass_position(s0[None], np.zeros((1, 3)), [dt])[0, :3]
        ri = _kepler(s0[:3], v_in, dt, glonass_orbit.GM_GLONASS)
        th = w * dt
        want = np.array([[np.cos(th), np.sin(th), 0], [-np.sin(th), np.cos(th), 0], [0, 0, 1]]) @ ri
        assert np.linalg.norm(got - want) < 1e-3, dt


def test_glonass_selection_window_and_mixed_tables(nav):
    t0 = gps_seconds(2020, 6, 25, 0, 30, 18)
    assert select_ephemeris(nav, "R01", t0)["toe_gps_s"] in (t0 - 900, t0 + 900)
    with pytest.raises(CdgpsError, match=r"within ±0.5 h"):
        select_ephemeris(nav[nav["sat"] == "R01"].iloc[:1], "R01", t0 + 3600)
    # a table with GPS, BeiDou and GLONASS rows: each row by its own algorithm
    rows = pd.concat([nav[nav["sat"] == s].iloc[:1] for s in ("G05", "C05", "R01", "C11")], ignore_index=True)
    t = rows["toe_gps_s"].to_numpy() + 60.0
    xyz, clk = sat_position_ecef(rows, t)
    for k in range(len(rows)):
        x1, c1 = sat_position_ecef(rows.iloc[k], t[k])
        assert np.allclose(xyz[k], x1, atol=1e-6) and np.isclose(clk[k], c1, atol=1e-15)


def test_a_real_receivers_pseudoranges_are_explained():
    """ESBC00DNK (Septentrio PolaRx5, 2020-06-25 00:30–00:31 GPST, 3 epochs) against the MOJN broadcast
    records of the same day: after the satellite clock (TGD applied), a hydrostatic troposphere and one
    receiver clock per signal, the pseudorange residuals are metres (ionosphere, multipath) for GPS,
    BeiDou — the GEO C05 included — and GLONASS, and the receiver clocks of the three systems agree
    to tens of nanoseconds: a wrong time scale (BDT's 14 s, GLONASS's UTC), GEO rotation or orbit
    integration would leave kilometres."""
    from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
    from cdgps_cli.io.rinex_signals import read_rinex_signals
    from cdgps_cli.model.gps.orbits import azimuth_elevation, sat_position_at_reception
    from cdgps_cli.model.gps.positioning import tropo_hydrostatic_m

    nav = read_rinex_nav(MOJN, systems=("G", "C", "R"))
    hdr, obs = read_rinex_signals(DATA / "ESBC00DNK_R_20201770000_subset.rnx", ["G:L1", "C:B1I", "R:G1"])
    rx = np.array(hdr["approx_position_xyz_m"])
    lat, _, h = ecef_to_geodetic(rx)
    rows = []
    for (sat, sig), g in obs.groupby(["sat", "signal"]):
        t = g["time_gps_s"].to_numpy()
        if not (nav["sat"] == sat).any():
            continue
        geo = sat_position_at_reception(nav, sat, t, rx)
        _, el = azimuth_elevation(rx, geo.xyz_m)
        if el.min() < np.radians(3.0):
            continue
        res = g["pseudorange_m"].to_numpy() - geo.range_m + SPEED_OF_LIGHT_M_S * geo.clock_s - tropo_hydrostatic_m(el, lat, h, t)
        rows.append(pd.DataFrame({"sat": sat, "signal": sig, "t": t, "res": res}))
    df = pd.concat(rows, ignore_index=True)
    df["clock_m"] = df.groupby(["signal", "t"])["res"].transform("median")
    df["r"] = df["res"] - df["clock_m"]
    per = df.groupby("signal").agg(sats=("sat", "nunique"), rms=("r", lambda x: float(np.sqrt(np.mean(x**2)))),
                                   worst=("r", lambda x: float(np.abs(x).max())), clock_m=("clock_m", "mean"))
    assert (per["sats"] >= 7).all() and (per["rms"] < 2.5).all() and (per["worst"] < 5.0).all(), per
    assert np.ptp(per["clock_m"]) / SPEED_OF_LIGHT_M_S < 50e-9, per          # one receiver clock (ISB ~ 24 ns)
    assert "C05" in set(df["sat"]) and np.abs(df.loc[df["sat"] == "C05", "r"]).max() < 5.0


@pytest.mark.parametrize("sat", ["C05", "C07", "C11", "C20", "G05"])
def test_broadcast_positions_obey_the_equations_of_motion(nav, sat):
    """Brute force: the state at t₀ (broadcast position, velocity by central finite differences over
    ±0.5 s) integrated 15 min in the Earth-fixed frame (central term, J₂, centrifugal, Coriolis; the
    GLONASS integrator, luni-solar terms off) lands within metres of the broadcast position at
    t₀ + 15 min (measured 0.9–2.9 m; the GEO rotations applied in the other order: 6.9 km)."""
    r = nav[nav["sat"] == sat].iloc[0]
    t0 = r["toe_gps_s"] - 450.0
    x, _ = sat_position_ecef(r, np.array([t0 - 0.5, t0, t0 + 0.5]))
    state = np.r_[x[1], x[2] - x[0]][None]
    end = glonass_orbit.glonass_position(state, np.zeros((1, 3)), [900.0], max_step_s=10.0)[0]
    assert np.linalg.norm(end[:3] - sat_position_ecef(r, t0 + 900.0)[0]) < 5.0


def test_each_glonass_record_takes_its_own_steps():
    """A record's integration depends on its own time alone (issue 29: a window of a record gives the whole
    record's values): with records far from t_b beside it, a record near t_b gives the bits it gives alone, and a
    time that is not finite gives NaN (it raised before) without touching the others."""
    s0 = np.array([[1.9e7, 1.1e7, 4.0e6, 150.0, 2100.0, -2900.0]])
    acc = np.array([[1e-7, -2e-7, 3e-7]])
    dts = np.array([12.0, -900.0, 1795.0, np.nan, 61.0])
    together = glonass_orbit.glonass_position(np.repeat(s0, dts.size, 0), np.repeat(acc, dts.size, 0), dts)
    for i, dt in enumerate(dts):
        alone = glonass_orbit.glonass_position(s0, acc, [dt])[0]
        assert together[i].tobytes() == alone.tobytes()
    assert np.isnan(together[3]).all() and np.isfinite(np.delete(together, 3, 0)).all()
