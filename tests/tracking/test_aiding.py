"""Aiding (issue 16 item 2): oscillator phase noise against the analytic Allan deviation, inertial
sensor models, the line-of-sight Doppler from a broadcast ephemeris against a real receiver's carrier
phase rate (the common mode of the differences being the receiver clock), and channels sharing a
clock loop."""

import math
from pathlib import Path

import numpy as np
import pytest
from _track_signals import ca_signal

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.tracking.aiding import clock_drift_s_per_s, common_mode_hz, los_doppler_hz
from cdgps_cli.tracking.channel import TrackOptions, track
from cdgps_cli.tracking.inertial import (GRADES, accelerometer_doppler_aid_hz, gyro_antenna_velocity_m_s, low_pass,
                                         sense)
from cdgps_cli.tracking.oscillator import (OCXO, TCXO, TCXO_HQ, Oscillator, carrier_phase_noise_rad, overlapping_allan_deviation,
                                           simulate_time_error)

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.mark.parametrize("osc", [Oscillator("white FM", 2e-19, 0, 0), Oscillator("flicker FM", 0, 7e-21, 0),
                                 Oscillator("random-walk FM", 0, 0, 2e-20), TCXO, TCXO_HQ, OCXO],
                         ids=lambda o: o.name)
def test_simulated_allan_deviation_matches_the_analytic_formula(osc):
    """σ_y(τ) of 2^19 simulated 1 ms samples at τ = 10 ms … 1 s within 8 % of
    sqrt(h0/(2τ) + 2 ln2 h−1 + (2π²/3) h−2 τ) — each noise type alone has its own slope (−1/2, 0, +1/2)."""
    dt, m = 1e-3, np.array([10, 100, 1000])
    x = simulate_time_error(osc, dt, 2**19, np.random.default_rng(7))
    got = overlapping_allan_deviation(x, dt, m)
    np.testing.assert_allclose(got, osc.allan_deviation(m * dt), rtol=0.08)


def test_oscillator_values_and_phase_noise():
    # TCXO: σ_y(1 s) = sqrt(1e-19 + 9.7e-21 + 1.32e-19) ≈ 4.9e-10; the OCXO is quieter at every τ
    assert TCXO.allan_deviation(1.0) == pytest.approx(4.92e-10, rel=0.01)
    taus = [0.01, 1, 100]
    assert np.all(OCXO.allan_deviation(taus) < TCXO_HQ.allan_deviation(taus))
    assert np.all(TCXO_HQ.allan_deviation(taus) <= TCXO.allan_deviation(taus))
    phi = carrier_phase_noise_rad(TCXO, 1e-3, 1000, np.random.default_rng(1))
    x = simulate_time_error(TCXO, 1e-3, 1000, np.random.default_rng(1))
    np.testing.assert_allclose(phi, 2 * math.pi * 1575.42e6 * x)
    assert phi.shape == (1001,) and phi[0] == 0.0
    with pytest.raises(CdgpsError, match="h_m2 must be a finite number"):
        Oscillator("bad", 1e-19, 0, -1.0)
    with pytest.raises(CdgpsError, match="averaging factor"):
        overlapping_allan_deviation(x, 1e-3, [600])


def test_inertial_sensor_bias_noise_and_bandwidth():
    g = GRADES["tactical"]
    dt, n = 1e-3, 200_000
    rng = np.random.default_rng(3)
    out = sense(np.zeros(n), dt, g.accel_bias_m_s2, g.accel_noise_m_s2_per_rthz, g.bandwidth_hz, rng)
    assert out.mean() == pytest.approx(g.accel_bias_m_s2, abs=4 * g.accel_noise_m_s2_per_rthz / math.sqrt(n * dt))
    # averaged over τ the noise has σ = N/√τ
    tau_blocks = out.reshape(-1, 100).mean(axis=1)
    assert tau_blocks.std() == pytest.approx(g.accel_noise_m_s2_per_rthz / math.sqrt(0.1), rel=0.05)
    # first-order low-pass: a tone at the bandwidth comes out at 1/√2, one a decade below at ≈ 1
    t = np.arange(20_000) * dt
    for f, gain in ((g.bandwidth_hz, 1 / math.sqrt(2)), (g.bandwidth_hz / 10, 1 / math.sqrt(1.01))):
        y = low_pass(np.sin(2 * math.pi * f * t), dt, g.bandwidth_hz)[5000:]
        assert np.sqrt(2 * np.mean(y * y)) == pytest.approx(gain, rel=0.02)
    assert GRADES["navigation"].accel_bias_m_s2 < g.accel_bias_m_s2 < GRADES["consumer"].accel_bias_m_s2


def test_accelerometer_aid_drifts_with_the_bias_and_gyro_lever_arm():
    g = GRADES["consumer"]
    dt = 1e-3
    t = np.arange(5000) * dt
    acc = 4.9 * np.sin(2 * math.pi * 2.0 * t)
    v_true = 4.9 / (2 * math.pi * 2.0) * (1 - np.cos(2 * math.pi * 2.0 * t))
    quiet = type(g)("biased", g.accel_bias_m_s2, 0.0, 0.0, 0.0, 1e4)            # wide, noise-free: bias only
    aid = accelerometer_doppler_aid_hz(acc, dt, quiet, np.random.default_rng(0))
    np.testing.assert_allclose(aid * GPS_L1_WAVELENGTH_M - v_true, g.accel_bias_m_s2 * t, atol=2e-3)
    v = gyro_antenna_velocity_m_s(np.array([[0.0, 0.0, 0.1]]), np.array([2.0, 0.0, 0.0]))
    np.testing.assert_allclose(v, [[0.0, 0.2, 0.0]])
    with pytest.raises(CdgpsError, match="shape"):
        gyro_antenna_velocity_m_s(np.zeros(3), np.zeros(3))


def test_los_doppler_agrees_with_a_real_receivers_phase_rate_up_to_its_clock():
    """GEONET 0759 (static, 30 s): −ΔL1/Δt of 8 satellites minus the predicted Doppler (Simpson mean
    over the interval) is one common value per interval — the receiver clock's drift — to 0.1 Hz,
    while the Dopplers themselves span kilohertz."""
    nav = read_rinex_nav(DATA / "07590920.05n")
    hdr, obs = read_rinex_obs(DATA / "07590920.05o")
    rx = np.array(hdr["approx_position_xyz_m"])
    t = np.unique(obs["time_gps_s"])[:8]
    sats = sorted(set(obs[obs["time_gps_s"] == t[0]]["sat"]))
    err = np.full((t.size - 1, len(sats)), np.nan)
    pred_all = []
    for j, s in enumerate(sats):
        o = obs[obs["sat"] == s].set_index("time_gps_s")["phase_l1_cycles"]
        for i in range(t.size - 1):
            if t[i] in o.index and t[i + 1] in o.index:
                f = los_doppler_hz(nav, s, [t[i], (t[i] + t[i + 1]) / 2, t[i + 1]], rx)
                pred = (f[0] + 4 * f[1] + f[2]) / 6
                pred_all.append(pred)
                err[i, j] = -(o[t[i + 1]] - o[t[i]]) / (t[i + 1] - t[i]) - pred
    clock = common_mode_hz(err)
    assert np.ptp(pred_all) > 3000
    assert np.nanmax(np.abs(err - clock[:, None])) < 0.1
    assert np.all(np.abs(clock_drift_s_per_s(clock)) < 5e-6)


def test_common_mode_weights_and_missing_channels():
    e = np.array([[1.0, 3.0, np.nan], [np.nan, np.nan, np.nan]])
    np.testing.assert_allclose(common_mode_hz(e, [1.0, 3.0, 5.0]), [2.5, np.nan])
    with pytest.raises(CdgpsError, match="weights"):
        common_mode_hz(e, [1.0, -1.0, 1.0])
    with pytest.raises(CdgpsError, match=r"weights: expected one per channel \(3\)"):
        common_mode_hz(e, [1.0, 2.0])
    with pytest.raises(CdgpsError, match=r"expected shape \(3,\) or \(2, 3\)"):
        los_doppler_hz(None, "G01", [0.0, 1.0], np.zeros(2))


def test_a_shared_clock_loop_keeps_narrow_channel_loops_locked():
    """Three satellites share an oscillator whose frequency swings 3 Hz at 1 Hz: the shared 15 Hz clock
    loop follows it (20 ms means within 0.5 Hz after removing the value absorbed at pull-in) and the 3 Hz
    channel loops stay locked, while the same 3 Hz loops tracking alone lose lock."""
    from cdgps_cli.tracking.shared_clock import track_shared_clock

    fs, dur, fa, fm = 2.2e6, 0.8, 3.0, 1.0
    sats = ((3, 1200.0, 100.0), (17, -2400.0, 600.0), (22, 300.0, 900.0))
    x = sum(ca_signal(p, d, c, 50.0, dur, seed=p, bits=False, fs=fs)[0] for p, d, c in sats)
    t = np.arange(x.size) / fs
    x = x * np.exp(1j * fa / fm * np.sin(2 * math.pi * fm * t))                       # clock: fa cos(2π fm t) Hz
    starts = [(p, d + fa, c) for p, d, c in sats]
    opt = TrackOptions(pll_bn_hz=3.0)
    r = track_shared_clock(x, fs, starts, opt, clock_bn_hz=15.0)
    upd = np.arange(r["clock_doppler_hz"].size) * 1e-3
    truth = fa * np.cos(2 * math.pi * fm * (upd + 5e-4))

    def means(v):
        return v.reshape(-1, 20).mean(axis=1)[20:]

    d = means(r["clock_doppler_hz"]) - means(truth)
    assert np.abs(d - d.mean()).max() < 0.5
    for (p, dop, c), tr in zip(starts, r["tracks"]):
        assert np.mean(tr["phase_lock"][400::20] > 0.8) == 1.0
        assert np.abs(means(tr["doppler_hz"]) - means(dop - fa + truth)).max() < 1.0
        alone = track(x, fs, p, dop, c, opt)
        assert np.mean(alone["phase_lock"][400::20] > 0.8) < 0.5


def test_shared_clock_in_pieces_equals_one_run_and_names_bad_input():
    from cdgps_cli.tracking.shared_clock import SharedClockReceiver

    fs = 2.2e6
    sats = ((3, 1200.0, 100.0), (17, -2400.0, 600.0))
    x = sum(ca_signal(p, d, c, 48.0, 0.15, seed=p, bits=False, fs=fs)[0] for p, d, c in sats)
    opt = TrackOptions(pll_bn_hz=5.0, pull_in_s=0.03, wide_pll_s=0.03)
    one = SharedClockReceiver(fs, sats, opt).run(x)
    rx = SharedClockReceiver(fs, sats, opt)
    parts = [rx.run(x[a:b]) for a, b in ((0, 22000 * 4), (22000 * 4, x.size))]
    np.testing.assert_array_equal(one[0], np.concatenate([p[0] for p in parts], axis=1))
    np.testing.assert_array_equal(one[1], np.concatenate([p[1] for p in parts]))
    with pytest.raises(CdgpsError, match="weights"):
        SharedClockReceiver(fs, sats, opt, weights=[1.0])
    with pytest.raises(CdgpsError, match=r"aids\[1\]: expected one value per 1 ms update \(150\)"):
        SharedClockReceiver(fs, sats, opt).run(x, [None, np.zeros(3)])


def test_oscillator_jitter_integral_closed_form_and_simulation():
    """White FM alone: ∫ f_c² h0/f² |1 − H|² df = π² f_c² h0 / (2ζω_n) (closed form of the integral);
    and a 10 Hz loop tracking simulated TCXO-HQ signals (4 × 2.5 s) shows the predicted thermal ⊕
    oscillator jitter (3.6°) within 15 %."""
    from _track_signals import nco_error_rad, track_pieces

    from cdgps_cli.tracking.loops import ZETA, pll2_gains
    from cdgps_cli.tracking.oscillator import pll_jitter_rad

    white = Oscillator("white FM", 2e-21, 0, 0)
    wn = math.sqrt(pll2_gains(10.0)[0])
    closed = math.pi * 1575.42e6 * math.sqrt(white.h0 / (2 * ZETA * wn))
    assert pll_jitter_rad(white, 10.0, f_max_hz=1e7) == pytest.approx(closed, rel=1e-3)

    bn, cn0, seconds = 10.0, 50.0, 3.5
    var = []
    for seed in range(4):                          # the error's low-frequency content: average 4 runs
        phase = carrier_phase_noise_rad(TCXO_HQ, 1e-4, int(seconds / 1e-4) + 10, np.random.default_rng(seed))
        grid = np.arange(phase.size) * 1e-4
        outs, truth = track_pieces(7, 1234.0, 200.0, cn0, seconds, [("pll", TrackOptions(pll_bn_hz=bn), None)],
                                   phase_fn=lambda t, g=grid, p=phase: np.interp(t, g, p), seed=9 + seed)
        var.append(np.var(nco_error_rad(outs["pll"], truth)[1000:]))
    c = 10 ** (cn0 / 10)
    predicted = math.hypot(math.sqrt(bn / c * (1 + 1 / (2e-3 * c))), pll_jitter_rad(TCXO_HQ, bn))
    assert math.sqrt(np.mean(var)) == pytest.approx(predicted, rel=0.15)


def test_the_papers_condition_a_tcxo_holds_3_hz_loops_when_the_clock_frequency_is_estimated_across_channels():
    """Alban et al.'s 3 Hz with a typical TCXO is the ultra-tight loop, fed the clock-error frequency as well
    as the Doppler.  Four satellites at 45 dB-Hz share Brown & Hwang's high-quality TCXO (6 s): 3 Hz
    channel loops under a shared 15 Hz clock loop follow it with the predicted jitter (thermal ⊕ clock
    loop's share ⊕ oscillator at 15 Hz: 2.6°) and stay locked; the same 3 Hz loops alone, each tracking the
    oscillator itself, show several times that jitter (predicted 16°)."""
    from _track_signals import nco_error_rad

    from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, ca_code
    from cdgps_cli.tracking.channel import L1_HZ, initial_state, outputs_dict, run_updates
    from cdgps_cli.tracking.oscillator import pll_jitter_rad
    from cdgps_cli.tracking.shared_clock import SharedClockReceiver

    fs, cn0, seconds, settle = 2.2e6, 45.0, 6.0, 2000
    sats = ((3, 1200.0, 100.0), (17, -2400.0, 600.0), (22, 300.0, 900.0), (28, 2900.0, 400.0))
    phase = carrier_phase_noise_rad(TCXO_HQ, 1e-4, int(seconds / 1e-4) + 10, np.random.default_rng(200))
    grid = np.arange(phase.size) * 1e-4
    rng = np.random.default_rng(40)
    opt = TrackOptions(pll_bn_hz=3.0)
    starts = [(p, d + 2.0, c) for p, d, c in sats]
    shared = SharedClockReceiver(fs, starts, opt, clock_bn_hz=15.0)
    alone = [initial_state(d, c) for _, d, c in starts]
    rows_shared, rows_alone = [[] for _ in sats], [[] for _ in sats]
    n_ms, sigma = int(fs * 1e-3), math.sqrt(fs / 10 ** (cn0 / 10) / 2)
    for k0 in range(0, int(seconds * 1e3), 500):
        t = np.arange(k0 * n_ms, (k0 + 500) * n_ms) / fs
        osc = np.interp(t, grid, phase)
        x = sigma * rng.standard_normal(2 * t.size).view(np.complex128)
        for p, d, c in sats:
            chips = c + t * CHIP_RATE_HZ * (1 + d / L1_HZ)
            x += ca_code(p)[np.floor(chips).astype(np.int64) % 1023] * np.exp(1j * (2 * np.pi * d * t + osc))
        rows, _ = shared.run(x)
        for i, (p, _, _) in enumerate(sats):
            rows_shared[i].append(rows[i])
            rows_alone[i].append(run_updates(x, fs, p, alone[i], opt))
    tm = (np.arange(int(seconds * 1e3)) + 0.5) * 1e-3
    c = 10 ** (cn0 / 10)
    thermal = lambda bn: math.sqrt(bn / c * (1 + 1 / (2e-3 * c)))  # noqa: E731
    predicted = math.degrees(math.sqrt(thermal(3.0) ** 2 + thermal(15.0) ** 2 / 4 + pll_jitter_rad(TCXO_HQ, 15.0) ** 2))
    for i, (p, d, _) in enumerate(sats):
        truth = 2 * np.pi * d * tm + np.interp(tm, grid, phase)
        sh, al = np.vstack(rows_shared[i]), np.vstack(rows_alone[i])
        jit_shared = math.degrees(np.std(nco_error_rad(sh, truth)[settle:]))
        jit_alone = math.degrees(np.std(nco_error_rad(al, truth)[settle:]))
        assert jit_shared == pytest.approx(predicted, rel=0.25), (p, jit_shared, predicted)
        assert jit_alone > 3 * jit_shared, (p, jit_alone, jit_shared)
        lock = outputs_dict(sh, fs)["phase_lock"][settle::20]
        assert np.mean(lock > 0.8) >= 0.95


def test_a_clock_loop_equal_to_the_channel_loops_changes_nothing():
    """Linear algebra of the shared clock: with the clock loop's filter equal to the channel loops'
    (same B_n, order, no narrowing), F(e_i − ē) + F(ē) = F(e_i), so every channel's NCO is that of an
    independent loop (the compiled channel) — to rounding."""
    from cdgps_cli.tracking.channel import run_updates, initial_state
    from cdgps_cli.tracking.shared_clock import SharedClockReceiver

    fs = 2.2e6
    sats = ((3, 1200.0, 100.0), (17, -2400.0, 600.0), (22, 300.0, 900.0))
    x = sum(ca_signal(p, d, c, 45.0, 0.4, seed=p, bits=True, fs=fs)[0] for p, d, c in sats)
    opt = TrackOptions(pll_bn_hz=15.0)
    rows, _ = SharedClockReceiver(fs, sats, opt, clock_bn_hz=15.0).run(x)
    for i, (p, d, c) in enumerate(sats):
        alone = run_updates(x, fs, p, initial_state(d, c), opt)
        np.testing.assert_allclose(rows[i][:, 2], alone[:, 2], rtol=0, atol=1e-6)     # carrier phase, cycles
