"""Alban et al. (2003) in miniature on synthetic signals of known truth (the full studies are in
benchmarks/tracking_paper.py): PLL jitter against the thermal-noise formula, and the aided narrow
loop following line-of-sight phase up to its inertial sensor's bandwidth (tone injection)."""

import math

import numpy as np
from _track_signals import nco_error_rad, track_pieces

from cdgps_cli.tracking.channel import TrackOptions
from cdgps_cli.tracking.inertial import InertialGrade, accelerometer_doppler_aid_hz

LAMBDA_M = 299792458.0 / 1575.42e6


def test_pll_jitter_matches_the_thermal_noise_formula():
    """σ = sqrt(B_n/(C/N0)·(1 + 1/(2T·C/N0))) for a 20 Hz loop at 45 dB-Hz over 4 s (≈ 160 independent
    samples of the error: the standard deviation is good to ≈ 6 %; tolerance 15 %)."""
    cn0, bn = 45.0, 20.0
    outs, truth = track_pieces(7, 1234.0, 200.0, cn0, 4.0, [("pll", TrackOptions(pll_bn_hz=bn), None)], seed=3)
    e = nco_error_rad(outs["pll"], truth)[500:]
    c = 10 ** (cn0 / 10)
    formula = math.sqrt(bn / c * (1 + 1 / (2e-3 * c)))
    assert abs(np.std(e) / formula - 1) < 0.15
    assert np.abs(e).max() < math.pi / 4                                                # no slip


def test_aided_narrow_loop_follows_phase_up_to_the_sensor_bandwidth():
    """A 20 Hz line-of-sight phase tone: a 3 Hz loop aided by a 30 Hz accelerometer follows it with
    the gain of H + L(1 − H) (0.86; L the sensor's low-pass), the same loop unaided barely (≈ 0.06)."""
    f_tone, amp_rad, seconds = 20.0, 0.05, 3.0

    def phase(t):
        return amp_rad * np.sin(2 * np.pi * f_tone * t)

    tm = (np.arange(int(seconds * 1e3)) + 0.5) * 1e-3
    acc = -amp_rad * (2 * np.pi * f_tone) ** 2 * np.sin(2 * np.pi * f_tone * tm) * LAMBDA_M / (2 * np.pi)
    v0 = amp_rad * 2 * np.pi * f_tone * np.cos(2 * np.pi * f_tone * tm[0]) * LAMBDA_M / (2 * np.pi)
    sensor = InertialGrade("30 Hz", 0.0, 0.0, 0.0, 0.0, 30.0)
    aid = accelerometer_doppler_aid_hz(acc, 1e-3, sensor, np.random.default_rng(0), v0_m_s=v0, wavelength_m=LAMBDA_M)
    configs = [("aided", TrackOptions(pll_bn_hz=3.0), aid), ("unaided", TrackOptions(pll_bn_hz=3.0), None)]
    outs, truth = track_pieces(7, 1234.0, 200.0, 55.0, seconds, configs, phase_fn=phase, seed=4)
    sel = slice(1000, None)
    basis = np.stack([np.ones(tm[sel].size), tm[sel], np.sin(2 * np.pi * f_tone * tm[sel]),
                      np.cos(2 * np.pi * f_tone * tm[sel])], axis=1)
    gains = {}
    for lab in ("aided", "unaided"):
        followed = nco_error_rad(outs[lab], truth)[sel] + phase(tm[sel])          # NCO phase minus the static part
        coef = np.linalg.lstsq(basis, followed, rcond=None)[0]
        gains[lab] = math.hypot(coef[2], coef[3]) / amp_rad
    assert 0.78 < gains["aided"] < 0.95
    assert gains["unaided"] < 0.12
