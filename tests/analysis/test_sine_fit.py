"""analysis/sine_fit: amplitude and frequency of a sinusoid on irregular, gappy, noisy samples."""

import numpy as np
import pytest

from cdgps_cli.analysis.sine_fit import fit_sine


def test_exact_sine_with_offset_drift_and_gaps():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(1.4e9, 1.4e9 + 300.0, 250))          # GPS seconds, irregular
    y = 0.003 * np.sin(2 * np.pi * 0.213 * (t - 1.4e9) + 0.7) + 0.25 - 1e-5 * (t - 1.4e9)
    y[40:60] = np.nan                                              # a gap
    f = fit_sine(t, y, 0.2)
    assert f.n == 230
    assert f.amplitude == pytest.approx(0.003, rel=1e-6) and f.frequency_hz == pytest.approx(0.213, rel=1e-7)
    assert f.drift_per_s == pytest.approx(-1e-5, rel=1e-4) and f.residual_rms < 1e-9
    ok = np.isfinite(y)                                            # the model in absolute time reproduces y
    model = f.amplitude * np.sin(2 * np.pi * f.frequency_hz * t + f.phase_rad) + f.offset + f.drift_per_s * t
    np.testing.assert_allclose(model[ok], y[ok], atol=1e-6)


def test_noise_gives_the_expected_scatter():
    """1 mm white noise on 3 mm at 0.1 Hz over 301 s: amplitude within 0.25 mm (≈ 3σ of √(2/N)·1 mm)."""
    t = np.arange(301.0)
    rng = np.random.default_rng(11)
    est = [fit_sine(t, 0.003 * np.sin(2 * np.pi * 0.1 * t) + rng.normal(0, 0.001, t.size), 0.1) for _ in range(20)]
    amp = np.array([e.amplitude for e in est])
    assert np.all(np.abs(amp - 0.003) < 0.00025) and np.all(np.abs([e.frequency_hz / 0.1 - 1 for e in est]) < 0.005)


def test_bad_arguments():
    with pytest.raises(ValueError, match="at least 5 finite samples"):
        fit_sine([0, 1, 2], [0, 1, 0], 0.1)
    with pytest.raises(ValueError, match="f_guess_hz > 0"):
        fit_sine(np.arange(10.0), np.zeros(10), -1.0)
