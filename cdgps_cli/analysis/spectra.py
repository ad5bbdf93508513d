"""Spectra of the estimated motion, checked against the rate gyros, and modal identification.

Teague, How & Parkinson (1998) Sec. VI.B / Fig. 8 compare power spectral densities of the
GPS-estimated angles with gyro-derived ones.  Here:

* Welch PSDs (Hann window, 50 % overlap, zero-padded FFT) of the estimated coordinates, in their
  units² / Hz;
* for every gyro, the GPS-equivalent angle g·q (the gyro's small-angle map applied to the estimated
  coordinates) and the gyro-derived angle PSD = rate PSD / (2πf)², both in rad²/Hz, and their
  magnitude-squared coherence;
* frequency and damping of each model mode: a modal filter (the pseudo-inverse of the model's mode
  shapes on the selected coordinates) isolates the mode, and a single-mode maximum-likelihood fit
  (debiased Whittle likelihood: the expected periodogram of a finite record of a damped oscillator,
  in closed form) to the periodogram of the whole record gives fn, ζ and their 1-σ from the Fisher
  information — no resolution bias on lightly damped modes, no tuning factor;
* frequency-domain decomposition (FDD, Brincker et al. 2001): singular values of the cross-spectral
  matrix of the (standardized) coordinates; each model mode is searched within ±5 % of its frequency
  for the singular-value peak whose singular vector best matches the model's mode shape (MAC); a
  mode is "seen" when the fitted frequency is within 5 % and that MAC is high enough.

A record too long for memory is read in chunks (:func:`spectra_of_chunks`; :func:`compute_spectra` is
its one-chunk form): the Welch segments are accumulated as the chunks arrive
(:class:`WelchAccumulator`) and every sum is carried from chunk to chunk in the order of one
whole-record pass, so the numbers do not depend on the chunking, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.config.options import SPECTRA_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.rowmath import rows_matmul
from cdgps_cli.model.kinematics import gyro_matrix


@dataclass
class SpectraOptions:
    """Options of :func:`compute_spectra` (echoed in peaks.json)."""

    coords: tuple | None = None        # coordinates for PSD/FDD (default: all but the rigid one)
    segment_s: float | None = None     # Welch segment length (default: min(duration / 4, 600 s): ≥ 7 averages, so the CSD matrix has rank > 1)
    overlap: float = SPECTRA_DEFAULTS["overlap"]               # fraction of a segment
    pad: int = SPECTRA_DEFAULTS["pad"]                       # FFT zero-padding factor (finer peak location)
    band_pct: float = 5.0              # search band around each model frequency, %
    seen_pct: float = 5.0              # a mode is "seen" when identified within this %
    min_mac: float = 0.6               # … and its FDD singular vector matches the model shape
    fmax_hz: float | None = None       # upper frequency of outputs (default: Nyquist)

    def echo(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}

    def command_line(self) -> dict:
        """The options ``spectra`` and the reports take on the command line (:data:`SPECTRA_CLI_FIELDS`), by their
        names there (``--segment-s`` …)."""
        return {f"--{k.replace('_', '-')}": v for k, v in self.echo().items() if k in SPECTRA_CLI_FIELDS}

    def settings(self) -> dict:
        """The others: fixed settings with no command-line option."""
        return {k: v for k, v in self.echo().items() if k not in SPECTRA_CLI_FIELDS}


#: the :class:`SpectraOptions` fields ``spectra``, ``report run`` and ``report spectrum`` take on the command line
SPECTRA_CLI_FIELDS = ("coords", "segment_s", "overlap", "pad")


def column_sums(x: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """Σ over rows of x (N, m), the rows added one after the other to ``start`` (default 0).

    The order numpy itself sums the rows of a C-ordered (N, m ≥ 2) array (``x.sum(axis=0)``), so a
    record's sum carried over its chunks (``start``: the chunks before) is bit for bit the whole
    record's; a single column, or a Fortran-ordered array, is summed in the same sequential order
    (numpy would sum it pairwise, a tree over the whole length that a chunked reader cannot rebuild)."""
    x = np.asarray(x, dtype=float)
    if start is None:
        start = np.zeros(x.shape[1])
    if x.shape[0] == 0:
        return np.array(start, dtype=float)
    return np.cumsum(np.vstack([start[None, :], x]), axis=0)[-1]


def column_means(x: np.ndarray) -> np.ndarray:
    """Mean of each column of x (N, m) with :func:`column_sums` (= ``x.mean(axis=0)`` for m ≥ 2)."""
    x = np.asarray(x, dtype=float)
    return column_sums(x) / x.shape[0]


class WelchAccumulator:
    """Welch cross-spectral density matrix accumulated over consecutive chunks of a regular series.

    Each segment (``nperseg`` samples, ``step`` apart) is taken as soon as the chunks fed so far
    cover it, whether or not it straddles a chunk boundary: its mean removed, the periodic Hann
    window applied, zero-padded to ``nfft``, and its periodogram matrix XXᴴ added to the running
    sum, segment after segment in time order — the same arithmetic, in the same order, as one call
    on the whole record (:func:`cross_spectral_matrix`), so the result is the same bit for bit
    however the record is cut.  Memory: one segment and the part of a chunk not yet used.

    Parameters
    ----------
    mean : ndarray (m,)
        Removed from every sample before segmenting (the whole record's column means).
    fs : float, Hz
    nperseg : int
        Segment length, samples.
    overlap : float
        Fraction of a segment shared with the next one (``step = nperseg − int(nperseg·overlap)``,
        as ``scipy.signal.welch``'s ``noverlap``).
    nfft : int
        FFT length (≥ nperseg).
    """

    def __init__(self, mean: np.ndarray, fs: float, nperseg: int, overlap: float, nfft: int):
        self.mean = np.asarray(mean, dtype=float)
        self.fs, self.nperseg, self.nfft = fs, int(nperseg), int(nfft)
        self.step = max(self.nperseg - int(self.nperseg * overlap), 1)        # as scipy.signal.welch's noverlap
        self.window = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(self.nperseg) / self.nperseg)    # periodic Hann
        m = self.mean.size
        self.sum = np.zeros((self.nfft // 2 + 1, m, m), dtype=complex)
        self._product = np.empty_like(self.sum)
        self.segments = 0
        self._pending = np.zeros((0, m))         # samples from the next segment's start on
        self._next = 0                           # absolute index of the next segment's first sample
        self._start = 0                          # absolute index of _pending[0]

    def feed(self, x: np.ndarray) -> None:
        """Add the next chunk of samples, x (k, m), in time order."""
        x = np.asarray(x, dtype=float)
        xc = np.ascontiguousarray(x - self.mean)              # C order: each segment summed the same way
        buf = np.concatenate([self._pending, xc]) if len(self._pending) else xc
        w = self.window[None, :, None]
        while self._next + self.nperseg <= self._start + len(buf):
            a = self._next - self._start
            seg = buf[a:a + self.nperseg][None]
            seg = seg - seg.mean(axis=1, keepdims=True)
            X = np.fft.rfft(seg * w, n=self.nfft, axis=1)                      # (1, F, m)
            np.einsum("sfi,sfj->fij", X, X.conj(), out=self._product)
            self.sum += self._product                     # (in place: no allocation per segment)
            self.segments += 1
            self._next += self.step
        keep = min(self._next - self._start, len(buf))
        self._pending = buf[keep:].copy()
        self._start += keep

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """f (F,) Hz and G (F, m, m): the one-sided CSD, units of x² / Hz."""
        if self.segments == 0:
            raise ValueError(f"no complete Welch segment of {self.nperseg} samples was fed")
        scale = 1.0 / (self.fs * np.sum(self.window**2))
        self._product = None
        G = self.sum * scale / self.segments
        if self.nfft % 2 == 0:
            G[1:-1] *= 2.0            # one-sided: double all but DC and Nyquist
        else:
            G[1:] *= 2.0
        return np.fft.rfftfreq(self.nfft, 1.0 / self.fs), G


def cross_spectral_matrix(x: np.ndarray, fs: float, nperseg: int, overlap: float, nfft: int):
    """Welch cross-spectral density matrix G(f) of the columns of x: one feed of a
    :class:`WelchAccumulator` with the whole record (its column means from :func:`column_means`).

    Parameters
    ----------
    x : ndarray (N, m)
    fs : float, Hz
    Returns
    -------
    f : (F,) Hz;  G : (F, m, m) complex, one-sided, units of x² / Hz.
    """
    x = np.asarray(x, dtype=float)
    acc = WelchAccumulator(column_means(x), fs, nperseg, overlap, nfft)
    acc.feed(x)
    return acc.result()


def welch_psd(x: np.ndarray, fs: float, nperseg: int, overlap: float, nfft: int):
    """One-sided Welch PSD of a series (Hann, constant detrend per segment), x² / Hz.

    Equal to ``scipy.signal.welch`` with the same settings (tested); written here with
    :func:`cross_spectral_matrix` so the command line does not pay for importing scipy.signal.
    """
    f, G = cross_spectral_matrix(np.asarray(x, dtype=float)[:, None], fs, nperseg, overlap, nfft)
    return f, np.real(G[:, 0, 0])


def coherence_msc(x: np.ndarray, y: np.ndarray, fs: float, nperseg: int, overlap: float, nfft: int):
    """Magnitude-squared coherence |Gxy|² / (Gxx Gyy) from the same Welch estimates."""
    f, G = cross_spectral_matrix(np.column_stack([x, y]).astype(float), fs, nperseg, overlap, nfft)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.abs(G[:, 0, 1]) ** 2 / np.real(G[:, 0, 0] * G[:, 1, 1])
    return f, np.nan_to_num(c)


def mac(a: np.ndarray, b: np.ndarray) -> float:
    """Modal assurance criterion |aᴴb|² / (aᴴa · bᴴb)."""
    num = np.abs(np.vdot(a, b)) ** 2
    den = np.real(np.vdot(a, a) * np.vdot(b, b))
    return float(num / den) if den > 0 else 0.0


def _parabolic(f: np.ndarray, y: np.ndarray, i: int) -> float:
    """Peak location refined by a parabola through log y at i−1, i, i+1 (only at a local maximum,
    and never by more than half a bin)."""
    if 0 < i < len(y) - 1 and y[i] >= y[i - 1] and y[i] >= y[i + 1] and min(y[i - 1], y[i], y[i + 1]) > 0:
        a, b, c = np.log(y[i - 1]), np.log(y[i]), np.log(y[i + 1])
        den = a - 2 * b + c
        if den < 0:
            d = float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
            return float(f[i] + d * (f[1] - f[0]))
    return float(f[i])


def _local_floor(f: np.ndarray, p: np.ndarray, f0: float) -> float:
    """The PSD a peak at ``f0`` stands on: a straight line fitted to log p against log f over the ring around it
    (a power law: white noise flat, a random walk 1/f²), evaluated at f0; the median where the ring has too few
    positive bins to fit."""
    ok = (p > 0) & (f > 0)
    if ok.sum() < 4:
        return float(np.median(p))
    slope, icpt = np.polyfit(np.log(f[ok]), np.log(p[ok]), 1)
    return float(np.exp(icpt + slope * np.log(f0)))


#: bins of the floor's ring wanted on each side of a peak (else no floor, and no peak, there)
MIN_RING_BINS = 4


def spectral_peaks(f: np.ndarray, psd: dict, fs: float, nperseg: int, units: dict | None = None, *,
                   max_per_coordinate: int = 3, min_ratio: float = 10.0) -> list:
    """The narrow peaks of each coordinate's Welch PSD that stand out of the spectrum around them: a sinusoid's
    frequency and amplitude, whatever the motion model (a random walk's states have no model modes to look for).

    A peak is a local maximum at least ``min_ratio`` times its local floor (:func:`_local_floor` of the PSD from 3 to
    12 main-lobe half-widths on either side, the main lobe of the Hann window being ±2 fs/nperseg: a straight line in
    log–log, so the steep low-frequency slope of a random walk is no peak), above 2 half-widths from 0 Hz.  Its frequency is the maximum refined by a parabola through log PSD; its amplitude, sqrt(2 P), P the power
    above the floor over ±1.25 main-lobe half-widths (the one-sided PSD integrates to a sinusoid's A²/2, however the
    FFT is zero-padded).  At most ``max_per_coordinate`` per coordinate, the strongest first, none within two
    half-widths of a stronger one.

    Parameters
    ----------
    f : ndarray (F,)
        Frequencies, Hz, evenly spaced from 0.
    psd : dict
        {coordinate: PSD (F,), unit² / Hz}.
    fs : float
        Sample rate, Hz.
    nperseg : int
        Welch segment length, samples.
    units : dict, optional
        {coordinate: unit of its values} (``m``, ``rad``), echoed.

    Returns
    -------
    list of dict
        ``coordinate``, ``frequency_hz``, ``amplitude`` (the coordinate's unit), ``unit``, ``psd_peak``,
        ``psd_floor`` (unit²/Hz), ``ratio`` (peak / floor) and ``prominence`` (peak / the higher of the two
        troughs within 3 half-widths on either side), by coordinate then strength.
    """
    f = np.asarray(f, dtype=float)
    df = float(f[1] - f[0]) if f.size > 1 else 0.0
    half = 2.0 * fs / nperseg                                   # Hann main-lobe half-width, Hz
    out = []
    for name, p in psd.items():
        p = np.asarray(p, dtype=float)
        inner = (p[1:-1] >= p[:-2]) & (p[1:-1] > p[2:])
        cand = np.flatnonzero(inner) + 1
        cand = cand[f[cand] >= 3 * half]
        found = []
        for i in cand[np.argsort(-p[cand], kind="stable")]:
            if len(found) >= max_per_coordinate:
                break
            if any(abs(f[i] - g["frequency_hz"]) < 2 * half for g in found):
                continue
            dist = np.abs(f - f[i])
            ring = (dist >= 3 * half) & (dist <= 12 * half) & (f > 0)
            below, above = ring & (f < f[i]), ring & (f > f[i])
            if below.sum() < MIN_RING_BINS or above.sum() < MIN_RING_BINS:
                continue                          # a floor from one side only is an extrapolation, not a floor
            floor = _local_floor(f[ring], p[ring], float(f[i]))
            if not (floor > 0 and p[i] >= min_ratio * floor):
                continue
            lobe = dist <= 1.25 * half
            power = float(np.sum(np.maximum(p[lobe] - floor, 0.0)) * df)
            left, right = (f >= f[i] - 3 * half) & (f < f[i]), (f > f[i]) & (f <= f[i] + 3 * half)
            trough = max(float(p[left].min()), float(p[right].min())) if left.any() and right.any() else float(p[i])
            found.append({"coordinate": name, "frequency_hz": _parabolic(f, p, int(i)),
                          "amplitude": float(np.sqrt(2.0 * power)), "unit": (units or {}).get(name),
                          "psd_peak": float(p[i]), "psd_floor": floor, "ratio": float(p[i] / floor),
                          "prominence": float(p[i] / trough) if trough > 0 else float("inf")})
        out += found
    return out


#: a peak's fitted amplitude at least this many of its σ: a steady sinusoid through the record
STEADY_SIGMAS = 3.0
#: a peak no steady sinusoid explains is kept only this many times above the troughs on both its sides (a resonance
#: excited at random); else it is a knee of the spectrum (a smoother's roll-off read against a straight-line floor)
MIN_PROMINENCE = 3.0


def kept_peaks(peaks: list) -> list:
    """The peaks (:func:`peak_sine_fits`') worth listing: a steady sinusoid, or a resonance at least
    :data:`MIN_PROMINENCE` times above the troughs on both its sides; not the knee of a spectrum (a smoothed random
    walk's roll-off, 16 times a straight-line floor there, fitted amplitude under its σ: a real u-blox pair)."""
    return [p for p in peaks if p["steady"] or p["prominence"] >= MIN_PROMINENCE]


def peak_sine_fits(record, peaks: list, names: list, span_s: float, mean: np.ndarray | None = None) -> list:
    """``peaks`` (:func:`spectral_peaks`) with each one's amplitude from a least-squares fit of the whole record at
    its frequency: y = c₀ + c₁ τ + a cos ωt + b sin ωt (τ the time over the record's span: a random walk's drift is
    no sinusoid), amplitude sqrt(a² + b²) and its 1-σ from the fit's residual (white), its phase at the record's
    first epoch; the PSD's estimate kept as ``amplitude_psd``.  One pass over ``record`` (an iterator of (t (k,),
    q (k, n)) chunks), the normal equations summed by :func:`column_sums`: the same bits for any chunking.  The fit
    uses every epoch coherently (a five-minute record: the PSD's main lobe ±15 %, the fit a few %).  ``mean`` (n,):
    the record's column means, taken out first (a coordinate far from 0 would leave the residual sum of squares to
    cancellation).  ``steady``: whether the amplitude is at least :data:`STEADY_SIGMAS` of its σ — a sinusoid
    through the record; a resonance excited at random, or decaying, peaks in the PSD without one (``amplitude_psd``
    then describes it)."""
    if not peaks:
        return peaks
    col = np.array([names.index(p["coordinate"]) for p in peaks])
    w = 2 * np.pi * np.array([p["frequency_hz"] for p in peaks])
    iu = np.triu_indices(4)
    sums, t0, n = None, None, 0
    for t, q in record:
        if t0 is None:
            t0 = float(t[0])
        dt = t - t0
        tau = dt / span_s
        c, s_ = np.cos(np.outer(dt, w)), np.sin(np.outer(dt, w))             # (k, P)
        one = np.ones_like(c)
        X = np.stack([one, np.broadcast_to(tau[:, None], c.shape), c, s_], axis=2)     # (k, P, 4)
        y = q[:, col] - (0.0 if mean is None else np.asarray(mean, dtype=float)[col])          # (k, P)
        prod = np.concatenate([(X[:, :, iu[0]] * X[:, :, iu[1]]), X * y[:, :, None], (y * y)[:, :, None]], axis=2)
        flat = prod.reshape(len(t), -1)
        sums = column_sums(flat, sums)
        n += len(t)
    out = []
    for k, pk in enumerate(peaks):
        v = sums.reshape(len(peaks), -1)[k]
        nmat = np.zeros((4, 4))
        nmat[iu] = v[:10]
        nmat = nmat + np.triu(nmat, 1).T
        rhs, yy = v[10:14], v[14]
        try:
            cov = np.linalg.inv(nmat)
        except np.linalg.LinAlgError:
            out.append(dict(pk, amplitude_psd=pk["amplitude"], amplitude_sigma=None, phase_rad=None, steady=False))
            continue
        x = cov @ rhs
        var = max(float(yy - x @ rhs), 0.0) / max(n - 4, 1)                 # residual variance (white)
        a, b = x[2], x[3]
        amp = float(np.hypot(a, b))
        g = np.array([a, b]) / amp if amp > 0 else np.zeros(2)
        sigma = float(np.sqrt(max(g @ (var * cov[2:, 2:]) @ g, 0.0)))
        out.append(dict(pk, amplitude=amp, amplitude_psd=pk["amplitude"], amplitude_sigma=sigma,
                        phase_rad=float(np.arctan2(a, b)), steady=bool(amp >= STEADY_SIGMAS * sigma)))
    return out


def _half_power_damping(f: np.ndarray, y: np.ndarray, i: int) -> tuple[float | None, float]:
    """ζ from the half-power bandwidth of peak i of y; returns (ζ, bandwidth_hz)."""
    half = y[i] / 2.0
    lo = i
    while lo > 0 and y[lo] > half:
        lo -= 1
    hi = i
    while hi < len(y) - 1 and y[hi] > half:
        hi += 1
    if y[lo] > half or y[hi] > half:
        return None, float("nan")

    def cross(a, b):
        return f[a] + (half - y[a]) * (f[b] - f[a]) / (y[b] - y[a])

    f1, f2 = cross(lo, lo + 1), cross(hi - 1, hi)
    bw = f2 - f1
    return (float(bw / (2 * f[i])) if f[i] > 0 else None), float(bw)


def efdd(f: np.ndarray, sv: np.ndarray, vecs: np.ndarray, i_peak: int, mac_min: float = 0.8,
         max_cycles: int = 8) -> tuple[float | None, float | None, int]:
    """Enhanced FDD: SDOF bell around a peak → correlation function → frequency and damping.

    The bell is the singular value at the bins around ``i_peak`` whose singular vector has
    MAC ≥ ``mac_min`` with the peak's (contiguous); its inverse FFT is the mode's free-decay
    correlation function, whose zero crossings give the damped frequency and whose envelope
    (logarithmic decrement of the extrema) gives the damping ratio.

    Returns (natural frequency Hz, damping ratio, number of bins in the bell).
    """
    ref = vecs[i_peak]
    lo = hi = i_peak
    while lo > 1 and mac(vecs[lo - 1], ref) >= mac_min:
        lo -= 1
    while hi < len(f) - 2 and mac(vecs[hi + 1], ref) >= mac_min:
        hi += 1
    bell = np.zeros(len(f))
    bell[lo:hi + 1] = sv[lo:hi + 1]
    if hi - lo < 2:
        return None, None, hi - lo + 1
    r = np.fft.irfft(bell)
    df = f[1] - f[0]
    dt = 1.0 / (df * len(r))
    r = r[: len(r) // 2]
    r = r / r[0]
    sgn = np.signbit(r)
    zc = np.flatnonzero(sgn[1:] != sgn[:-1])
    if zc.size < 4:
        return None, None, hi - lo + 1
    # sub-sample zero crossings by linear interpolation; use the first max_cycles cycles
    zc = zc[: 2 * max_cycles + 1]
    tz = (zc + r[zc] / (r[zc] - r[zc + 1])) * dt
    half_periods = np.diff(tz)
    fd = 0.5 / float(np.mean(half_periods))
    # extrema between zero crossings → log decrement
    ext = np.array([np.max(np.abs(r[a:b + 1])) for a, b in zip(zc[:-1], zc[1:])])
    ext = ext[ext > 0]
    if ext.size < 3:
        return fd, None, hi - lo + 1
    k = np.arange(ext.size)
    slope = np.polyfit(k, np.log(ext), 1)[0]            # ln decrement per half cycle
    delta = -2.0 * slope                                # per full cycle
    zeta = float(delta / np.sqrt(4 * np.pi**2 + delta**2)) if delta > 0 else None
    fn = fd / np.sqrt(1 - zeta**2) if zeta is not None and zeta < 1 else fd
    return float(fn), zeta, hi - lo + 1


def sdof_expected_periodogram(n: int, fs: float, k: np.ndarray, variance: float, fn_hz: float,
                              zeta: float, floor: float = 0.0) -> np.ndarray:
    """Expected one-sided periodogram E[I(f_k)] of n samples of a stationary single-mode response.

    The mode is ξ̈ + 2ζω ξ̇ + ω² ξ = white noise (ω = 2π fn), sampled at ``fs``; its autocovariance
    is c(τ) = σ² e^{−ζω|τ|} (cos ω_d τ + ζ/√(1−ζ²) sin ω_d|τ|), ω_d = ω√(1−ζ²).  The periodogram
    I(f) = 2 |Σ_t x_t e^{−i2πft/fs}|² / (fs n) of a finite record has expectation
    (2/fs) Σ_{|τ|<n} (1 − |τ|/n) c(τ) e^{−i2πfτ/fs}: the spectrum blurred by the record's Fejér kernel
    (leakage), which broadens a peak whose bandwidth 2ζ fn is comparable to fs/n.  Because c is a
    sum of two complex exponentials the sum has a closed form, evaluated here at the Fourier
    frequencies f_k = k fs / n in O(len(k)) (the "debiased Whittle" likelihood, Sykulski et al. 2019,
    uses this expectation instead of the spectrum itself).

    Parameters
    ----------
    n : int, record length (samples);  fs : float, Hz
    k : ndarray of int, Fourier bin indices (1 ≤ k < n/2)
    variance : float, σ² (units²);  fn_hz : float;  zeta : float in (0, 1)
    floor : float, white-noise PSD added (units² / Hz)

    Returns
    -------
    ndarray, shape k.shape, units² / Hz
    """
    k = np.asarray(k, dtype=float)
    dt = 1.0 / fs
    w = 2.0 * np.pi * fn_hz
    root = np.sqrt(1.0 - zeta * zeta)
    a = 1.0 - 1j * zeta / root                          # c_t / σ² = Re(a r^t), t ≥ 0
    r = np.exp((-zeta * w + 1j * w * root) * dt)
    rn = r**n                                           # z^n for z = r e^{±iθ_k} (θ_k n = 2πk)
    theta = 2.0 * np.pi * k / n
    total = np.zeros(k.shape)
    for sign in (1.0, -1.0):
        z = r * np.exp(1j * sign * theta)
        one = 1.0 - z
        s0 = (1.0 - rn) / one
        s1 = (z - n * rn + (n - 1) * rn * z) / (one * one)
        total += np.real(a * (s0 - s1 / n))
    # Σ_t (1 − t/n) Re(a r^t) cos θt = total / 2;  E[I] = (2/fs) σ² (2·that − 1)
    return (2.0 / fs) * variance * (total - 1.0) + floor


def sdof_whittle_fit(y: np.ndarray, fs: float, f0_hz: float, zeta0: float, half_width_hz: float):
    """Frequency and damping of one mode from a time series by maximum (debiased Whittle) likelihood.

    Fits σ², fn, ζ and a white floor to the periodogram of ``y`` at the Fourier frequencies within
    ``f0_hz ± half_width_hz`` by minimizing Σ_k [log E_k + I_k / E_k], E_k from
    :func:`sdof_expected_periodogram` (the finite-record leakage is in the model, so lightly damped
    modes are not biased towards the resolution).  The untapered periodogram of a long record has
    nearly independent bins with exponential distribution; the 1-σ values are from the Fisher
    information Σ_k ∇log E_k ∇log E_kᵀ at the optimum.

    Parameters
    ----------
    y : ndarray (n,), one mode's response (e.g. a modal filter's output)
    fs : float, Hz;  f0_hz, zeta0 : starting values (the model's);  half_width_hz : float

    Returns
    -------
    (fn_hz, zeta, sigma_fn_hz, sigma_zeta), or four Nones when fewer than 8 bins are in the band
    or the fit fails.
    """
    from scipy.optimize import minimize

    none = (None, None, None, None)
    y = np.asarray(y, dtype=float)
    n = y.size
    X = np.fft.rfft(y - y.mean())
    periodogram = 2.0 * np.abs(X) ** 2 / (fs * n)
    df = fs / n
    k = np.arange(max(1, int(np.ceil((f0_hz - half_width_hz) / df))),
                  min(int(np.floor((f0_hz + half_width_hz) / df)), (n - 1) // 2) + 1)
    if k.size < 8:
        return none
    II = periodogram[k]
    fk = k * df
    m = k.size
    zmax = 0.9

    z0 = float(min(max(zeta0, 1e-3), 0.5))
    peak = float(np.max(sdof_expected_periodogram(n, fs, k, 1.0, f0_hz, z0)))
    # a floor below 1e-8 of the peak changes nothing: clamping it there keeps the likelihood exactly
    # flat in that direction (instead of creeping towards −∞), so the simplex converges
    floor_lo = np.log(1e-8 * peak)

    def shape(th):
        # unit-variance mode plus a floor relative to it; the scale is profiled out below
        z = zmax / (1.0 + np.exp(-th[1]))               # ζ in (0, zmax)
        return sdof_expected_periodogram(n, fs, k, 1.0, th[0], z, np.exp(max(th[2], floor_lo)))

    def nll(th):
        # Whittle negative log-likelihood with the scale s at its optimum ŝ = mean(I / shape)
        if not (fk[0] - df < th[0] < fk[-1] + df):
            return np.inf
        E = shape(th)
        if not np.all(E > 0):
            return np.inf
        return float(np.sum(np.log(E)) + m * np.log(np.mean(II / E)))

    def logit(z):
        return np.log(z / (zmax - z))

    rel_floor0 = max(np.log(max(float(np.median(II)) / max(float(np.max(II)), 1e-300), 1e-12) * 0.1 * peak),
                     floor_lo + 2.0)
    best = None
    f_peak = float(fk[int(np.argmax(II))])
    starts = [float(f0_hz)] + ([f_peak] if abs(f_peak - f0_hz) > 0.25 * half_width_hz else [])
    for f_start in starts:
        th = np.array([f_start, logit(z0), rel_floor0])
        simplex = np.vstack([th, th + [0.2 * half_width_hz, 0, 0], th + [0, 0.7, 0], th + [0, 0, 2.0]])
        r = minimize(nll, th, method="Nelder-Mead",
                     options={"xatol": 1e-7, "fatol": 1e-7, "maxiter": 2000, "maxfev": 4000, "initial_simplex": simplex})
        if np.isfinite(r.fun) and (best is None or r.fun < best.fun):
            best = r
    if best is None:
        return none
    th = best.x
    scale = float(np.mean(II / shape(th)))
    fn = float(th[0])
    zeta = float(zmax / (1.0 + np.exp(-th[1])))
    floor = scale * float(np.exp(max(th[2], floor_lo)))
    th = np.array([np.log(scale), fn, th[1], np.log(floor)])
    # Fisher information by central differences of log E (parameters: log σ², fn, ζ, log floor)
    p = np.array([th[0], fn, zeta, th[3]])
    steps = np.array([1e-4, 1e-6 * max(fn, 1e-6), 1e-4 * zeta, 1e-4])

    def logE(pp):
        return np.log(sdof_expected_periodogram(n, fs, k, np.exp(pp[0]), pp[1], pp[2], np.exp(pp[3])))

    grads = []
    for i in range(4):
        e = np.zeros(4)
        e[i] = steps[i]
        grads.append((logE(p + e) - logE(p - e)) / (2 * steps[i]))
    D = np.array(grads)
    # a floor far below the peak is not identifiable (its gradient vanishes): pinv drops that direction
    cov = np.linalg.pinv(D @ D.T, rcond=1e-10, hermitian=True)
    s_f = float(np.sqrt(cov[1, 1])) if cov[1, 1] > 0 else None
    s_z = float(np.sqrt(cov[2, 2])) if cov[2, 2] > 0 else None
    return fn, zeta, s_f, s_z


def _refuse_blind_gyros(cfg, G: np.ndarray) -> None:
    """A gyro whose rate map G (or G·U) is zero would give an all-zero GPS curve: refuse it."""
    GU = G @ np.asarray(cfg.mode_shapes)
    tol = 1e-12 * max(float(np.abs(GU).max()) if GU.size else 0.0, 1e-300)
    blind = [n for n, row in zip(cfg.gyro_names, GU) if not np.any(np.abs(row) > tol)]
    if blind:
        raise CdgpsError(f"gyro(s) {', '.join(blind)} of config {cfg.name!r} sense none of the modes (their row of "
                         "G·U is zero: no section rotation or rotation_rad along the gyro axis), so the GPS-derived "
                         "angle would be an all-zero curve; fix the config's [[gyros]] (docs/config-format.md)")


def _selected_coordinates(cfg: StructureConfig, opt: SpectraOptions) -> tuple[list, list]:
    """The config's coordinate names and the indices of those analysed (``opt.coords``, default all
    but the rigid one)."""
    names = list(cfg.coord_names)
    if not opt.coords:
        return names, [i for i in range(len(names)) if i != cfg.rigid_index]
    bad = [c for c in opt.coords if c not in names]
    if bad:
        raise CdgpsError(f"--coords: unknown coordinate(s) {', '.join(bad)} (known: {', '.join(names)})")
    return names, [names.index(c) for c in opt.coords]


#: shortest Welch segment, samples (a default segment of a short record is raised to it)
MIN_SEGMENT_SAMPLES = 16


def _segment_lengths(N: int, T: float, opt: SpectraOptions) -> tuple[int, int]:
    """Welch segment length and FFT length, samples, for N epochs T s apart (every bad setting
    listed at once)."""
    fs = 1.0 / T
    seg_s = opt.segment_s or min(N * T / 4.0, 600.0)
    problems = []
    if not seg_s > 0:
        problems.append(f"--segment-s {seg_s:g}: expected a positive segment length in seconds")
    elif opt.segment_s is not None and not MIN_SEGMENT_SAMPLES <= round(seg_s * fs) <= N:
        # was clamped silently: 1e9 s gave one segment (a rank-1 CSD), 0.001 s gave 16 samples (issue 32)
        problems.append(f"--segment-s {seg_s:g}: expected {MIN_SEGMENT_SAMPLES * T:g} s ({MIN_SEGMENT_SAMPLES} samples) "
                        f"to {N * T:g} s ({N} samples, the whole record)")
    if not opt.pad >= 1:
        problems.append(f"--pad {opt.pad:g}: expected an FFT zero-padding factor >= 1")
    if not 0 <= opt.overlap < 1:
        problems.append(f"--overlap {opt.overlap:g}: expected a fraction of a segment in [0, 1)")
    if problems:
        raise CdgpsError("; ".join(problems))
    nperseg = int(min(N, max(MIN_SEGMENT_SAMPLES, round(seg_s * fs))))
    return nperseg, int(2 ** np.ceil(np.log2(nperseg * opt.pad)))


def _record_chunks(chunks, n_names: int, N: int):
    """The (time_s, q) chunks of ``chunks()`` as float arrays, each chunk's shape checked, and the
    epochs counted against N."""
    seen = 0
    for t, qc in chunks():
        t = np.asarray(t, dtype=float)
        qc = np.asarray(qc, dtype=float)
        if qc.shape != (len(t), n_names):
            raise CdgpsError(f"q has shape {qc.shape}, expected ({len(t)}, {n_names}) for {len(t)} epochs and the "
                             "config's coordinates")
        seen += len(t)
        yield t, qc
    if seen != N:
        raise CdgpsError(f"the state record gave {seen} epochs, expected {N}")


def _with_previous(t: np.ndarray, prev: float | None) -> np.ndarray:
    return t if prev is None else np.concatenate([[prev], t])


def _median_of_counts(counts: dict) -> float:
    """``np.median`` of values given as value → count (the two middle values averaged as numpy does)."""
    keys = np.array(sorted(counts), dtype=float)
    if keys.size == 0 or np.isnan(keys).any():
        return float("nan")
    cum = np.cumsum([counts[k] for k in keys])
    n = int(cum[-1])

    def kth(i):
        return keys[int(np.searchsorted(cum, i, side="right"))]
    return float(kth(n // 2)) if n % 2 else float(np.mean([kth(n // 2 - 1), kth(n // 2)]))


class _Gyros:
    """The gyro part of the spectra: gyro matrix, rates on the epochs, GPS-equivalent angles."""

    def __init__(self, cfg, gyro_time_s, gyro_rate):
        self.G = gyro_matrix(cfg)
        self.time_s, self.rate = np.asarray(gyro_time_s, dtype=float), np.asarray(gyro_rate, dtype=float)
        self.n = self.rate.shape[1]

    def pairs(self, t: np.ndarray, qc: np.ndarray) -> np.ndarray:
        """(k, 2 n_g): the GPS angles g·q of every gyro, then its rates interpolated at t (rad, rad/s)."""
        rates = [np.interp(t, self.time_s, self.rate[:, g]) for g in range(self.n)]
        return np.column_stack([rows_matmul(qc, self.G.T), *rates])


def _scan_first(record, sel, names, gyros) -> dict:
    """Pass 1: time order, the spacings' counts, first non-finite value, column sums (and abs maxima)."""
    m = len(sel)
    out = {"prev": None, "counts": {}, "decreasing": None, "nonfinite": None, "sum": np.zeros(m),
           "absmax": np.zeros(m), "gyro_sum": np.zeros(2 * gyros.n) if gyros else None}
    for t, qc in record:
        tt = _with_previous(t, out["prev"])
        dt = np.diff(tt)
        if out["decreasing"] is None and np.any(dt <= 0):
            k = int(np.flatnonzero(dt <= 0)[0])
            out["decreasing"] = (tt[k], tt[k + 1])
        for v, c in zip(*np.unique(dt, return_counts=True)):
            out["counts"][float(v)] = out["counts"].get(float(v), 0) + int(c)
        bad = ~np.isfinite(qc)
        if out["nonfinite"] is None and bad.any():
            k, j = np.argwhere(bad)[0]
            out["nonfinite"] = (names[j], t[k])
        Y = qc[:, sel]
        out["sum"] = column_sums(Y, out["sum"])
        if len(Y):
            out["absmax"] = np.maximum(out["absmax"], np.abs(Y).max(axis=0))
        if gyros:
            out["gyro_sum"] = column_sums(gyros.pairs(t, qc), out["gyro_sum"])
        out["prev"] = tt[-1] if len(tt) else out["prev"]
    return out


def _scan_grid(record, sel, T: float, mean: np.ndarray) -> np.ndarray:
    """Pass 2: the regular grid checked against T; Σ (y − mean)² of each selected column."""
    prev, sq = None, np.zeros(len(sel))
    for t, qc in record:
        tt = _with_previous(t, prev)
        if np.any(np.abs(np.diff(tt) - T) > 1e-6 * max(T, 1)):
            raise CdgpsError("state epochs are not regularly spaced; spectra need a regular grid")
        with np.errstate(invalid="ignore", over="ignore"):     # (non-finite values are refused after this pass)
            d = qc[:, sel] - mean
            sq = column_sums(d * d, sq)
        prev = tt[-1] if len(tt) else prev
    return sq


def _coordinate_scales(sumsq: np.ndarray, absmax: np.ndarray, N: int, names: list) -> np.ndarray:
    """Standard deviation of each selected column from Σ (y − mean)² (1 for a column constant to
    rounding), refusing a record where every coordinate is constant (a static estimate has no spectrum)."""
    std = np.sqrt(sumsq / N)
    constant = std <= 1e-12 * np.maximum(1.0, absmax)     # rounding only (m or rad)
    if constant.all():
        raise CdgpsError(f"every coordinate ({', '.join(names)}) is constant over the {N} epochs "
                         "(a static estimate): spectra need a time-varying estimate "
                         "(cdgps estimate with the random-walk model, or a structure's modal states)")
    std[constant] = 1.0
    return std


class MemoryColumns:
    """(n_rows, n_cols) float64 kept in memory, written by blocks of rows and read a column at a time:
    the default store of :func:`spectra_of_chunks` (same interface as
    :class:`cdgps_cli.io.column_scratch.ColumnScratch`, which keeps them on disk)."""

    def __init__(self, n_rows: int, n_cols: int):
        self._a = np.empty((n_cols, n_rows))

    def write(self, row: int, block: np.ndarray) -> None:
        self._a[:, row:row + len(block)] = block.T

    def column(self, j: int) -> np.ndarray:
        return self._a[j]

    def close(self) -> None:
        self._a = None


def _scan_welch(record, store, sel, std, mean_std, welch: tuple, Wfilt, gyros, gyro_mean):
    """Pass 4: the standardized coordinates' CSD, every gyro pair's CSD, and the modal filter's
    outputs (N, n_modes) written to ``store`` for the whole-record fits."""
    fs, nperseg, overlap, nfft = welch
    acc = WelchAccumulator(mean_std, fs, nperseg, overlap, nfft)
    pair_acc = [WelchAccumulator(gyro_mean[[g, gyros.n + g]], *welch) for g in range(gyros.n)] if gyros else []
    a = 0
    for t, qc in record:
        Z = qc[:, sel] / std
        acc.feed(Z)
        store.write(a, rows_matmul(Z, Wfilt.T))
        if gyros:
            P = gyros.pairs(t, qc)
            for g, pa in enumerate(pair_acc):
                pa.feed(P[:, [g, gyros.n + g]])
        a += len(t)
    return acc.result(), [pa.result()[1] for pa in pair_acc]


def _gyro_psds(cfg, f, pair_G: list, psd: dict) -> None:
    """Each gyro's angle PSD (rate PSD / (2πf)²), the GPS angle PSD it senses and their coherence
    (from the CSD of the pair), added to ``psd``."""
    for gname, G in zip(cfg.gyro_names, pair_G):
        with np.errstate(divide="ignore", invalid="ignore"):
            psd[f"gyro_{gname}"] = np.where(f > 0, np.real(G[:, 1, 1]) / (2 * np.pi * f) ** 2, np.nan)
            psd[f"gps_{gname}"] = np.real(G[:, 0, 0])
            c = np.abs(G[:, 0, 1]) ** 2 / np.real(G[:, 0, 0] * G[:, 1, 1])
        psd[f"coherence_{gname}"] = np.nan_to_num(c)


def _fdd_peak(f, U_sv, S_sv, band, phi) -> dict:
    """The FDD peak in ``band``: among the first three singular values, the frequency whose value ×
    MAC with the model shape ``phi`` is largest (``fdd_peak_hz``, ``mac``, ``singular_value``; {} when
    the band is empty)."""
    best = _fdd_best(U_sv, S_sv, band, phi)
    if best is None:
        return {}
    _, k, i, m_mac = best
    return {"fdd_peak_hz": _parabolic(f, S_sv[:, k], i), "mac": float(m_mac), "singular_value": k + 1}


def _fdd_best(U_sv, S_sv, band, phi):
    """``(score, singular value index k, frequency bin i, MAC)`` of :func:`_fdd_peak`, or None."""
    best = None
    idx = np.flatnonzero(band)
    for k in range(min(3, S_sv.shape[1])):
        if idx.size == 0:
            continue
        macs = np.array([mac(U_sv[i, :, k], phi) for i in idx])
        score = S_sv[idx, k] * macs
        ib = int(np.argmax(score))
        if best is None or score[ib] > best[0]:
            best = (score[ib], k, int(idx[ib]), macs[ib])
    return best


def fdd_shapes(cfg, opt, f, U_sv, S_sv, Um, std, names) -> dict:
    """The FDD singular vectors at each mode's peak (the shapes the MAC column compares), for a MAC
    matrix against every model shape: ``vectors`` {mode number: (m,) complex, standardized
    coordinates}, ``model`` (m, n_modes) the model shapes standardized alike, ``scales`` (m,) the
    coordinate scales (coordinate = standardized × scale), ``coordinates`` (m,) names."""
    vectors = {}
    for j, fm in enumerate(cfg.mode_frequency_hz):
        if fm <= 0 or np.linalg.norm(Um[:, j]) == 0:
            continue
        band = (f >= fm * (1 - opt.band_pct / 100)) & (f <= fm * (1 + opt.band_pct / 100))
        best = _fdd_best(U_sv, S_sv, band, Um[:, j])
        if best is not None:
            vectors[j + 1] = U_sv[best[2], :, best[1]]
    return {"vectors": vectors, "model": Um, "scales": std, "coordinates": list(names)}


def _gyro_peak(gy: dict, shape, f, psd: dict, center_hz: float, band_pct: float) -> dict:
    """The mode's peak in the gyro that sees it best (``gyro``, ``coherence``, and ``gyro_hz`` when the
    maximum is inside the band); {} when no gyro sees the mode or the band is empty."""
    weights = np.abs(gy["G"] @ shape)
    visible = np.linalg.norm(gy["G"], axis=1) * np.linalg.norm(shape) * 1e-6
    if not np.any(weights > visible):
        return {}
    gname = gy["names"][int(np.argmax(weights))]
    gb = (f >= center_hz * (1 - band_pct / 100)) & (f <= center_hz * (1 + band_pct / 100))
    if not gb.any():
        return {}
    pg = psd[f"gyro_{gname}"]
    band_idx = np.flatnonzero(gb)
    ii = int(band_idx[np.nanargmax(pg[gb])])
    out = {"gyro": gname, "coherence": float(psd[f"coherence_{gname}"][ii])}
    # a maximum on the band edge is the flank of something else, not a peak
    if band_idx[0] < ii < band_idx[-1]:
        out["gyro_hz"] = _parabolic(f, pg, ii)
    return out


def compute_spectra(cfg: StructureConfig, time_s: np.ndarray, q: np.ndarray,
                    gyro_time_s: np.ndarray | None = None, gyro_rate: np.ndarray | None = None,
                    opt: SpectraOptions | None = None) -> dict:
    """PSDs, FDD modal identification and GPS–gyro comparison of a whole record in memory: one
    chunk of :func:`spectra_of_chunks` (the same numbers, bit for bit, as any chunking of it).

    Parameters
    ----------
    cfg : StructureConfig
    time_s : (N,) regular epochs, s
    q : (N, n_q) estimated generalized coordinates
    gyro_time_s : (M,), gyro_rate : (M, n_g) rad/s, optional
    opt : SpectraOptions

    Returns
    -------
    dict with ``f_hz``, ``psd`` (name → array), ``fdd_sv`` (F, k), ``modes`` (list), ``settings``.
    """
    time_s = np.asarray(time_s, dtype=float)
    names, _ = _selected_coordinates(cfg, opt or SpectraOptions())
    if np.shape(q) != (len(time_s), len(names)):
        raise CdgpsError(f"q has shape {np.shape(q)}, expected ({len(time_s)}, {len(names)}) for {len(time_s)} epochs "
                         "and the config's coordinates")
    return spectra_of_chunks(cfg, lambda: iter([(time_s, q)]), len(time_s), gyro_time_s, gyro_rate, opt)


def spectra_of_chunks(cfg: StructureConfig, chunks, n_epochs: int, gyro_time_s: np.ndarray | None = None,
                      gyro_rate: np.ndarray | None = None, opt: SpectraOptions | None = None,
                      columns=MemoryColumns) -> dict:
    """:func:`compute_spectra` of a record read in consecutive chunks of epochs, in bounded memory.

    ``chunks()`` returns a new iterator of ``(time_s (k,), q (k, n_q))`` chunks, first to last, each
    time it is called: the record is read four times (time grid and column sums; spreads; the
    standardized coordinates' sums; Welch segments), every sum carried from chunk to chunk in the
    order one whole-record pass adds it (:func:`column_sums`, :class:`WelchAccumulator`,
    :func:`cdgps_cli.core.rowmath.rows_matmul`), so any chunking gives the same numbers bit for bit.
    Held beside one chunk: the Welch sums, and the modal filter's output (8 bytes per epoch and mode)
    whose whole-record periodogram the mode fits need, one mode at a time, in ``columns(N, n_modes)``
    (default :class:`MemoryColumns`; the command line keeps them on disk).

    Parameters
    ----------
    cfg : StructureConfig
    chunks : callable () -> iterator of (ndarray, ndarray)
    n_epochs : int, N
    gyro_time_s, gyro_rate, opt : as :func:`compute_spectra`
    columns : callable (n_rows, n_cols) -> store with ``write(row, block)``, ``column(j)``, ``close()``
    """
    opt = opt or SpectraOptions()
    names, sel = _selected_coordinates(cfg, opt)
    N = int(n_epochs)
    if opt.fmax_hz is not None and not opt.fmax_hz > 0:
        raise CdgpsError(f"fmax_hz must be positive, got {opt.fmax_hz!r}")
    if N < 16:
        raise CdgpsError(f"only {N} epochs: too short for spectra")
    gyros = None
    if gyro_rate is not None and np.size(gyro_rate) and len(cfg.gyro_names):
        gyros = _Gyros(cfg, gyro_time_s, gyro_rate)

    def record():
        return _record_chunks(chunks, len(names), N)
    first = _scan_first(record(), sel, names, gyros)
    if first["decreasing"] is not None:
        a, b = first["decreasing"]
        raise CdgpsError(f"state epochs are not increasing (at {a:g} s → {b:g} s)")
    T = _median_of_counts(first["counts"])
    mean = first["sum"] / N
    sumsq = _scan_grid(record(), sel, T, mean)
    if first["nonfinite"] is not None:
        name, t = first["nonfinite"]
        raise CdgpsError(f"the estimate has a non-finite value ({name} at {t:g} s); spectra need finite data")
    fs = 1.0 / T
    nperseg, nfft = _segment_lengths(N, T, opt)
    std = _coordinate_scales(sumsq, first["absmax"], N, [names[i] for i in sel])
    sum_std = np.zeros(len(sel))
    for _, qc in record():
        sum_std = column_sums(qc[:, sel] / std, sum_std)
    Um = np.asarray(cfg.mode_shapes)[sel] / std[:, None]      # model mode shapes, standardized like the data
    Wfilt = np.linalg.pinv(Um)                              # modal filter: ξ̂ = U⁺ y (standardized)
    if gyros:
        _refuse_blind_gyros(cfg, gyros.G)
    welch = (fs, nperseg, opt.overlap, nfft)
    store = columns(N, Wfilt.shape[0])
    try:
        (f, G), pair_G = _scan_welch(record(), store, sel, std, sum_std / N, welch, Wfilt, gyros,
                                     first["gyro_sum"] / N if gyros else None)
        res = _spectra_result(cfg, opt, names, sel, N, T, nperseg, nfft, f, G, std, Um, store, gyros, pair_G)
        mean_all = np.zeros(len(names))
        mean_all[sel] = first["sum"] / N                  # (the first pass's sums are of the selected coordinates)
        res["peaks"] = kept_peaks(peak_sine_fits(record(), res["peaks"], names, N * T, mean=mean_all))
        return res
    finally:
        store.close()


def _spectra_result(cfg, opt, names, sel, N, T, nperseg, nfft, f, G, std, Um, store, gyros, pair_G) -> dict:
    """PSDs, FDD and the modes identified, from the record's CSD matrices and modal series."""
    fs = 1.0 / T
    psd = {f"gps_{names[i]}": np.real(G[:, j, j]) * std[j] ** 2 for j, i in enumerate(sel)}
    U_sv, S_sv = np.linalg.svd(G)[:2]                       # (F, m, m), (F, m)
    gy = None
    if gyros:
        _gyro_psds(cfg, f, pair_G, psd)
        gy = {"names": list(cfg.gyro_names), "G": gyros.G}
    modes = [_identify_mode(cfg, j, Um, store.column(j), f, U_sv, S_sv, gy, psd, fs, N, opt)
             for j in range(len(cfg.mode_names)) if cfg.mode_frequency_hz[j] > 0]
    fmax = min(opt.fmax_hz or fs / 2, fs / 2)
    keep = (f > 0) & (f <= fmax)
    coords = [names[i] for i in sel]
    below = f <= fmax                             # peaks chosen among the frequencies shown only
    peaks = spectral_peaks(f[below], {c: psd[f"gps_{c}"][below] for c in coords}, fs, nperseg,
                           {c: cfg.coord_unit(c) for c in coords})
    return {
        "f_hz": f[keep], "psd": {k: v[keep] for k, v in psd.items()},
        "fdd_sv": S_sv[keep, : min(3, S_sv.shape[1])],
        "modes": modes, "peaks": peaks,
        "fdd_shapes": fdd_shapes(cfg, opt, f, U_sv, S_sv, Um, std, [names[i] for i in sel]),
        "settings": {**opt.echo(), "sample_rate_hz": fs, "duration_s": N * T, "segment_s": nperseg / fs,
                     "segments": int((N - nperseg) // max(int(round(nperseg * (1 - opt.overlap))), 1) + 1),
                     "nfft": nfft, "resolution_hz": 1.44 * fs / nperseg,      # Hann half-power main-lobe width
                     "coordinates": [names[i] for i in sel], "window": "hann"},
    }


def _identify_mode(cfg, j, Um, y, f, U_sv, S_sv, gy, psd, fs, N, opt) -> dict:
    """Mode j of the model identified: whole-record fit of its modal filter output ``y``, FDD peak,
    gyro peak."""
    mname, fm, tau = cfg.mode_names[j], cfg.mode_frequency_hz[j], cfg.mode_time_constant_s[j]
    zeta_model = 1.0 / (2 * np.pi * fm * tau)
    entry = {"mode": mname, "number": j + 1, "model_hz": float(fm), "model_damping": float(zeta_model), "gps_hz": None,
             "gyro_hz": None, "error_pct": None, "damping": None, "damping_resolution_limited": None,
             "mac": None, "singular_value": None, "fdd_peak_hz": None, "seen": False, "gyro": None}
    phi = Um[:, j]
    if np.linalg.norm(phi) == 0:
        return entry
    # 1. modal filter + single-mode maximum-likelihood fit on the whole record
    bw_model = 2 * zeta_model * fm
    half = max(5 * bw_model, fm * opt.band_pct / 100, 20 * fs / N)
    f_fit, z_fit, f_sig, z_sig = sdof_whittle_fit(y, fs, fm, zeta_model, half)
    # 2. FDD: singular-value peak in the band whose vector matches the model shape
    band = (f >= fm * (1 - opt.band_pct / 100)) & (f <= fm * (1 + opt.band_pct / 100))
    entry.update(_fdd_peak(f, U_sv, S_sv, band, phi))
    f_id = f_fit if f_fit is not None else entry["fdd_peak_hz"]
    if f_id is not None:
        err = 100.0 * (f_id - fm) / fm
        entry.update(gps_hz=f_id, gps_hz_sigma=f_sig if f_fit is not None else None, error_pct=err, damping=z_fit,
                     damping_sigma=z_sig if f_fit is not None else None,
                     damping_resolution_limited=bool(z_fit is None or 2 * z_fit * f_id < 2 * fs / N),
                     seen=bool(abs(err) <= opt.seen_pct and (entry["mac"] or 0) >= opt.min_mac))
    if gy is not None:
        entry.update(_gyro_peak(gy, np.asarray(cfg.mode_shapes)[:, j], f, psd, entry["gps_hz"] or fm, opt.band_pct))
    return entry
