"""The synthetic BeiDou constellation of the simulators (model/gps/positioning.synthetic_beidou_nav).

Independent checks: the broadcast records, evaluated by the ICD's user algorithms of
model/gps/orbits.py (GEO: the −5° tilt and Earth rotation), give orbits that obey the two-body
equations of motion in an inertial frame (second central difference of the de-rotated positions
against −GM·r/|r|³, the acceleration computed here from CGCS2000's GM); GEO satellites stay over
their slots; IGSO ground tracks cross the equator at the stated longitude; neighbouring records give
the same position (no jump); record times are whole BDT hours (BDT = GPST − 14 s) written with the
BDT week; RINEX navigation files written with them (and with real BeiDou records) read back equal.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.rinex_write import write_rinex_nav
from cdgps_cli.model.gps.orbits import GM_BEIDOU, OMEGA_E_BEIDOU, ecef_to_geodetic, sat_position_ecef, select_ephemeris
from cdgps_cli.model.gps.positioning import (
    SYNTHETIC_BEIDOU_GEO_LON_DEG,
    SYNTHETIC_BEIDOU_IGSO,
    synthetic_beidou_nav,
    synthetic_nav,
)

T0 = gps_seconds(2024, 1, 1)
MOJN = Path(__file__).resolve().parents[1] / "data" / "MOJN00DNK_R_20201770000_subset.rnx"


@pytest.fixture(scope="module")
def nav():
    return synthetic_beidou_nav(T0, 6 * 3600.0, seed=5)


def _position(nav, sat, t):
    t = np.atleast_1d(np.asarray(t, float))
    return sat_position_ecef(select_ephemeris(nav, sat, t), t)[0]


def _inertial(xyz, t):
    """De-rotate ECEF positions by ω_e·(t − T0) about Z (an inertial frame, up to a constant rotation)."""
    th = OMEGA_E_BEIDOU * (np.asarray(t) - T0)
    c, s = np.cos(th), np.sin(th)
    return np.stack([c * xyz[:, 0] - s * xyz[:, 1], s * xyz[:, 0] + c * xyz[:, 1], xyz[:, 2]], axis=-1)


def test_constellation_shape(nav):
    sats = sorted(nav["sat"].unique())
    assert sats[:8] == [f"C{k:02d}" for k in range(1, 9)] and sats[8:] == [f"C{k:02d}" for k in range(19, 43)]
    a = nav.groupby("sat")["sqrt_a_sqrt_m"].first() ** 2
    a_gso = (GM_BEIDOU / OMEGA_E_BEIDOU**2) ** (1 / 3)                  # 42 164 km: n = ω_e
    assert np.allclose(a[sats[:8]], a_gso) and a_gso == pytest.approx(42_164_170.0, abs=200.0)
    assert np.allclose(a[sats[8:]], 27_906_100.0)


@pytest.mark.parametrize("sat", ["C01", "C04", "C07", "C25"])
def test_orbits_obey_two_body_motion(nav, sat):
    """ẍ = −GM r/|r|³ in the inertial frame, at times inside a record and across a record change.
    The MEO/IGSO orbits have a slow node regression (Ω̇ = −8e-9 rad/s), the GEOs none: their residual
    acceleration is 2ω_e·Ω̇·r-sized (< 6e-5 m/s²) and ~1e-8 m/s² respectively (of 0.22–0.51 m/s²)."""
    h = 20.0
    for t_mid in (T0 + 1000.0, T0 + 3600.0 + 14.0, T0 + 2 * 3600.0 + 14.0):      # 2nd, 3rd: at a record change
        t = t_mid + np.array([-h, 0.0, h])
        x = _inertial(_position(nav, sat, t), t)
        acc = (x[0] - 2 * x[1] + x[2]) / h**2
        g = -GM_BEIDOU * x[1] / np.linalg.norm(x[1]) ** 3
        tol = 1e-7 if int(sat[1:]) <= 5 else 6e-5
        assert np.linalg.norm(acc - g) < tol, (sat, t_mid, np.linalg.norm(acc - g))


def test_neighbouring_records_agree(nav):
    for sat, recs in nav.groupby("sat"):
        recs = recs.reset_index(drop=True)
        for i in range(len(recs) - 1):
            tm = 0.5 * (recs["toe_gps_s"][i] + recs["toe_gps_s"][i + 1])
            a, _ = sat_position_ecef(recs.iloc[i], tm)
            b, _ = sat_position_ecef(recs.iloc[i + 1], tm)
            assert np.linalg.norm(a - b) < 1e-3, (sat, i)


def test_geo_satellites_stay_over_their_slots(nav):
    t = T0 + np.arange(0.0, 6 * 3600.0, 300.0)
    for k, lon_slot in enumerate(SYNTHETIC_BEIDOU_GEO_LON_DEG):
        lat, lon, h = ecef_to_geodetic(_position(nav, f"C{k + 1:02d}", t))
        assert np.all(np.abs(np.degrees(lat)) < 1.6)                         # physical inclination ≤ 1.5°
        assert np.all(np.abs(np.degrees(lon) - lon_slot) < 0.5)              # e ≤ 0.001: ≤ 2e rad of drift
        assert np.all(np.abs(h - 35_786e3) < 60e3)


def test_the_same_elements_through_the_meo_algorithm_are_not_geostationary(nav):
    """The records are GEO records: renamed to a MEO PRN they land thousands of km away."""
    rec = nav[nav["sat"] == "C02"].iloc[1].copy()
    t = float(rec["toe_gps_s"]) + 600.0
    geo, _ = sat_position_ecef(rec, t)
    rec["sat"] = "C30"
    meo, _ = sat_position_ecef(rec, t)
    assert np.linalg.norm(geo - meo) > 1000e3


def test_igso_ground_track_crosses_the_equator_at_its_longitude(nav):
    lon_x, inc_deg, n = SYNTHETIC_BEIDOU_IGSO
    t = T0 + np.arange(0.0, 6 * 3600.0, 10.0)
    for k in range(n):
        sat = f"C{len(SYNTHETIC_BEIDOU_GEO_LON_DEG) + k + 1:02d}"
        lat, lon, _ = ecef_to_geodetic(_position(nav, sat, t))
        assert np.degrees(np.abs(lat)).max() < inc_deg + 0.5
        up = np.flatnonzero((lat[:-1] < 0) & (lat[1:] >= 0))
        for i in up:                                                          # ascending node crossings
            assert abs(math.degrees(lon[i]) - lon_x) < 1.0


def test_record_times_are_whole_bdt_hours_with_the_bdt_week(nav):
    toe_bdt = nav["toe_gps_s"].to_numpy() - 14.0
    assert np.all(np.mod(toe_bdt, 7200.0) == 0.0) and np.array_equal(nav["toc_gps_s"], nav["toe_gps_s"])
    week = nav["week"].to_numpy()
    assert np.array_equal((week + 1356) * 604800.0 + nav["toe_sow_s"].to_numpy() + 14.0, nav["toe_gps_s"].to_numpy())
    assert set(week) == {939}                                                 # 2024-01-01: GPS week 2295 − 1356
    assert nav["iode"].max() < 32 and (nav["codes_l2"] == -1).all()


def test_deterministic_and_part_of_synthetic_nav():
    a = synthetic_nav("GEC", T0, 3600.0, seed=7)
    b = synthetic_nav(["C", "G", "E"], T0, 3600.0, seed=7)
    assert a.equals(b)
    assert a[a["sat"].str[0] == "C"].reset_index(drop=True).equals(synthetic_beidou_nav(T0, 3600.0, seed=9))


@pytest.mark.parametrize("source", ["synthetic", "MOJN00DNK"])
def test_beidou_records_round_trip_through_a_rinex_navigation_file(tmp_path, nav, source):
    """toc is written in BDT, AODC in the fit-interval slot (RINEX 3.04 Table A14), and the reader gives
    back the same record (real records: the MOJN00DNK 2020-06-25 BeiDou records of tests/data)."""
    src = nav if source == "synthetic" else read_rinex_nav(MOJN, systems=("C",))
    write_rinex_nav(tmp_path / "nav.rnx", src, created="20240101 000000 UTC")
    back = read_rinex_nav(tmp_path / "nav.rnx", systems=("C",))
    assert len(back) == len(src)
    m = src.merge(back, on=["sat", "toe_gps_s"], suffixes=("", "_b"))
    assert len(m) == len(src)
    for c in ("toc_gps_s", "transmit_gps_s", "week", "toe_sow_s", "iode", "iodc", "sv_health"):
        assert np.array_equal(m[c].to_numpy(float), m[c + "_b"].to_numpy(float)), c
    for c in ("af0_s", "omega0_rad", "i0_rad", "m0_rad", "sqrt_a_sqrt_m", "tgd_s"):
        assert np.allclose(m[c], m[c + "_b"], rtol=1e-12, atol=1e-24), c
    t = m["toe_gps_s"].to_numpy() + 900.0
    xa, ca = sat_position_ecef(m[src.columns], t)
    xb, cb = sat_position_ecef(m[[c + "_b" if c + "_b" in m else c for c in src.columns]].set_axis(src.columns, axis=1), t)
    assert np.abs(xa - xb).max() < 1e-3 and np.abs(ca - cb).max() < 1e-15
    first = next(ln for ln in (tmp_path / "nav.rnx").read_text().splitlines() if ln.startswith(str(src["sat"].iloc[0])))
    y, mo, d, hh, mi, ss = (int(first[a:b]) for a, b in ((4, 8), (9, 11), (12, 14), (15, 17), (18, 20), (21, 23)))
    assert gps_seconds(y, mo, d, hh, mi, ss) + 14.0 == src.sort_values(["sat", "toc_gps_s"])["toc_gps_s"].iloc[0]
