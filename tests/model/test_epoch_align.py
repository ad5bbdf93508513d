"""Epochs that line up (issue 14 item 2): the grid of GPS times, Doppler × offset corrections
against an analytic phase, slip flags of undifferenced epochs, and the static solution of pairs
with a drifting 8 ms receiver-clock offset and with different rates against the offset-free one."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.estimation.baseline import BaselineOptions, Station, solve_static_baseline
from cdgps_cli.model.gps.positioning import simulate_static_pair, synthetic_gps_nav
from cdgps_cli.sim.gnss import DEFAULT_MASTER_XYZ, DEFAULT_ROVER_XYZ
from cdgps_cli.model.gps.epoch_align import (
    align_receiver,
    carry_slips,
    common_epochs,
    grid_step_s,
    pair_epochs,
    sampling_interval_s,
)
from cdgps_cli.io.rinex import OBS_COLUMNS, gps_seconds

T0 = gps_seconds(2024, 1, 1)


def table(t, sat, phase, lli=None, pr=None):
    n = len(t)
    return pd.DataFrame({
        "time_gps_s": np.asarray(t, dtype=float), "sat": np.asarray(sat, dtype=object),
        "phase_l1_cycles": np.asarray(phase, dtype=float),
        "lli_l1": np.zeros(n, dtype=np.int64) if lli is None else np.asarray(lli, dtype=np.int64),
        "ssi_l1": np.zeros(n, dtype=np.int64),
        "pseudorange_l1_m": np.asarray(phase, dtype=float) * GPS_L1_WAVELENGTH_M if pr is None else pr,
        "snr_l1_dbhz": np.full(n, 45.0), "rx_clock_offset_s": np.full(n, np.nan),
        "epoch_flag": np.zeros(n, dtype=np.int64)}, columns=list(OBS_COLUMNS))


@pytest.mark.parametrize("interval, step", [(1.0, 1.0), (0.333, 1 / 3), (0.2, 0.2), (5.0, 5.0), (30.0, 30.0),
                                            (0.5, 0.5), (math.nan, 1.0)])
def test_grid_step(interval, step):
    assert grid_step_s(interval) == pytest.approx(step, abs=1e-12)


def _gappy(step, n, rng, jitter=0.0):
    """``n`` epochs of a receiver sampling every ``step`` s that skips 0-9 samples at a time (spacings 1-10
    steps, median about 3: a u-blox base interleaving RTCM), tags jittered by up to ``jitter`` s."""
    k = np.cumsum(rng.choice(np.arange(1, 11), size=n, p=np.r_[0.25, 0.18, 0.12, 0.1, 0.1, np.full(5, 0.05)]))
    return T0 + k * step - 0.009 + rng.uniform(-jitter, jitter, size=n)


@pytest.mark.parametrize("step", [1.0, 0.1, 5.0])
def test_sampling_interval_of_a_log_with_gaps(step):
    rng = np.random.default_rng(7)
    t = _gappy(step, 300, rng, jitter=0.001 * step)
    assert np.median(np.diff(t)) > 2.5 * step                 # the median spacing is not the sampling interval
    assert sampling_interval_s(t) == pytest.approx(step, abs=1e-12)
    assert sampling_interval_s(T0 + step * np.arange(50)) == pytest.approx(step, abs=1e-12)   # no gaps


def test_sampling_interval_falls_back_to_the_median_spacing():
    rng = np.random.default_rng(3)
    t = T0 + np.cumsum(rng.uniform(0.7, 2.9, size=200))      # no common sampling interval
    d = np.diff(t)
    assert sampling_interval_s(t) == pytest.approx(round(float(np.median(d)), 3))
    assert math.isnan(sampling_interval_s([T0])) and sampling_interval_s([T0, T0 + 2.0]) == 2.0


def test_a_rover_that_logs_with_gaps_keeps_every_epoch():
    """The rover's own grid is its sampling interval (1 s), not its median spacing (3 s): every epoch of a
    u-blox-like log with gaps and tags 9 ms before the second is kept (issue 28: the CORS -> M8P base pair kept
    76 of 283)."""
    rng = np.random.default_rng(11)
    t = _gappy(1.0, 120, rng)
    obs = table(np.repeat(t, 2), np.tile(["G01", "G02"], t.size), np.arange(2 * t.size, dtype=float))
    out, info = align_receiver(obs, tol_s=0.025, mode="geometry")
    assert info["grid_s"] == 1.0 and info["dropped_off_grid"] == 0 and len(out) == len(obs)


def test_geometry_mode_keeps_the_observations_and_reports_the_epochs():
    k = np.arange(100)
    tags = T0 + k + 0.008 + 2e-5 * k              # 8 ms, drifting 20 µs/s
    tags[10] = T0 + 10.5                           # far from the grid: dropped
    t = np.repeat(tags, 2)
    sat = np.tile(["G01", "G02"], 100)
    ph = np.arange(200, dtype=float)
    out, s = align_receiver(table(t, sat, ph), tol_s=0.025, mode="geometry")
    assert s["epochs"] == 100 and s["dropped_off_grid"] == 1 and s["off_grid_kept"] == 99 and s["on_grid"] == 0
    assert s["corrected"] == 0 and s["max_offset_ms"] == pytest.approx(8 + 0.02 * 99, abs=1e-3)
    np.testing.assert_array_equal(out["phase_l1_cycles"], np.delete(ph, [20, 21]))
    np.testing.assert_array_equal(out["time_gps_s"], np.delete(t, [20, 21]))
    np.testing.assert_allclose(out["grid_gps_s"], np.delete(T0 + np.repeat(k, 2), [20, 21]), atol=1e-6)


def test_doppler_mode_moves_phase_and_range_to_the_grid_time():
    """Φ(t) quadratic (1 cycle/s² like a GPS satellite's line-of-sight acceleration): the
    corrected phase at the grid time matches the analytic one to the neglected ½·Φ̈·δ²."""
    k = np.arange(60)
    delta = -0.008 + 1e-4 * k                      # .992 s tags, drifting
    tags = T0 + k + delta
    rows = []
    for s_i, (a, b, c) in enumerate([(1e7, -3000.0, 0.5), (2e7, 2500.0, -0.4)]):
        tt = tags - T0
        ph = a + b * tt + c * tt**2
        rows.append(table(tags, [f"G0{s_i + 1}"] * 60, ph))
    obs = pd.concat(rows, ignore_index=True).sort_values(["time_gps_s", "sat"]).reset_index(drop=True)
    before = obs.copy(deep=True)
    out, s = align_receiver(obs, tol_s=0.025, mode="doppler")
    pd.testing.assert_frame_equal(obs, before)      # the input is not modified (the kept rows are not copied first)
    assert s["corrected"] == 60 and s["rows_dropped_no_rate"] == 0
    np.testing.assert_allclose(out["time_gps_s"], out["grid_gps_s"], atol=0)
    for s_i, (a, b, c) in enumerate([(1e7, -3000.0, 0.5), (2e7, 2500.0, -0.4)]):
        o = out[out["sat"] == f"G0{s_i + 1}"]
        tt = o["grid_gps_s"].to_numpy() - T0
        exact = a + b * tt + c * tt**2
        d = delta[np.round(tt).astype(int)]
        err = o["phase_l1_cycles"].to_numpy() - exact
        np.testing.assert_allclose(err, -c * d**2, atol=1e-6)     # only the curvature term −½·Φ̈·δ² is left
        assert np.max(np.abs(err)) < 1e-4                         # 0.02 mm
        np.testing.assert_allclose(o["pseudorange_l1_m"].to_numpy() / GPS_L1_WAVELENGTH_M - exact, -c * d**2, atol=1e-6)
    # an uncorrected phase would be off by δ·Φ̇: 3000 cycles/s × 8 ms = 24 cycles
    assert abs(obs["phase_l1_cycles"].iloc[0] - out["phase_l1_cycles"].iloc[0]) > 10


def test_doppler_rate_never_spans_a_slip_and_short_segments_are_dropped():
    k = np.arange(30)
    tags = T0 + k + 0.005
    ph = 1000.0 + 200.0 * k.astype(float)
    ph[15:] += 1234.0                              # slip flagged at k = 15
    lli = np.zeros(30, dtype=np.int64)
    lli[15] = 1
    lli[29] = 1                                    # the last epoch alone in its segment
    ph[29] += 77.0
    out, s = align_receiver(table(tags, ["G05"] * 30, ph, lli), tol_s=0.025, mode="doppler")
    assert s["rows_dropped_no_rate"] == 1
    exact = np.r_[1000.0 + 200.0 * (k - 0.005)][:29]
    exact[15:] += 1234.0
    np.testing.assert_allclose(out["phase_l1_cycles"].to_numpy(), exact, atol=1e-7)


def test_duplicates_and_tolerance():
    """Doppler mode moves observations by δ·Φ̇: only within the tolerance; geometry mode moves nothing and labels
    an epoch up to a third of the step off its grid time with it (a rover tagged 30 ms after the second was
    dropped whole by init while rtk bridged every epoch); beyond that third the epoch is dropped in both."""
    tags = T0 + np.array([0.0, 1.004, 1.010, 2.03, 3.0, 4.4, 5.0])
    obs = table(tags, ["G01"] * 7, np.arange(7.0) * 100)
    out, s = align_receiver(obs, tol_s=0.025, mode="doppler")
    assert s["dropped_duplicate"] == 1 and s["dropped_off_grid"] == 2 and s["tolerance_ms"] == pytest.approx(25)
    out, s = align_receiver(obs, tol_s=0.025)
    assert s["dropped_duplicate"] == 1 and s["dropped_off_grid"] == 1 and s["tolerance_ms"] == pytest.approx(1000 / 3)
    np.testing.assert_allclose(out["tag_gps_s"], T0 + np.array([0.0, 1.004, 2.03, 3.0, 5.0]))
    np.testing.assert_allclose(out["grid_gps_s"], T0 + np.array([0.0, 1.0, 2.0, 3.0, 5.0]))


def test_pair_epochs_across_rates():
    g3 = T0 + np.arange(0, 30) / 3.0               # 3 Hz grid
    g1 = T0 + np.arange(0, 10) * 1.0
    g5 = T0 + np.arange(0, 10, 5) * 1.0
    ia, ib = pair_epochs(g3, g1)
    np.testing.assert_array_equal(ia, np.arange(0, 30, 3))
    np.testing.assert_array_equal(ib, np.arange(10))
    ia, ib = pair_epochs(g1, g5)
    np.testing.assert_array_equal(ia, [0, 5])
    ce = common_epochs(T0 + np.arange(0, 30) / 3.0 - 0.004, T0 + np.arange(10) + 0.009, 0.025)
    assert ce["common_epochs"] == 10 and ce["master"]["matched"] == 10 and ce["rover"]["off_grid"] == 10


def test_carry_slips():
    t = np.array([0, 1, 2, 3, 0, 1, 2, 3], dtype=float)
    sat = np.array(["A"] * 4 + ["B"] * 4, dtype=object)
    lli = np.array([0, 1, 0, 0, 0, 0, 0, 1])
    keep = np.array([1, 0, 0, 1, 1, 1, 1, 0], dtype=bool)
    out = carry_slips(t, sat, lli, keep)
    np.testing.assert_array_equal(out[keep], [0, 1, 0, 0, 0])   # A's slip moved to t = 3; B's last one has no successor


# ---------------------------------------------------------------------------------------------
# the static solution


@pytest.fixture(scope="module")
def nav():
    return synthetic_gps_nav(T0, 900.0, seed=3)


def solve(nav, *, offset=(0.0, 0.0), drift=(0.0, 0.0), raw=False, mode="geometry", base_every=1, slips=0):
    xm, xr = np.array(DEFAULT_MASTER_XYZ), np.array(DEFAULT_ROVER_XYZ)
    sim = simulate_static_pair(nav, xm, xr, T0, 600.0, 1.0, phase_sigma_m=(0.003, 0.003), clock_offset_ms=offset,
                               clock_drift_ms=drift, tag_resolution_s=None if raw else 1e-3, seed=4,
                               base_every=base_every, random_slips=slips, mask_rad=math.radians(10.0))
    opt = BaselineOptions(epoch_alignment=mode, kinematic_series=False)
    res = solve_static_baseline(Station("base", {"approx_position_xyz_m": xm, "path": "b"}, sim["base"]),
                                Station("rover", {"approx_position_xyz_m": xr, "path": "r"}, sim["rover"]),
                                nav, opt, master_xyz=xm, rover_xyz=xr)
    return res, sim


@pytest.fixture(scope="module")
def offset_free(nav):
    return solve(nav)[0]


@pytest.mark.parametrize("mode", ["geometry", "doppler"])
def test_drifting_8ms_offset_matches_the_offset_free_solution(nav, offset_free, mode):
    res, sim = solve(nav, offset=(0.0, -8.0), drift=(0.0, 1.5), raw=True, mode=mode)
    tags = np.unique(sim["rover"]["time_gps_s"])
    frac = tags - np.round(tags)
    assert np.all(np.abs(frac) > 0.006) and np.all(np.abs(frac) < 0.0081)   # .992–.9935 s tags
    ep = res["epochs"]
    assert ep["n_epochs_used"] >= 0.99 * offset_free["epochs"]["n_epochs_used"]
    al = ep["epoch_alignment"]["rover"]
    assert al["matched"] == al["epochs"] == 600 and al["dropped_off_grid"] == 0
    assert al["corrected"] == (600 if mode == "doppler" else 0)
    assert res["solution"] == "fixed" and offset_free["solution"] == "fixed"
    d = np.array(res["fixed"]["enu_m"]) - np.array(offset_free["fixed"]["enu_m"])
    assert np.max(np.abs(d)) < 1e-3


def test_a_5s_base_beside_a_1hz_rover_keeps_the_rovers_slips(nav):
    """Every 1 Hz rover epoch is used (four of five bridged to the nearest 5 s base epoch, issue 28;
    before: only the 120 common epochs), and the rover's slips still start new ambiguities (they
    were once lost: a silently wrong fix, metres off)."""
    res, sim = solve(nav, base_every=5, slips=12)
    truth = np.array([0.0, 0.0, 0.0])
    assert res["epochs"]["epoch_alignment"]["rover"]["matched"] == 600
    ep = res["epochs"]["epoch_pairing"]
    assert ep["used"] == 600 and ep["bridged"] == 480 and 2.0 <= ep["max_age_s"] <= 4.0 + 0.01   # 4: the last rover epochs after the last base epoch
    assert res["solution"] in ("fixed", "partially fixed")
    sol = np.array((res["fixed"] or res["float"])["enu_m"])
    assert np.max(np.abs(sol - truth)) < 0.01


def test_simulate_gnss_raw_tags_and_master_rate(tmp_path):
    from cdgps_cli.sim.gnss import simulate_gnss_pair

    simulate_gnss_pair(tmp_path, duration_s=20.0, seed=1, clock_offset_ms=(0.0, -8.0), clock_drift_ms=(0.0, 0.0),
                       raw_tags=True, master_rate_hz=0.2)
    tj = json.loads((tmp_path / "truth.json").read_text())
    assert tj["master_rate_hz"] == 0.2 and tj["clock_offset_ms"]["rover"] == -8.0
    rover = (tmp_path / "rover.rnx").read_text()
    base = (tmp_path / "base.rnx").read_text()
    assert "23 59 59.992000" in rover and " 0.0000000" in base and " 5.0000000" in base and " 1.0000000" not in base


def test_phase_rate_agrees_with_the_doppler_of_a_real_ublox_log(repo_root):
    """Independent check of the rate (and of its sign, Φ̇ = −D) on real RXM-RAWX data."""
    from cdgps_cli.model.gps.epoch_align import phase_rate
    from cdgps_cli.io.gnss_run import read_receiver_file
    from cdgps_cli.pipeline.gnss_ingest import processing_obs

    path = repo_root.parent / "shared" / "data" / "ubx" / "pygpsdata-RXMRAWX.log"
    if not path.exists():
        pytest.skip("../shared/data is not available")
    rx = read_receiver_file("rx", "ubx", path)
    o = processing_obs(rx)
    rate = phase_rate(o["time_gps_s"], o["sat"], o["phase_l1_cycles"], o["lli_l1"], 1.0)
    dop = rx.raw["doppler_hz"].to_numpy(dtype=float)
    ok = np.isfinite(rate) & np.isfinite(dop)
    assert ok.sum() >= 40
    assert np.median(np.abs(rate[ok] + dop[ok])) < 0.5            # Hz, against rates of ±3000 Hz
    assert np.max(np.abs(rate[ok] + dop[ok])) < 5.0
