"""Parallel code-phase acquisition of GPS L1 C/A signals by FFT (circular correlation).

For each Doppler bin the samples are carrier-wiped, cut into 1 ms blocks and correlated with the
sampled code in the frequency domain (x ⊛ c = IFFT(FFT(x)·conj(FFT(c)))); |·|² is summed over
``noncoherent_ms`` blocks.  Detection is a constant-false-alarm test on the peak over the surface's
mean cell (the noise power per cell).  Under noise alone a cell normalized by its mean is Gamma
distributed with shape K (K independent blocks: a sum of K exponentials); real front ends give
fewer effective blocks (the bundled file: K ≈ 8.5 for 10 blocks, from correlated noise and the strong
satellites' cross-correlation), so K is measured on each surface by moments, K = mean²/variance of
the cells more than two chips from the peak's code phase.  With N cells the threshold is
γ = Q⁻¹(K, P_fa/N)/K (Q the regularized upper incomplete gamma): noise alone exceeds it anywhere on a
PRN's surface with probability at most ``false_alarm`` (a union bound, conservative since neighbouring
cells are correlated).  A peak within one Doppler bin of a stronger acquired satellite whose excess
over the noise is more than 10 dB below that satellite's is taken for its cross-correlation (C/A
cross-correlation is at most about −21 dB) and rejected.  The peak-to-second-peak ratio (largest
value one chip or more away) is reported too.  A finer Doppler search around each detected peak follows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammainccinv

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, CODE_LENGTH, sampled_code

#: default search: ±5 kHz of Doppler (a static receiver sees at most about ±4.5 kHz) in 250 Hz bins
DOPPLER_MAX_HZ = 5000.0
DOPPLER_STEP_HZ = 250.0
#: default false-alarm probability of one PRN's whole search surface (noise alone crossing the threshold)
FALSE_ALARM = 1e-4
#: default non-coherent integration (1 ms blocks)
NONCOHERENT_MS = 10
#: a peak this far (power ratio of the excess over noise) below a stronger satellite in the same Doppler
#: bin is taken for that satellite's cross-correlation
CROSS_CORRELATION_RATIO = 0.1
#: fine Doppler search: coherent block length (ms; a navigation bit lasts 20) and step (Hz)
FINE_BLOCK_MS = 5
FINE_STEP_HZ = 10.0


@dataclass(frozen=True)
class Acquisition:
    """One PRN's acquisition result."""

    prn: int
    acquired: bool
    doppler_hz: float          # carrier Doppler of the peak (after the fine search when acquired)
    code_phase_chips: float    # code phase at the first sample, chips in [0, 1023)
    code_phase_samples: int    # same, in samples of the input
    peak_ratio: float          # peak over second peak (≥ 1 chip away)
    peak_to_noise: float = float("inf")   # peak over the surface's mean cell (the detection statistic)
    threshold: float = float("nan")       # the detection threshold on peak_to_noise


def detection_threshold(shape_k: float, cells: int, false_alarm: float = FALSE_ALARM) -> float:
    """Threshold on peak / mean cell for cells Gamma-distributed with shape ``shape_k`` (K independent
    non-coherent blocks) such that noise alone exceeds it in any of ``cells`` cells with probability at
    most ``false_alarm`` (union bound)."""
    if not (0 < false_alarm < 1):
        raise CdgpsError(f"false_alarm: expected a probability in (0, 1), got {false_alarm!r}")
    if not (shape_k > 0 and cells >= 1):
        raise CdgpsError(f"shape_k and cells: expected a positive shape and cell count, got {shape_k!r}, {cells!r}")
    return float(gammainccinv(shape_k, false_alarm / cells) / shape_k)


def noise_shape(corr: np.ndarray, peak_sample: int, samples_per_chip: float) -> tuple[float, float]:
    """(mean cell, Gamma shape K = mean²/variance) of one PRN's (bins, n) surface, over the cells more
    than two chips from the peak's code phase (so the signal's Doppler sidelobes do not count)."""
    n = corr.shape[1]
    dist = np.abs((np.arange(n) - peak_sample + n // 2) % n - n // 2)
    rest = corr[:, dist > 2 * samples_per_chip].astype(np.float64)
    mean, var = float(rest.mean()), float(rest.var())
    return mean, (mean * mean / var if var > 0 else float("inf"))


def _blocks(x: np.ndarray, n: int, k: int) -> np.ndarray:
    if x.size < n * k:
        raise CdgpsError(f"acquisition needs {k} ms of samples ({n * k}), the input has {x.size}")
    return x[: n * k].reshape(k, n)


def _search(x, fs, prns, dopplers, k, block_ms: int = 1):
    """|correlation|² of ``block_ms`` ms blocks summed over k blocks: array (len(prns), len(dopplers), n).

    Single precision (complex64 FFTs, float32 powers): the peak search needs relative precision far
    coarser than 1e-7, and it halves the work (the search is most of a cold start's time)."""
    n = int(round(fs * 1e-3 * block_ms))
    x = _blocks(x, n, k).ravel()
    t = np.arange(n * k) / fs
    blocks_f = np.empty((len(dopplers), k, n), dtype=np.complex64)
    for i, fd in enumerate(dopplers):
        blocks_f[i] = np.fft.fft((x * np.exp(-2j * np.pi * fd * t)).astype(np.complex64).reshape(k, n), axis=1)
    out = np.empty((len(prns), len(dopplers), n))
    prod = np.empty_like(blocks_f)
    for j, prn in enumerate(prns):
        c = np.conj(np.fft.fft(sampled_code(prn, fs, n))).astype(np.complex64)
        np.multiply(blocks_f, c, out=prod)
        z = np.fft.ifft(prod, axis=2)
        out[j] = np.sum(z.real ** 2 + z.imag ** 2, axis=1)
    return out


def _peak(corr: np.ndarray, samples_per_chip: float):
    """(doppler index, sample index, ratio) of the largest value of one PRN's (bins, n) surface."""
    d, s = np.unravel_index(int(np.argmax(corr)), corr.shape)
    row = corr[d]
    n = row.size
    dist = np.abs((np.arange(n) - s + n // 2) % n - n // 2)
    second = row[dist > samples_per_chip].max()
    return int(d), int(s), float(row[s] / second) if second > 0 else float("inf")


def reject_cross_correlation(bins, peak_to_noise, hits) -> list[bool]:
    """``hits`` with every detection dropped whose coarse Doppler bin is within one of a stronger
    detection's and whose excess over the noise (peak_to_noise − 1) is below CROSS_CORRELATION_RATIO times
    that detection's: the stronger satellite's cross-correlation, not a satellite."""
    out = list(hits)
    for j in range(len(bins)):
        for i in range(len(bins)):
            if (hits[j] and hits[i] and abs(bins[i] - bins[j]) <= 1 and peak_to_noise[i] > peak_to_noise[j]
                    and peak_to_noise[j] - 1 < CROSS_CORRELATION_RATIO * (peak_to_noise[i] - 1)):
                out[j] = False
    return out


def acquire(samples: np.ndarray, fs_hz: float, prns=range(1, 33), *, if_hz: float = 0.0,
            doppler_max_hz: float = DOPPLER_MAX_HZ, doppler_step_hz: float = DOPPLER_STEP_HZ,
            noncoherent_ms: int = NONCOHERENT_MS, false_alarm: float = FALSE_ALARM) -> list[Acquisition]:
    """Search every PRN; returns one :class:`Acquisition` per PRN in the order given.

    Parameters
    ----------
    samples : ndarray, complex, shape (N,)
        Baseband (or IF) samples, at least ``noncoherent_ms`` ms of them.
    fs_hz : float
        Sample rate, Hz.
    prns : iterable of int
        (The fine search correlates 5 ms blocks coherently, so its Doppler is good to about ±10 Hz.)
    if_hz : float
        Intermediate frequency of the samples, Hz (0 for complex baseband).
    doppler_max_hz, doppler_step_hz : float
        Search range ±max and bin spacing, Hz.
    noncoherent_ms : int
        1 ms blocks summed non-coherently (detection probability at P_fa 1e-4, white noise,
        benchmarks/tracking_acquisition.py: 10 ms 0.975 at 38 dB-Hz, 0.6 at 36; 20 ms 1.0 at 36, 0.55 at 34).
    false_alarm : float
        Probability that noise alone is declared a satellite, per PRN searched (sets the threshold,
        :func:`detection_threshold`).
    """
    x = np.asarray(samples)
    if not np.iscomplexobj(x):
        x = x.astype(np.complex128)
    if not (np.isfinite(fs_hz) and fs_hz >= 2.1 * CHIP_RATE_HZ):
        raise CdgpsError(f"fs: expected a sample rate of at least 2.1 × the chip rate (2.15 MHz), got {fs_hz!r} Hz")
    prns = list(prns)
    k = int(noncoherent_ms)
    n = int(round(fs_hz * 1e-3))
    seg = x[: n * k]
    coarse = if_hz + np.arange(-doppler_max_hz, doppler_max_hz + 1e-9, doppler_step_hz)
    surf = _search(seg, fs_hz, prns, coarse, k)
    spc = fs_hz / CHIP_RATE_HZ
    peaks = []
    for j in range(len(prns)):
        d, s, ratio = _peak(surf[j], spc)
        mean, shape = noise_shape(surf[j], s, spc)
        gamma = detection_threshold(min(shape, float(k)), surf[j].size, false_alarm)
        pnr = float(surf[j][d, s] / mean) if mean > 0 else 0.0
        peaks.append((d, s, ratio, pnr, gamma))
    hits = reject_cross_correlation([p[0] for p in peaks], [p[3] for p in peaks], [p[3] > p[4] for p in peaks])
    out = []
    for j, prn in enumerate(prns):
        d, s, ratio, pnr, gamma = peaks[j]
        hit = hits[j]
        fd = coarse[d]
        if hit and k >= FINE_BLOCK_MS:
            fine = fd + np.arange(-doppler_step_hz / 2, doppler_step_hz / 2 + 1e-9, FINE_STEP_HZ)
            surf_f = _search(seg, fs_hz, [prn], fine, k // FINE_BLOCK_MS, FINE_BLOCK_MS)[0]
            d2 = int(np.argmax(surf_f.max(axis=1)))
            fd = fine[d2]
        phase = (-s / spc) % CODE_LENGTH if s else 0.0
        out.append(Acquisition(prn=prn, acquired=bool(hit), doppler_hz=float(fd - if_hz),
                               code_phase_chips=float(phase), code_phase_samples=int(s), peak_ratio=ratio,
                               peak_to_noise=pnr, threshold=gamma))
    return out
