"""``estimate``'s note on how fast a random walk's states follow motion (``gnss.random_walk_passband_hz``): a sweep of
real u-blox files found a 5 mm vibration at 0.2 Hz reported as 0.11 mm by random-walk states of the default
1 mm/√s, without a word.  Checked against a scalar Kalman filter and RTS smoother written here (an independent
implementation) run on a noise-free sinusoid at the frequency the function gives: its amplitude comes out 1/√2."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.pipeline.gnss import random_walk_passband_hz


def _filter_smooth(y, q, r):
    """Scalar random walk x_k = x_{k-1} + w (var q), y_k = x_k + v (var r): filtered and RTS-smoothed x."""
    n = y.size
    xf, pf, xp, pp = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    x, p = 0.0, 1e6
    for k in range(n):
        xp[k], pp[k] = x, p + q
        g = pp[k] / (pp[k] + r)
        x, p = xp[k] + g * (y[k] - xp[k]), (1 - g) * pp[k]
        xf[k], pf[k] = x, p
    xs = xf.copy()
    for k in range(n - 2, -1, -1):
        c = pf[k] / pp[k + 1]
        xs[k] = xf[k] + c * (xs[k + 1] - xp[k + 1])
    return xf, xs


def _amplitude(x, t, f):
    a = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t)])
    c = np.linalg.lstsq(a, x, rcond=None)[0]
    return float(np.hypot(c[0], c[1]))


@pytest.mark.parametrize("smoothed", [False, True])
def test_a_sinusoid_at_the_passband_comes_out_one_over_root_two(smoothed):
    step, sigma_w, sigma_r = 0.1, 1e-3, 0.0158                 # K = σ_w / (σ_r √T) ≈ 0.2 rad/s
    cov = np.tile(np.eye(3) * sigma_r**2, (20, 1, 1))
    t20 = np.arange(20) * step
    f_c = random_walk_passband_hz((sigma_w,) * 3, cov, t20, smoothed)[0]
    t = np.arange(0, 4000.0, step)
    y = 1e-3 * np.sin(2 * np.pi * f_c * t)
    xf, xs = _filter_smooth(y, sigma_w**2 * step, sigma_r**2)
    keep = t > 200.0                                          # past the filter's start
    got = _amplitude((xs if smoothed else xf)[keep], t[keep], f_c) / 1e-3
    assert got == pytest.approx(1 / np.sqrt(2), rel=0.03), (f_c, got)


def test_no_band_without_single_epoch_solutions():
    cov = np.full((5, 3, 3), np.nan)
    assert random_walk_passband_hz((1e-3,) * 3, cov, np.arange(5.0), True) is None
