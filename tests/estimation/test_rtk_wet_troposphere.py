"""``rtk``'s zenith wet delays (estimation/rtk_multi.py): a state per receiver on long baselines, against simulator
truth with wet delays the a-priori model does not hold.

The simulated pair: a base and a rover 60 km apart and 200 m apart in height, GPS L1 + L2 every 30 s for an hour,
zenith wet delays of 0.10 m at the base and 0.20 m at the rover (the simulator maps them with Niell's wet function;
no ionosphere, so the ionosphere is neglected here and the wet delays alone are tested).  Without the wet states the
10 cm difference puts the rover's height decimetres off with a σ of centimetres; with them every position's NEES is
about its 3 degrees of freedom and the difference of the delays is found.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from _shared import run_cli

from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.core.signals import signal
from cdgps_cli.estimation.rtk_multi import (WET_KEYS, position_nees, receiver_geometry, reported_positions, solve_rtk,
                                           wet_threshold_km)
from cdgps_cli.model.gps.orbits import ecef_to_enu, ecef_to_geodetic, enu_matrix
from cdgps_cli.model.gps.positioning import synthetic_nav
from cdgps_cli.sim.gnss_signals import simulate_receiver_signals

ZWD_M = (0.10, 0.20)        # base, rover
SEEDS = (1, 2, 3, 4)


def _pair(seed: int, km: float = 60.0, dz_m: float = 200.0, n: int = 120, dt_s: float = 30.0):
    t0 = gps_seconds(2024, 3, 1)
    nav = synthetic_nav("G", t0, n * dt_s + 60.0, seed=seed)
    xb = np.array([-3978242.4, 3382841.2, 3649902.8])
    xr = xb + np.array([0.6e3 * km, 0.8e3 * km, dz_m]) @ enu_matrix(*ecef_to_geodetic(xb)[:2])
    geo = []
    for k, (x, zwd) in enumerate(zip((xb, xr), ZWD_M)):
        o = simulate_receiver_signals(nav, x, t0, n, dt_s, ("G:L1", "G:L2"), seed=10 * seed + k,
                                      clock_drift_ms=0.5 * (k + 1), zenith_wet_m=zwd)["obs"]
        geo.append(receiver_geometry(o.assign(wavelength_m=[signal(g).wavelength_m for g in o["signal"]]), nav, x))
    return geo, xb, xr


@pytest.fixture(scope="module")
def pairs():
    return {seed: _pair(seed) for seed in SEEDS}


def _solve(pair, **options):
    (gb, gr), xb, xr = pair
    opt = {"code_noise": "model", "age_noise": "model", "direction": "forward", "iono_threshold_km": 1000.0, **options}
    res = solve_rtk(gb, gr, xb, xr + np.array([0.5, -0.3, 0.8]), options=opt)
    xyz, cov = reported_positions(res)
    nees = position_nees(xyz, cov, xr)
    up = enu_matrix(*ecef_to_geodetic(xr)[:2])[2]
    return res, ecef_to_enu(xyz[-1], xr), float(np.sqrt(up @ cov[-1] @ up)), nees


@pytest.mark.parametrize("mode", ["static", "kinematic"])
def test_with_the_wet_delays_estimated_the_sigma_holds_and_without_them_it_does_not(pairs, mode):
    est, neg = [], []
    for seed in SEEDS:
        res, enu, sig_u, nees = _solve(pairs[seed], mode=mode, fix=False, tropo_threshold_km=10.0)
        assert res["wet_troposphere"]["model"] == "estimated"
        assert abs(enu[2]) < 3.5 * sig_u, (seed, enu, sig_u)
        z = res["wet_troposphere"]["zenith_wet_m"]
        assert abs((z["rover"] - z["base"]) - (ZWD_M[1] - ZWD_M[0])) < 0.03, (seed, z)
        est.append(nees[20:])
        res, enu, sig_u, nees = _solve(pairs[seed], mode=mode, fix=False, tropo_threshold_km=1000.0)
        assert res["wet_troposphere"]["model"] == "neglected (short baseline)"
        assert abs(enu[2]) > 0.1 and abs(enu[2]) > 4 * sig_u, (seed, enu, sig_u)
        neg.append(nees[20:])
    assert 1.5 < np.concatenate(est).mean() < 4.5           # 3 degrees of freedom (measured 3.06 / 2.88 on 8 seeds)
    assert np.concatenate(neg).mean() > 30.0                 # the neglected 10 cm: hundreds


def test_with_the_wet_delays_estimated_the_static_rover_is_fixed_to_millimetres(pairs):
    for seed in SEEDS[:2]:
        res, enu, sig_u, _ = _solve(pairs[seed], mode="static", tropo_threshold_km=10.0)
        assert res["fixed"][-1], seed
        assert np.linalg.norm(enu) < 0.01 and sig_u < 0.03, (seed, enu, sig_u)


def test_the_summary_says_what_was_estimated_and_a_short_baseline_has_no_wet_state():
    """The JSON summary's ``wet_troposphere``: the threshold in force (the ionosphere's when not given), the prior and
    the last estimates with their σ; below the threshold the state holds no wet column and the rows no mapping."""
    assert MULTI_GNSS_DEFAULTS["tropo_threshold_km"] is None
    assert wet_threshold_km({"iono_threshold_km": 10.0, "tropo_threshold_km": None}) == 10.0
    assert wet_threshold_km({"iono_threshold_km": 10.0, "tropo_threshold_km": 50.0}) == 50.0
    pair = _pair(5, km=2.0, dz_m=5.0, n=20)
    res, *_ = _solve(pair, mode="static", iono_threshold_km=10.0)
    assert res["wet_troposphere"] == {"model": "neglected (short baseline)", "threshold_km": 10.0}
    res, *_ = _solve(pair, mode="static", iono_threshold_km=10.0, tropo_threshold_km=1.0)
    w = res["wet_troposphere"]
    assert w["model"] == "estimated" and w["threshold_km"] == 1.0 and w["initial_m"] == 0.15 and w["sigma_m"] == 0.3
    assert set(w["zenith_wet_m"]) == set(w["zenith_wet_sigma_m"]) == {"base", "rover"}
    assert all(0.0 < s < 0.3 for s in w["zenith_wet_sigma_m"].values())
    assert [k for k in WET_KEYS] == [("T", "base"), ("T", "rover")]


def test_bad_wet_options_are_named_and_the_static_engine_refuses_them():
    from cdgps_cli.estimation.static_engine import _static_options
    from cdgps_cli.pipeline.gnss_multi import validate_options

    with pytest.raises(CdgpsError) as exc:
        validate_options({"tropo_threshold_km": -1, "tropo_sigma_m": 0, "tropo_rw_m_per_sqrt_s": float("nan"),
                          "tropo_initial_m": "x"})
    text = str(exc.value)
    for key in ("tropo_threshold_km: expected a baseline length in km >= 0", "tropo_sigma_m: expected a σ in m > 0",
                "tropo_rw_m_per_sqrt_s: expected a random walk", "tropo_initial_m: expected a zenith wet delay"):
        assert key in text, text
    validate_options({"tropo_threshold_km": None})
    with pytest.raises(CdgpsError, match="does not estimate zenith wet delays"):
        _static_options({"tropo_threshold_km": 20.0})
    with pytest.raises(CdgpsError, match="option antex = 'x.atx' is not supported"):
        _static_options({"antex": "x.atx"})


def test_rtk_takes_the_threshold_and_follows_the_ionosphere_s_by_default(tmp_path):
    """The real 35 km pair DELF → ZEGV (tests/data/georust-delf-zegv): estimated by default (the ionosphere is, from
    10 km), neglected with the ionosphere (``--iono-threshold-km 100``) unless asked for; a negative threshold is
    refused by its option's name, nothing written."""
    from pathlib import Path

    data = Path(__file__).resolve().parents[1] / "data" / "georust-delf-zegv"
    args = ("rtk", "--base", data / "delf0010.21d", "--rover", data / "zegv0010.21d", "--nav", data / "cbw10010.21n.gz",
            "--json", "-q")
    got = {}
    for extra in ((), ("--iono-threshold-km", 100), ("--iono-threshold-km", 100, "--tropo-threshold-km", 5)):
        r = run_cli(*args, "-o", tmp_path / f"{len(extra)}.csv", *extra)
        assert r.exit_code == 0, r.output
        got[len(extra)] = json.loads(r.output[r.output.index("{"):])["wet_troposphere"]
    assert got[0]["model"] == "estimated" and got[0]["threshold_km"] == 10.0
    assert got[2] == {"model": "neglected (short baseline)", "threshold_km": 100.0}
    assert got[4]["model"] == "estimated" and got[4]["threshold_km"] == 5.0
    bad = run_cli(*args, "-o", tmp_path / "bad.csv", "--tropo-threshold-km", -1)
    assert bad.exit_code == 2 and "--tropo-threshold-km -1: outside the plausible range" in bad.output
    assert not (tmp_path / "bad.csv").exists()


def test_an_interpolated_base_observation_carries_the_wet_delay_of_the_rover_s_time():
    """A base every 30 s and a rover every second, 500 m apart, both with 0.15 m of zenith wet delay: the rover's
    epochs take the base interpolated to their time (measurement/base_interpolation), whose wet delay is that time's,
    so its mapping is taken at the base's elevation then (``dd_signals._base_elevation_of_rows``).  Taken at the base
    epoch's elevation instead (a review found it), the mismatch made the two delays' common part, which a short
    baseline cannot see, look observed: 0.011 ± 0.028 m for 0.15; now it stays at its prior's σ, 0.21 m."""
    t0 = gps_seconds(2024, 3, 1)
    nav = synthetic_nav("G", t0, 1300.0, seed=2)
    xb = np.array([-3978242.4, 3382841.2, 3649902.8])
    xr = xb + np.array([300.0, 400.0, 2.0]) @ enu_matrix(*ecef_to_geodetic(xb)[:2])
    geo = []
    for k, (x, n, dt) in enumerate(((xb, 41, 30.0), (xr, 1201, 1.0))):
        o = simulate_receiver_signals(nav, x, t0, n, dt, ("G:L1", "G:L2"), seed=k + 1, zenith_wet_m=0.15)["obs"]
        geo.append(receiver_geometry(o.assign(wavelength_m=[signal(g).wavelength_m for g in o["signal"]]), nav, x))
    res = solve_rtk(geo[0], geo[1], xb, xr, options={"tropo_threshold_km": 0.0, "code_noise": "model",
                                                     "age_noise": "model", "direction": "forward", "mode": "static"})
    assert res["epoch_pairing"]["interpolated"] > 1000
    w = res["wet_troposphere"]
    for who in ("base", "rover"):
        assert w["zenith_wet_sigma_m"][who] > 0.15, w                 # the common part: not observed
        assert abs(w["zenith_wet_m"][who] - 0.15) < 2 * w["zenith_wet_sigma_m"][who], w


def test_wet_options_given_as_text_are_numbers_after_validation():
    from cdgps_cli.pipeline.gnss_multi import validate_options

    opt = validate_options({"tropo_threshold_km": "0", "tropo_sigma_m": "0.3", "tropo_rw_m_per_sqrt_s": "1e-4",
                            "tropo_initial_m": "0.1"})
    assert (opt["tropo_threshold_km"], opt["tropo_sigma_m"], opt["tropo_rw_m_per_sqrt_s"], opt["tropo_initial_m"]) == \
        (0.0, 0.3, 1e-4, 0.1)
