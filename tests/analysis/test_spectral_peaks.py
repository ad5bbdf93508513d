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


def _chunks(t, x, size):
    return iter([(t[a:a + size], x[a:a + size, None]) for a in range(0, t.size, size)])


def test_the_sine_fit_is_the_whole_record_s_least_squares_for_any_chunking():
    """:func:`peak_sine_fits`: the same bits however the record is cut; the fitted sinusoid is numpy's least squares
    of the same model (an independent solve; there on a record that also drifts as a random walk); on a five-minute
    record of a 3 mm, 0.2 Hz sine in 1 mm of white noise the amplitude errors over 200 seeds are their own σ (z-scores
    of unit spread), where the PSD's main lobe scatters ±15 %."""
    from cdgps_cli.analysis.spectra import peak_sine_fits

    fs, n, f0, amp = 1.0, 301, 0.2, 3e-3
    t = 1.4e9 + np.arange(n) / fs
    z = []
    for seed in range(200):
        x = _series(n, fs, amp, f0, 1e-3, seed, walk=2e-4 if seed == 0 else 0.0)
        peak = [{"coordinate": "x", "frequency_hz": f0, "amplitude": 1.0}]
        got = [peak_sine_fits(_chunks(t, x, size), peak, ["x"], n / fs)[0] for size in (n, 7, 64)]
        assert got[0] == got[1] == got[2] and got[0]["amplitude_psd"] == 1.0 and got[0]["steady"]
        g = got[0]
        if seed == 0:
            dt = t - t[0]
            A = np.column_stack([np.ones(n), dt / (n / fs), np.cos(2 * np.pi * f0 * dt), np.sin(2 * np.pi * f0 * dt)])
            coef = np.linalg.lstsq(A, x, rcond=None)[0]
            assert g["amplitude"] == pytest.approx(np.hypot(coef[2], coef[3]), rel=1e-9)
            assert g["phase_rad"] == pytest.approx(np.arctan2(coef[2], coef[3]), abs=1e-9)
        if seed:                           # (seed 0 drifts: a random walk, which the white σ over-covers)
            z.append((g["amplitude"] - amp) / g["amplitude_sigma"])
    z = np.array(z)
    assert abs(z.mean()) < 0.25 and 0.8 < z.std() < 1.2, (z.mean(), z.std())


def test_a_coordinate_far_from_zero_keeps_its_sigma():
    """The record's mean is taken out before the sums (found by a review: at an offset of 10⁶ the residual sum of
    squares cancelled, σ 3.7 mm for 0.075; at 4·10⁶, 0)."""
    from cdgps_cli.analysis.spectra import peak_sine_fits

    n, f0 = 301, 0.2
    t = np.arange(n, dtype=float)
    x = _series(n, 1.0, 3e-3, f0, 1e-3, 5)
    peak = [{"coordinate": "x", "frequency_hz": f0, "amplitude": 1.0}]
    ref = peak_sine_fits(_chunks(t, x, 50), peak, ["x"], float(n), mean=np.array([x.mean()]))[0]
    for offset in (1e4, 1e6, 4e6):
        y = x + offset
        got = peak_sine_fits(_chunks(t, y, 50), peak, ["x"], float(n), mean=np.array([y.mean()]))[0]
        assert got["amplitude"] == pytest.approx(ref["amplitude"], rel=1e-6)
        assert got["amplitude_sigma"] == pytest.approx(ref["amplitude_sigma"], rel=1e-3), offset


def test_peaks_are_chosen_below_the_highest_frequency_shown():
    """Peaks above ``fmax`` took the three places of a coordinate before it was applied (a review): a 2 mm sine at
    0.1 Hz under three stronger ones above 0.3 Hz was not listed."""
    fs, n = 2.0, 7200
    t = np.arange(n) / fs
    rng = np.random.default_rng(2)
    x = 2e-3 * np.sin(2 * np.pi * 0.1 * t) + sum(8e-3 * np.sin(2 * np.pi * f * t) for f in (0.4, 0.55, 0.7))
    x = x + 5e-4 * rng.standard_normal(n)
    f, p = welch_psd(x, fs, 1200, 0.5, 8192)
    below = f <= 0.3
    got = spectral_peaks(f[below], {"x": p[below]}, fs, 1200)
    assert [round(g["frequency_hz"], 2) for g in got] == [0.1]


def test_no_peak_on_a_random_walk_s_steep_low_end():
    """The repository's own simulated GNSS random-walk STATES (tests/data/format-2026-12-03, 120 s at 1 Hz): the
    ring below a candidate was empty and the floor extrapolated from above onto the 1/f² slope — a 'peak' at
    0.18 Hz, 20 × its floor, amplitude 0.02 ± 0.12 mm (a review)."""
    from pathlib import Path

    from tests._shared import run_cli

    states = Path(__file__).resolve().parents[1] / "data" / "format-2026-12-03" / "gnss-states.mcap"
    import json
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        r = run_cli("spectra", states, "-o", d, "--json", "-q")
        assert r.exit_code == 0, r.output
        assert json.loads(r.output[r.output.index("{"):])["peaks"] == []


def test_the_knee_of_a_smoothed_random_walk_is_no_peak():
    """A random walk low-passed (the roll-off of a smoother) stands, near its knee, 10 times above a straight-line
    floor fitted across it: candidates (11 over 40 records here); none is a steady sinusoid nor stands above the
    troughs on both its sides, so none is listed (a sweep of real u-blox files found such a peak at 0.028 Hz in
    smoothed random-walk states, fitted amplitude 0.22 ± 0.41 mm)."""
    from scipy import signal as ss

    from cdgps_cli.analysis.spectra import kept_peaks, peak_sine_fits

    found = kept = 0
    b, a = ss.butter(4, 0.06)
    for seed in range(40):
        rng = np.random.default_rng(seed)
        n = 1200
        x = ss.filtfilt(b, a, np.cumsum(rng.standard_normal(n)) * 1e-3) + 2e-4 * rng.standard_normal(n)
        f, p = welch_psd(x, 1.0, 300, 0.5, 2048)
        cand = spectral_peaks(f, {"x": p}, 1.0, 300)
        t = np.arange(n, dtype=float)
        found += len(cand)
        kept += len(kept_peaks(peak_sine_fits(iter([(t, x[:, None])]), cand, ["x"], float(n), mean=np.array([x.mean()]))))
    assert found > 0 and kept == 0, (found, kept)
