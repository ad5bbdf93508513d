"""Spectral peaks of a coordinate's Welch PSD (``analysis.spectra.spectral_peaks``): a sinusoid's frequency and
amplitude, whatever the motion model (a random walk's GNSS states have no model modes; a sweep of real files found
``cdgps spectra`` reporting nothing of a known 3 mm vibration that its psd.csv showed).

Independent checks: the sinusoid's known amplitude and frequency under white noise (and scipy.signal.welch's PSD of
the same series, the same peaks), and no peak in noise alone or in a random walk over many seeds (false alarms)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal as ss

from cdgps_cli.analysis.spectra import spectral_peaks, welch_psd


def _series(n, fs, amp, f0, noise, seed, walk=0.0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    return amp * np.sin(2 * np.pi * f0 * t + 0.7) + noise * rng.standard_normal(n) + walk * np.cumsum(rng.standard_normal(n))


@pytest.mark.parametrize("n, fs, f0, nperseg", [(3600, 1.0, 0.2, 600), (36000, 10.0, 0.137, 3000), (301, 1.0, 0.2, 75)])
def test_a_sinusoid_in_white_noise_is_found_at_its_frequency_and_amplitude(n, fs, f0, nperseg):
    amp = 3e-3
    errs_a, errs_f = [], []
    for seed in range(8):
        x = _series(n, fs, amp, f0, 2e-3, seed)
        nfft = int(2 ** np.ceil(np.log2(4 * nperseg)))
        f, p = welch_psd(x, fs, nperseg, 0.5, nfft)
        got = spectral_peaks(f, {"x": p}, fs, nperseg, {"x": "m"})
        assert got and got[0]["coordinate"] == "x" and got[0]["unit"] == "m", got
        errs_a.append(got[0]["amplitude"] / amp - 1)
        errs_f.append(got[0]["frequency_hz"] / f0 - 1)
        # scipy's Welch PSD of the same series (its periodic Hann, the same segments): the same peak
        fs_, ps_ = ss.welch(x, fs=fs, window="hann", nperseg=nperseg, noverlap=nperseg // 2, nfft=nfft, detrend="constant")
        ref = spectral_peaks(fs_, {"x": ps_}, fs, nperseg)
        assert ref[0]["frequency_hz"] == pytest.approx(got[0]["frequency_hz"], abs=1e-9)
        assert ref[0]["amplitude"] == pytest.approx(got[0]["amplitude"], rel=1e-6)
    tol_a = 0.20 if n < 1000 else 0.05            # the noise inside the main lobe, seed to seed (6 segments of 75 s: ±15 %)
    assert np.max(np.abs(errs_a)) < tol_a and abs(np.mean(errs_a)) < tol_a / 3, errs_a
    assert np.max(np.abs(errs_f)) < 0.005, errs_f


def test_noise_alone_and_a_random_walk_give_no_peak():
    found = 0
    for seed in range(40):
        for walk in (0.0, 1e-3):
            x = _series(3600, 1.0, 0.0, 0.2, 2e-3, seed, walk)
            f, p = welch_psd(x, 1.0, 600, 0.5, 4096)
            found += len(spectral_peaks(f, {"x": p}, 1.0, 600))
    assert found <= 1, found


def test_two_sinusoids_are_two_peaks_strongest_first():
    t = np.arange(7200) / 2.0
    rng = np.random.default_rng(3)
    x = 4e-3 * np.sin(2 * np.pi * 0.11 * t) + 2e-3 * np.sin(2 * np.pi * 0.31 * t) + 1e-3 * rng.standard_normal(t.size)
    f, p = welch_psd(x, 2.0, 1200, 0.5, 8192)
    got = spectral_peaks(f, {"u": p}, 2.0, 1200)
    assert [round(g["frequency_hz"], 2) for g in got[:2]] == [0.11, 0.31]
    assert got[0]["amplitude"] == pytest.approx(4e-3, rel=0.03) and got[1]["amplitude"] == pytest.approx(2e-3, rel=0.03)
