"""Multi-signal receiver simulation (cdgps_cli/sim/gnss_signals.py) against its own truth, and the
multi-signal RINEX 3 writer read back by both readers (io/rinex_signals.py, io/rinex.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.core.signals import signal
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.rinex_signals import read_rinex_signals
from cdgps_cli.io.rinex_write import write_rinex_nav, write_rinex_obs_signals
from cdgps_cli.model.gps.orbits import azimuth_elevation, sat_position_ecef, select_ephemeris
from cdgps_cli.model.gps.positioning import synthetic_gps_nav, synthetic_nav
from cdgps_cli.sim.gnss_signals import simulate_receiver_signals

SIGS = ("G:L1", "G:L2", "E:E1", "E:E5a")
X = np.array([-3978242.4, 3382841.2, 3649902.8])
T0 = gps_seconds(2024, 1, 1)


@pytest.fixture(scope="module")
def sim():
    nav = synthetic_nav("GE", T0, 120.0, seed=4)
    return nav, simulate_receiver_signals(nav, X, T0, 60, 2.0, SIGS, seed=9, troposphere=False, clock_drift_ms=0.0)


def test_synthetic_nav_gps_part_is_the_gps_constellation_and_galileo_is_added():
    nav = synthetic_nav(("G", "E"), T0, 600.0, seed=2)
    g = nav[nav["sat"].str[0] == "G"].reset_index(drop=True)
    assert g.equals(synthetic_gps_nav(T0, 600.0, seed=2))
    e = nav[nav["sat"].str[0] == "E"]
    assert e["sat"].nunique() == 24 and np.allclose(e["sqrt_a_sqrt_m"] ** 2, 29_599_800.0)
    xyz, _ = sat_position_ecef(select_ephemeris(e, "E05", np.array([T0])), np.array([T0]))
    assert np.linalg.norm(xyz) == pytest.approx(29_599_800.0, rel=0.013)        # e ≤ 0.012


def test_phases_are_range_plus_integer_per_signal(sim):
    """λ_g(φ_g − N_g − f_g) is the same range on every signal (to the phase noise) and agrees with the
    code; the range is the geometric one of an independent light-time solution (clock 0, no troposphere)."""
    nav, s = sim
    obs, amb = s["obs"], s["ambiguities"].set_index(["signal", "sat"])["n_cycles"]
    assert set(obs["signal"]) == set(SIGS) and set(obs["sat"].str[0]) == {"G", "E"}
    rng = {}
    for g in SIGS:
        o = obs[obs["signal"] == g]
        n = amb.loc[g].reindex(o["sat"]).to_numpy()
        rng[g] = signal(g).wavelength_m * (o["phase_cycles"].to_numpy() - n - s["frac_bias_cycles"][g])
        assert np.all(np.abs(rng[g] - o["pseudorange_m"].to_numpy()) < 3.0)     # 6σ of the code
    for a, b in (("G:L1", "G:L2"), ("E:E1", "E:E5a")):
        d = rng[a] - rng[b]
        assert np.std(d) < 0.02 and abs(np.mean(d)) < 0.005                   # phase noise only
    e1 = obs[obs["signal"] == "E:E1"]
    sel = (e1["sat"] == e1["sat"].iloc[0]).to_numpy()
    for row, r_sim in zip(e1[sel].iloc[:5].itertuples(), rng["E:E1"][sel][:5]):
        eph = select_ephemeris(nav, row.sat, np.array([row.time_gps_s]))
        tau = 0.075
        for _ in range(8):                       # light time, Earth rotation at reception
            xs, clk = sat_position_ecef(eph, np.array([row.time_gps_s - tau]))
            th = 7.2921151467e-5 * tau
            rot = np.array([[math.cos(th), math.sin(th), 0], [-math.sin(th), math.cos(th), 0], [0, 0, 1]]) @ xs[0]
            tau = np.linalg.norm(rot - X) / SPEED_OF_LIGHT_M_S
        assert r_sim == pytest.approx(tau * SPEED_OF_LIGHT_M_S - SPEED_OF_LIGHT_M_S * clk[0], abs=0.08)
        assert azimuth_elevation(X, rot[None, :])[1][0] > math.radians(10.0)


def test_multi_signal_rinex_round_trip(sim, tmp_path):
    nav, s = sim
    obs = s["obs"]
    p = tmp_path / "rx.rnx"
    info = write_rinex_obs_signals(p, obs, SIGS, {"marker_name": "RX", "approx_position_xyz_m": X, "interval_s": 2.0},
                                   created="20240101 000000 UTC")
    assert info["obs_types"] == {"G": ["C1C", "L1C", "S1C", "C2X", "L2X", "S2X"], "E": ["C1C", "L1C", "S1C", "C5Q", "L5Q", "S5Q"]}
    hdr, back = read_rinex_signals(p, SIGS)
    assert len(back) == len(obs)
    m = back.merge(obs, on=["time_gps_s", "sat", "signal"])
    assert len(m) == len(obs)
    assert np.max(np.abs(m["phase_cycles_x"] - m["phase_cycles_y"])) <= 5e-4 + 1e-6
    assert np.max(np.abs(m["pseudorange_m_x"] - m["pseudorange_m_y"])) <= 5e-4 + 1e-6
    assert np.allclose(m["wavelength_m"], [signal(g).wavelength_m for g in m["signal"]])
    # the GPS L1 reader of the ingest takes the same file (Galileo rows counted apart)
    h1, l1 = read_rinex_obs(p)
    ref = obs[obs["signal"] == "G:L1"]
    assert len(l1) == len(ref) and np.allclose(np.sort(l1["phase_l1_cycles"]), np.sort(ref["phase_cycles"]), atol=6e-4)
    # mixed navigation file written and read back with both systems
    write_rinex_nav(tmp_path / "nav.rnx", nav, created="20240101 000000 UTC")
    back_nav = read_rinex_nav(tmp_path / "nav.rnx", systems=("G", "E"))
    assert set(back_nav["sat"].str[0]) == {"G", "E"} and len(back_nav) == len(nav)


def test_beidou_signals_geo_igso_meo_ranges_and_rinex(tmp_path):
    """BeiDou B1I + B2a (synthetic GEO, IGSO and MEO satellites, BDT records): λ_g(φ_g − N_g − f_g) is
    the independent light-time range minus the satellite clock (T_GD of the record) on both signals,
    for a GEO, an IGSO and a MEO satellite; the RINEX 3 file carries C2I/L2I and C5P/L5P and reads back;
    the mixed navigation file gives the BeiDou records back in GPS seconds."""
    sigs = ("G:L1", "C:B1I", "C:B2a")
    nav = synthetic_nav("GC", T0, 120.0, seed=4)
    s = simulate_receiver_signals(nav, X, T0, 30, 2.0, sigs, seed=3, troposphere=False, clock_drift_ms=0.0)
    obs, amb = s["obs"], s["ambiguities"].set_index(["signal", "sat"])["n_cycles"]
    seen = set(obs.loc[obs["signal"] == "C:B1I", "sat"])
    kinds = {"GEO": {f"C{k:02d}" for k in range(1, 6)}, "IGSO": {"C06", "C07", "C08"}}
    kinds["MEO"] = seen - kinds["GEO"] - kinds["IGSO"]
    assert all(seen & v for v in kinds.values()) and len(seen) >= 10        # Japan sees every BeiDou orbit type
    for sat in (min(seen & kinds["GEO"]), min(seen & kinds["IGSO"]), min(kinds["MEO"])):
        for g in ("C:B1I", "C:B2a"):
            o = obs[(obs["signal"] == g) & (obs["sat"] == sat)].iloc[:3]
            r_sim = signal(g).wavelength_m * (o["phase_cycles"].to_numpy() - amb.loc[(g, sat)] - s["frac_bias_cycles"][g])
            for t, r in zip(o["time_gps_s"], r_sim):
                eph = select_ephemeris(nav, sat, np.array([t]))
                tau = 0.12
                for _ in range(8):
                    xs, clk = sat_position_ecef(eph, np.array([t - tau]))
                    th = 7.2921151467e-5 * tau
                    rot = np.array([[math.cos(th), math.sin(th), 0], [-math.sin(th), math.cos(th), 0], [0, 0, 1]]) @ xs[0]
                    tau = np.linalg.norm(rot - X) / SPEED_OF_LIGHT_M_S
                assert r == pytest.approx(tau * SPEED_OF_LIGHT_M_S - SPEED_OF_LIGHT_M_S * clk[0], abs=0.08), (sat, g)
    assert signal("C:B1I").wavelength_m == pytest.approx(SPEED_OF_LIGHT_M_S / 1561.098e6)
    assert signal("C:B2a").wavelength_m == pytest.approx(SPEED_OF_LIGHT_M_S / 1176.45e6)
    info = write_rinex_obs_signals(tmp_path / "rx.rnx", obs, sigs, {"marker_name": "RX", "approx_position_xyz_m": X},
                                   created="20240101 000000 UTC")
    assert info["obs_types"]["C"] == ["C2I", "L2I", "S2I", "C5P", "L5P", "S5P"]
    _, back = read_rinex_signals(tmp_path / "rx.rnx", sigs)
    m = back.merge(obs, on=["time_gps_s", "sat", "signal"])
    assert len(m) == len(obs) == len(back) and np.max(np.abs(m["phase_cycles_x"] - m["phase_cycles_y"])) <= 5e-4 + 1e-6
    write_rinex_nav(tmp_path / "nav.rnx", nav, created="20240101 000000 UTC")
    bn = read_rinex_nav(tmp_path / "nav.rnx", systems=("G", "C"))
    c_in, c_out = (n[n["sat"].str[0] == "C"].sort_values(["sat", "toe_gps_s"]) for n in (nav, bn))
    assert np.array_equal(c_in["toe_gps_s"].to_numpy(), c_out["toe_gps_s"].to_numpy())
