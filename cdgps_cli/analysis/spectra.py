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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.config.options import SPECTRA_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
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


def _segments(x: np.ndarray, nperseg: int, step: int) -> np.ndarray:
    n = x.shape[0]
    starts = np.arange(0, n - nperseg + 1, step)
    return np.stack([x[s:s + nperseg] for s in starts])          # (S, nperseg, m)


def cross_spectral_matrix(x: np.ndarray, fs: float, nperseg: int, overlap: float, nfft: int):
    """Welch cross-spectral density matrix G(f) of the columns of x.

    Parameters
    ----------
    x : ndarray (N, m)
    fs : float, Hz
    Returns
    -------
    f : (F,) Hz;  G : (F, m, m) complex, one-sided, units of x² / Hz.
    """
    step = max(nperseg - int(nperseg * overlap), 1)          # as scipy.signal.welch's noverlap
    seg = _segments(x - x.mean(axis=0), nperseg, step)
    seg = seg - seg.mean(axis=1, keepdims=True)
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(nperseg) / nperseg)    # periodic Hann
    X = np.fft.rfft(seg * w[None, :, None], n=nfft, axis=1)      # (S, F, m)
    scale = 1.0 / (fs * np.sum(w**2))
    G = np.einsum("sfi,sfj->fij", X, X.conj()) * scale / seg.shape[0]
    if nfft % 2 == 0:
        G[1:-1] *= 2.0            # one-sided: double all but DC and Nyquist
    else:
        G[1:] *= 2.0
    f = np.fft.rfftfreq(nfft, 1.0 / fs)
    return f, G


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


def _grid_step_s(time_s: np.ndarray, q: np.ndarray, names: list, opt: SpectraOptions) -> float:
    """The epochs' regular spacing, s, after checking q's shape, finiteness and the grid."""
    N = len(time_s)
    if np.shape(q) != (N, len(names)):
        raise CdgpsError(f"q has shape {np.shape(q)}, expected ({N}, {len(names)}) for {N} epochs and the config's coordinates")
    if opt.fmax_hz is not None and not opt.fmax_hz > 0:
        raise CdgpsError(f"fmax_hz must be positive, got {opt.fmax_hz!r}")
    if N < 16:
        raise CdgpsError(f"only {N} epochs: too short for spectra")
    dt = np.diff(time_s)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        raise CdgpsError(f"state epochs are not increasing (at {time_s[k]:g} s → {time_s[k + 1]:g} s)")
    T = float(np.median(dt))
    if np.any(np.abs(dt - T) > 1e-6 * max(T, 1)):
        raise CdgpsError("state epochs are not regularly spaced; spectra need a regular grid")
    bad = ~np.isfinite(np.asarray(q, dtype=float))
    if bad.any():
        k, j = np.argwhere(bad)[0]
        raise CdgpsError(f"the estimate has a non-finite value ({names[j]} at {time_s[k]:g} s); spectra need finite data")
    return T


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


def _coordinate_scales(Y: np.ndarray, names: list) -> np.ndarray:
    """Standard deviation of each column of Y (1 for a column constant to rounding), refusing a
    record where every coordinate is constant (a static estimate has no spectrum)."""
    std = Y.std(axis=0)
    constant = std <= 1e-12 * np.maximum(1.0, np.abs(Y).max(axis=0))     # rounding only (m or rad)
    if constant.all():
        raise CdgpsError(f"every coordinate ({', '.join(names)}) is constant over the {len(Y)} epochs "
                         "(a static estimate): spectra need a time-varying estimate "
                         "(cdgps estimate with the random-walk model, or a structure's modal states)")
    std[constant] = 1.0
    return std


def _gyro_spectra(cfg: StructureConfig, time_s, q, gyro_time_s, gyro_rate, psd: dict, welch: tuple) -> dict:
    """Each gyro's angle PSD (rate PSD / (2πf)²), the GPS angle PSD it senses and their coherence,
    added to ``psd``; returns the gyro names and matrix G (angles = G q).  ``welch``: (fs, nperseg,
    overlap, nfft)."""
    fs, nperseg, overlap, nfft = welch
    Gm = gyro_matrix(cfg)
    _refuse_blind_gyros(cfg, Gm)
    rates = np.column_stack([np.interp(time_s, gyro_time_s, gyro_rate[:, g]) for g in range(gyro_rate.shape[1])])
    gps_ang = q @ Gm.T
    for g, gname in enumerate(cfg.gyro_names):
        fw, pr = welch_psd(rates[:, g], fs, nperseg, overlap, nfft)
        with np.errstate(divide="ignore", invalid="ignore"):
            psd[f"gyro_{gname}"] = np.where(fw > 0, pr / (2 * np.pi * fw) ** 2, np.nan)
        _, pa = welch_psd(gps_ang[:, g], fs, nperseg, overlap, nfft)
        psd[f"gps_{gname}"] = pa
        _, coh = coherence_msc(gps_ang[:, g], rates[:, g], fs, nperseg, overlap, nfft)
        psd[f"coherence_{gname}"] = coh
    return {"names": list(cfg.gyro_names), "G": Gm}


def _fdd_peak(f, U_sv, S_sv, band, phi) -> dict:
    """The FDD peak in ``band``: among the first three singular values, the frequency whose value ×
    MAC with the model shape ``phi`` is largest (``fdd_peak_hz``, ``mac``, ``singular_value``; {} when
    the band is empty)."""
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
    if best is None:
        return {}
    _, k, i, m_mac = best
    return {"fdd_peak_hz": _parabolic(f, S_sv[:, k], i), "mac": float(m_mac), "singular_value": k + 1}


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
    """PSDs, FDD modal identification and GPS–gyro comparison.

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
    opt = opt or SpectraOptions()
    names, sel = _selected_coordinates(cfg, opt)
    N = len(time_s)
    T = _grid_step_s(time_s, q, names, opt)
    fs = 1.0 / T
    duration = N * T
    nperseg, nfft = _segment_lengths(N, T, opt)
    resolution = 1.44 * fs / nperseg                     # Hann half-power main-lobe width
    Y = q[:, sel]
    std = _coordinate_scales(Y, [names[i] for i in sel])
    f, G = cross_spectral_matrix(Y / std, fs, nperseg, opt.overlap, nfft)
    fmax = min(opt.fmax_hz or fs / 2, fs / 2)
    keep = (f > 0) & (f <= fmax)
    psd = {}
    for j, i in enumerate(sel):
        psd[f"gps_{names[i]}"] = np.real(G[:, j, j]) * std[j] ** 2
    sv_u = np.linalg.svd(G)
    U_sv, S_sv = sv_u[0], sv_u[1]                          # (F, m, m), (F, m)
    # model mode shapes on the selected coordinates, standardized like the data
    Um = np.asarray(cfg.mode_shapes)[sel] / std[:, None]
    gy = None
    if gyro_rate is not None and gyro_rate.size and len(cfg.gyro_names):
        gy = _gyro_spectra(cfg, time_s, q, gyro_time_s, gyro_rate, psd, (fs, nperseg, opt.overlap, nfft))
    modes = []
    Ystd = Y / std
    Wfilt = np.linalg.pinv(Um)                              # modal filter: ξ̂ = U⁺ y (standardized)
    for j, (mname, fm, tau) in enumerate(zip(cfg.mode_names, cfg.mode_frequency_hz, cfg.mode_time_constant_s)):
        if fm <= 0:
            continue
        zeta_model = 1.0 / (2 * np.pi * fm * tau)
        entry = {"mode": mname, "number": j + 1, "model_hz": float(fm), "model_damping": float(zeta_model), "gps_hz": None,
                 "gyro_hz": None, "error_pct": None, "damping": None, "damping_resolution_limited": None,
                 "mac": None, "singular_value": None, "fdd_peak_hz": None, "seen": False, "gyro": None}
        phi = Um[:, j]
        if np.linalg.norm(phi) == 0:
            modes.append(entry)
            continue
        # 1. modal filter + single-mode maximum-likelihood fit on the whole record
        bw_model = 2 * zeta_model * fm
        half = max(5 * bw_model, fm * opt.band_pct / 100, 20 * fs / N)
        f_fit, z_fit, f_sig, z_sig = sdof_whittle_fit(Ystd @ Wfilt[j], fs, fm, zeta_model, half)
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
        modes.append(entry)
    return {
        "f_hz": f[keep], "psd": {k: v[keep] for k, v in psd.items()},
        "fdd_sv": S_sv[keep, : min(3, S_sv.shape[1])],
        "modes": modes,
        "settings": {**opt.echo(), "sample_rate_hz": fs, "duration_s": duration, "segment_s": nperseg / fs,
                     "segments": int((N - nperseg) // max(int(round(nperseg * (1 - opt.overlap))), 1) + 1),
                     "nfft": nfft, "resolution_hz": resolution, "coordinates": [names[i] for i in sel],
                     "window": "hann"},
    }
