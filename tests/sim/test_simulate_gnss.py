"""RINEX 3 writers (cdgps_cli.io.rinex_write), the synthetic constellation and `cdgps simulate-gnss`.

Round trips through our own readers: observation tables (phase, code, C/N0, LLI, SSI, epoch flags,
clock offsets) and navigation tables (every ephemeris field) come back as written.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.cli.commands import main
from cdgps_cli.model.gps.orbits import azimuth_elevation, sat_position_ecef
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.gps.positioning import simulate_static_pair, synthetic_gps_nav
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.core.records import NAV_COLUMNS
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.rinex_write import write_rinex_nav, write_rinex_obs

DATA = Path(__file__).resolve().parents[1] / "data"
MASTER = np.array([-3978242.4348, 3382841.1715, 3649902.7667])
ROVER = np.array([-3976219.5082, 3382372.5671, 3652512.9849])
T0 = gps_seconds(2005, 4, 2)


@pytest.fixture(scope="module")
def nav():
    return read_rinex_nav(DATA / "07590920.05n")


@pytest.fixture(scope="module")
def sim(nav):
    return simulate_static_pair(nav, MASTER, ROVER, T0, 300.0, 1.0, seed=3, slips=[("rover", "G07", T0 + 100, 5)])


def test_obs_round_trip(sim, tmp_path):
    obs = sim["rover"].copy()
    obs.loc[obs.index[::7], "snr_l1_dbhz"] = 44.25
    obs.loc[obs.index[5], "lli_l1"] = 3
    obs.loc[obs.index[9], "pseudorange_l1_m"] = np.nan
    obs.loc[obs.index[11], "phase_l1_cycles"] = np.nan              # code only: kept, no flags
    obs.loc[obs["time_gps_s"] == obs["time_gps_s"].iloc[40], "rx_clock_offset_s"] = 1.25e-4
    obs.loc[obs["time_gps_s"] == obs["time_gps_s"].iloc[80], "epoch_flag"] = 1
    hdr = {"marker_name": "ROV", "receiver_type": "SIM RX", "approx_position_xyz_m": ROVER, "interval_s": 1.0,
           "antenna_delta_hen_m": (0.1, 0.0, 0.0), "comments": ["a comment"]}
    info = write_rinex_obs(tmp_path / "r.rnx", obs, hdr, created="20050402 000000 UTC")
    assert info["epochs"] == obs["time_gps_s"].nunique() and info["records"] == len(obs)
    h, back = read_rinex_obs(tmp_path / "r.rnx")
    assert h["version"] == 3.04 and h["marker_name"] == "ROV" and h["receiver_type"] == "SIM RX"
    np.testing.assert_allclose(h["approx_position_xyz_m"], ROVER, atol=1e-4)
    assert h["antenna_delta_hen_m"] == (0.1, 0.0, 0.0) and h["interval_s"] == 1.0 and "a comment" in h["comments"]
    assert h["l1_obs_types"] == {"phase": "L1C", "pseudorange": "C1C", "snr": "S1C"}
    assert len(back) == len(obs)
    o = obs.sort_values(["time_gps_s", "sat"]).reset_index(drop=True)
    np.testing.assert_array_equal(back["sat"].to_numpy(), o["sat"].to_numpy())
    np.testing.assert_allclose(back["time_gps_s"], o["time_gps_s"], atol=1e-7, rtol=0)
    np.testing.assert_allclose(back["phase_l1_cycles"], o["phase_l1_cycles"], atol=5e-4, rtol=0)   # F14.3
    np.testing.assert_allclose(back["pseudorange_l1_m"], o["pseudorange_l1_m"], atol=5e-4, rtol=0)
    np.testing.assert_allclose(back["snr_l1_dbhz"], o["snr_l1_dbhz"], atol=5e-4, rtol=0)
    np.testing.assert_array_equal(back["lli_l1"], np.where(np.isnan(o["phase_l1_cycles"]), 0, o["lli_l1"]))
    np.testing.assert_array_equal(back["epoch_flag"], o["epoch_flag"])
    np.testing.assert_allclose(back["rx_clock_offset_s"], o["rx_clock_offset_s"], atol=1e-12)
    # a signal-strength digit from C/N0 where none was given
    assert set(back.loc[back["snr_l1_dbhz"] == 44.25, "ssi_l1"]) == {7}


def test_nav_round_trip_is_exact(nav, tmp_path):
    write_rinex_nav(tmp_path / "n.rnx", nav, leap_seconds=13, comments=["copy"])
    back = read_rinex_nav(tmp_path / "n.rnx")
    assert back.attrs["leap_seconds"] == 13 and back.attrs["version"] == 3.04
    assert len(back) == len(nav)
    for c in NAV_COLUMNS:
        if c == "line":
            continue
        a, b = back[c].to_numpy(), nav[c].to_numpy()
        if a.dtype.kind in "fi":
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0, err_msg=c)
        else:
            np.testing.assert_array_equal(a, b, err_msg=c)


def test_writer_errors(sim, tmp_path):
    with pytest.raises(CdgpsError, match="no observations"):
        write_rinex_obs(tmp_path / "x.rnx", sim["rover"].iloc[:0])
    bad = sim["rover"].iloc[:3].copy()
    bad["sat"] = "R05"
    with pytest.raises(CdgpsError, match="only GPS satellites"):
        write_rinex_obs(tmp_path / "x.rnx", bad)
    big = sim["rover"].iloc[:3].copy()
    big["phase_l1_cycles"] = 2e10
    with pytest.raises(CdgpsError, match="too large"):
        write_rinex_obs(tmp_path / "x.rnx", big)
    assert not list(tmp_path.iterdir())                         # nothing left behind


def test_synthetic_constellation_is_continuous_and_visible(tmp_path):
    t0 = gps_seconds(2024, 1, 1)
    nav = synthetic_gps_nav(t0, 6 * 3600.0)
    assert nav["sat"].nunique() == 36 and (nav["sv_health"] == 0).all()
    # consecutive records of a satellite describe the same orbit and clock (1 mm, 1 ps)
    for s in ("G01", "G20"):
        g = nav[nav["sat"] == s].reset_index(drop=True)
        for k in range(len(g) - 1):
            tb = g["toe_gps_s"][k] + 3600.0
            x1, c1 = sat_position_ecef(g.iloc[k], tb)
            x2, c2 = sat_position_ecef(g.iloc[k + 1], tb)
            assert np.linalg.norm(x1 - x2) < 1e-3 and abs(c1 - c2) < 1e-12
    # at least 5 satellites above 15° at a mid-latitude site all the time
    for t in t0 + np.arange(0, 6 * 3600, 900):
        sel = nav[(nav["toe_gps_s"] - t > -3600) & (nav["toe_gps_s"] - t <= 3600)]
        x, _ = sat_position_ecef(sel, np.full(len(sel), t))
        assert (azimuth_elevation(MASTER, x)[1] > math.radians(15)).sum() >= 5
    # round trip through the writer and reader
    write_rinex_nav(tmp_path / "syn.rnx", nav)
    back = read_rinex_nav(tmp_path / "syn.rnx")
    np.testing.assert_allclose(back["m0_rad"], nav["m0_rad"], rtol=1e-12)


def test_moving_rover_option(nav):
    off = np.zeros((11, 3))
    off[:, 2] = np.linspace(0, 1.0, 11)                          # 1 m up over the span
    a = simulate_static_pair(nav, MASTER, ROVER, T0, 11.0, 1.0, seed=1, phase_sigma_m=0, code_sigma_m=0)
    b = simulate_static_pair(nav, MASTER, ROVER, T0, 11.0, 1.0, seed=1, phase_sigma_m=0, code_sigma_m=0,
                             rover_offset_enu_m=off)
    d = (b["rover"]["pseudorange_l1_m"] - a["rover"]["pseudorange_l1_m"]).to_numpy()
    first = (b["rover"]["time_gps_s"] < T0 + 0.5).to_numpy()
    assert np.allclose(d[first], 0, atol=1e-6) and np.all(d[~first] < 0)       # moving up shortens the ranges
    with pytest.raises(ValueError, match="shape"):
        simulate_static_pair(nav, MASTER, ROVER, T0, 11.0, 1.0, rover_offset_enu_m=off[:3])


def test_simulate_gnss_command_files_truth_and_determinism(tmp_path):
    args = ["-q", "simulate-gnss", "--duration", "120", "--rate-hz", "1", "--seed", "4", "--slips", "2",
            "--displacement", "0.01,0.02,-0.03"]
    r = CliRunner().invoke(main, args + ["--out", str(tmp_path / "a"), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["epochs"] == 120 and s["displacement_model"] == "static"
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == ["base.rnx", "config.toml", "nav.rnx", "rover.rnx", "truth.csv", "truth.json"]
    truth = pd.read_csv(tmp_path / "a" / "truth.csv")
    assert list(truth.columns) == ["time_s", "rover_e_m", "rover_n_m", "rover_u_m"] and len(truth) == 120
    assert np.allclose(truth[["rover_e_m", "rover_n_m", "rover_u_m"]].to_numpy(), [0.01, 0.02, -0.03])
    tj = json.loads((tmp_path / "a" / "truth.json").read_text())
    assert tj["rover"] == "rover" and tj["displacement_enu_m"] == [0.01, 0.02, -0.03] and tj["ambiguities"]
    h, o = read_rinex_obs(tmp_path / "a" / "rover.rnx")
    np.testing.assert_allclose(h["approx_position_xyz_m"], ROVER, atol=1e-4)   # the NOMINAL position
    r2 = CliRunner().invoke(main, args + ["--out", str(tmp_path / "b")])
    assert r2.exit_code == 0, r2.output
    for f in files:                                             # same seed → identical files
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    # a random walk; real navigation data outside their span → clear error, exit 2
    r3 = CliRunner().invoke(main, ["-q", "simulate-gnss", "--duration", "60", "--random-walk", "0.001",
                                   "--out", str(tmp_path / "c")])
    assert r3.exit_code == 0, r3.output
    t3 = pd.read_csv(tmp_path / "c" / "truth.csv")
    assert t3["rover_u_m"].std() > 0 and "random_walk" in (tmp_path / "c" / "config.toml").read_text()
    r4 = CliRunner().invoke(main, ["simulate-gnss", "--nav", str(DATA / "07590920.05n"), "--start", "2010-01-01",
                                   "--out", str(tmp_path / "d")])
    assert r4.exit_code == 2 and "do not cover" in r4.stderr and not (tmp_path / "d").exists()


def test_noise_follows_the_elevation_model_and_cn0_is_simulated(nav, tmp_path):
    kw = dict(seed=5, code_sigma_m=0.0)
    a = simulate_static_pair(nav, MASTER, ROVER, T0, 600.0, 1.0, phase_sigma_m=0.0, **kw)
    b = simulate_static_pair(nav, MASTER, ROVER, T0, 600.0, 1.0, phase_sigma_m=(0.003, 0.003), **kw)
    for rx in ("base", "rover"):
        snr = b[rx]["snr_l1_dbhz"].to_numpy()
        np.testing.assert_array_equal(snr, a[rx]["snr_l1_dbhz"].to_numpy())       # deterministic, noise-free
        sin_el = (snr - 35.0) / 15.0                                               # C/N0 = 35 + 15 sin(el)
        assert 35 < snr.min() and snr.max() < 50 and sin_el.min() < 0.3 and sin_el.max() > 0.8
        eps = (b[rx]["phase_l1_cycles"] - a[rx]["phase_l1_cycles"]).to_numpy() * GPS_L1_WAVELENGTH_M
        z = eps / np.sqrt(0.003**2 + 0.003**2 / sin_el**2)                        # σ² = a² + b²/sin²el
        assert abs(np.std(z) - 1.0) < 0.05 and abs(np.mean(z)) < 0.05
        low = sin_el < 0.5
        assert np.std(eps[low]) > 1.5 * np.std(eps[~low])                         # noisier at low elevation
    # written as S1C with the signal-strength digit derived from it, read back
    write_rinex_obs(tmp_path / "b.rnx", b["rover"], {"marker_name": "R"}, created="20050402 000000 UTC")
    _, back = read_rinex_obs(tmp_path / "b.rnx")
    o = b["rover"].sort_values(["time_gps_s", "sat"]).reset_index(drop=True)
    np.testing.assert_allclose(back["snr_l1_dbhz"], o["snr_l1_dbhz"], atol=5e-4, rtol=0)
    np.testing.assert_array_equal(back["ssi_l1"], np.floor(o["snr_l1_dbhz"] / 6.0).astype(int))


def _gnss_sim(tmp_path, name, **kw):
    from cdgps_cli.sim.gnss import simulate_gnss_pair

    s = simulate_gnss_pair(tmp_path / name, **kw)
    return s, json.loads((tmp_path / name / "truth.json").read_text())


def test_requested_slips_are_all_simulated_on_tracked_satellites(tmp_path):
    # the reviewer's case (`--slips 5 --seed 7 --duration 1800 --random-walk 0.0005` gave 2 slips)
    s, tj = _gnss_sim(tmp_path, "a", duration_s=1800.0, seed=7, n_slips=5, random_walk_sigma=0.0005)
    assert s["slips"] == s["slips_requested"] == 5 and len(tj["cycle_slips"]) == 5 and "slips_note" not in tj
    assert sum(a["kind"] == "slip" for a in tj["ambiguities"]) == 5 and tj["slip_mask_deg"] == 15.0
    obs = {n: read_rinex_obs(tmp_path / "a" / f"{n}.rnx")[1] for n in ("base", "rover")}
    t0 = tj["start_gps_s"]
    for sl in tj["cycle_slips"]:
        assert sl["elevation_deg"] > 15.0 and t0 + 90 <= sl["time_gps_s"] <= t0 + 1710
        for n, o in obs.items():                                  # tracked at both receivers, before and after
            g = o[(o["sat"] == sl["sat"]) & (np.abs(o["time_gps_s"] - sl["time_gps_s"]) < 10.5)]
            assert len(g) == 21, (sl, n)
        o = obs[sl["receiver"]]
        rec = o[(o["sat"] == sl["sat"]) & (np.abs(o["time_gps_s"] - sl["time_gps_s"]) < 0.01)]
        assert len(rec) == 1 and int(rec["lli_l1"].iloc[0]) & 1                  # LLI-flagged
    # too short a span for any well-tracked slip: fewer, and truth.json says why
    s, tj = _gnss_sim(tmp_path, "b", duration_s=15.0, seed=7, n_slips=3)
    assert s["slips"] == 0 and s["slips_requested"] == 3 and tj["cycle_slips"] == []
    assert "3 slips requested, 0 simulated" in tj["slips_note"]


def test_default_noise_model_is_the_estimators_weighting(tmp_path):
    s, tj = _gnss_sim(tmp_path, "d", duration_s=30.0, seed=1)
    assert tj["phase_sigma_m"] == [0.003, 0.003] and tj["phase_noise_model"].startswith("elevation")
    _, tw = _gnss_sim(tmp_path, "w", duration_s=30.0, seed=1, phase_sigma_m=0.002)
    assert tw["phase_sigma_m"] == 0.002 and tw["phase_noise_model"].startswith("white")
    with pytest.raises(CdgpsError, match="phase-noise-m"):
        _gnss_sim(tmp_path, "x", duration_s=30.0, phase_sigma_m=-1.0)


def test_rover_phase_multipath_is_the_gauss_markov_process_it_claims():
    """σ, the autocorrelation exp(−lag/τ), independence between satellites, a gap's decorrelation (exp(−gap/τ)),
    and the phases' other contents untouched."""
    from cdgps_cli.sim.gnss import rover_phase_multipath

    t = np.arange(40_000.0)
    obs = pd.DataFrame({"time_gps_s": np.tile(t, 2), "sat": np.repeat(["G01", "G02"], t.size), "phase_l1_cycles": 1e3})
    out = rover_phase_multipath(obs, 0.005, 30.0, seed=3)
    m = (out["phase_l1_cycles"].to_numpy() - 1e3) * GPS_L1_WAVELENGTH_M
    a, b = m[:t.size], m[t.size:]
    for x in (a, b):
        assert np.std(x) == pytest.approx(0.005, rel=0.1)
        x0 = x - x.mean()
        rho = lambda k: float(np.dot(x0[:-k], x0[k:]) / np.dot(x0, x0))   # noqa: E731
        assert rho(1) == pytest.approx(np.exp(-1 / 30), abs=0.01)
        assert rho(30) == pytest.approx(np.exp(-1), abs=0.12)
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.1                              # satellites independent
    # two records per satellite, 3 s or 60 s apart: their correlation is exp(−Δt/τ) (0.905, 0.135)
    sats = [f"S{i:04d}" for i in range(4000)]
    for gap, want in ((3.0, np.exp(-0.1)), (60.0, np.exp(-2.0))):
        two = pd.DataFrame({"time_gps_s": np.tile([0.0, gap], len(sats)), "sat": np.repeat(sats, 2),
                            "phase_l1_cycles": 0.0})
        v = rover_phase_multipath(two, 0.005, 30.0, seed=5)["phase_l1_cycles"].to_numpy().reshape(-1, 2)
        assert np.corrcoef(v[:, 0], v[:, 1])[0, 1] == pytest.approx(want, abs=0.05)
        assert np.std(v) * GPS_L1_WAVELENGTH_M == pytest.approx(0.005, rel=0.05)
    assert list(out.columns) == list(obs.columns) and obs["phase_l1_cycles"].eq(1e3).all()   # input not modified
    # a satellite seen once (it rises at the last epoch): its one draw
    one = rover_phase_multipath(pd.DataFrame({"time_gps_s": [0.0], "sat": ["G01"], "phase_l1_cycles": [0.0]}),
                                0.005, 30.0, seed=1)
    assert np.isfinite(one["phase_l1_cycles"]).all() and one["phase_l1_cycles"].iloc[0] != 0.0
    with pytest.raises(CdgpsError, match="multipath-m must be 0 .none. or in .0, 0.1. m"):
        rover_phase_multipath(obs, 0.5, 30.0, seed=3)
    with pytest.raises(CdgpsError, match="multipath-tau-s"):
        rover_phase_multipath(obs, 0.005, 0.0, seed=3)
    with pytest.raises(CdgpsError, match="multipath-m"):
        rover_phase_multipath(obs, -1.0, 30.0, seed=3)
