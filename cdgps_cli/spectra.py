"""Spectra of the estimated motion, checked against the rate gyros, and modal identification.

Teague, How & Parkinson (1998) Sec. VI.B / Fig. 8 compare power spectral densities of the
GPS-estimated angles with gyro-derived ones.  Here:

* Welch PSDs (Hann window, 50 % overlap, zero-padded FFT) of the estimated coordinates, in their
  units² / Hz;
* for every gyro, the GPS-equivalent angle g·q (the gyro's small-angle map applied to the estimated
  coordinates) and the gyro-derived angle PSD = rate PSD / (2πf)², both in rad²/Hz, and their
  magnitude-squared coherence;
* frequency-domain decomposition (FDD, Brincker et al. 2001): singular values of the cross-spectral
  matrix of the (standardized) coordinates; each model mode is searched within ±5 % of its frequency
  for the singular-value peak whose singular vector best matches the model's mode shape (MAC), the
  frequency refined by parabolic interpolation, the damping from the half-power bandwidth of that
  singular value (flagged when it is not wider than the frequency resolution).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


from .config import StructureConfig
from .errors import CdgpsError
from .kinematics import gyro_matrix


@dataclass
class SpectraOptions:
    """Options of :func:`compute_spectra` (echoed in peaks.json)."""

    coords: tuple | None = None        # coordinates for PSD/FDD (default: all but the rigid one)
    segment_s: float | None = None     # Welch segment length (default: min(duration / 4, 600 s): ≥ 7 averages, so the CSD matrix has rank > 1)
    overlap: float = 0.5               # fraction of a segment
    pad: int = 4                       # FFT zero-padding factor (finer peak location)
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


def sdof_fit(f: np.ndarray, p: np.ndarray, f0: float, zeta0: float, half_width_hz: float,
             correlated_bins: int = 1, with_sigma: bool = False):
    """Least-squares fit of a single-mode displacement PSD, A / ((fn² − f²)² + (2 ζ fn f)²) + floor,
    to ``p`` (log domain) within ``f0 ± half_width_hz``.  Returns (fn, ζ) or (None, None); with
    ``with_sigma`` also the 1-σ of fn from the fit (bins treated as ``correlated_bins``-fold correlated)."""
    sel = (f >= f0 - half_width_hz) & (f <= f0 + half_width_hz) & (p > 0)
    if sel.sum() < 5:
        return (None, None, None) if with_sigma else (None, None)
    ff, pp = f[sel], p[sel]

    def model(x):
        logA, fn, z, logfloor = x
        return np.logaddexp(logA - np.log((fn**2 - ff**2) ** 2 + (2 * z * fn * ff) ** 2), logfloor)

    i = int(np.argmax(pp))
    z0 = min(max(zeta0, 1e-3), 0.3)
    x0 = [np.log(pp[i]) + np.log((2 * z0 * f0 * f0) ** 2), ff[i], z0, np.log(max(np.min(pp), 1e-300))]
    lo = [-np.inf, f0 - half_width_hz, 1e-4, -np.inf]
    hi = [np.inf, f0 + half_width_hz, 0.5, np.inf]
    x0[1] = min(max(x0[1], lo[1] + 1e-12), hi[1] - 1e-12)
    from scipy.optimize import least_squares

    try:
        r = least_squares(lambda x: model(x) - np.log(pp), x0, bounds=(lo, hi), x_scale="jac")
    except ValueError:
        return (None, None, None) if with_sigma else (None, None)
    if not with_sigma:
        return float(r.x[1]), float(r.x[2])
    dof = max(len(pp) - 4, 1)
    s2 = float(r.fun @ r.fun) / dof * correlated_bins
    try:
        cov = np.linalg.pinv(r.jac.T @ r.jac) * s2
        sig = float(np.sqrt(max(cov[1, 1], 0.0)))
    except np.linalg.LinAlgError:
        sig = None
    return float(r.x[1]), float(r.x[2]), sig


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
    names = list(cfg.coord_names)
    if opt.coords:
        bad = [c for c in opt.coords if c not in names]
        if bad:
            raise CdgpsError(f"--coords: unknown coordinate(s) {', '.join(bad)} (known: {', '.join(names)})")
        sel = [names.index(c) for c in opt.coords]
    else:
        sel = [i for i in range(len(names)) if i != cfg.rigid_index]
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
    fs = 1.0 / T
    duration = N * T
    seg_s = opt.segment_s or min(duration / 4.0, 600.0)
    if seg_s <= 0 or opt.pad < 1 or not 0 <= opt.overlap < 1:
        raise CdgpsError("segment must be positive, pad ≥ 1, 0 ≤ overlap < 1")
    nperseg = int(min(N, max(16, round(seg_s * fs))))
    nfft = int(2 ** np.ceil(np.log2(nperseg * opt.pad)))
    resolution = 1.44 * fs / nperseg                     # Hann half-power main-lobe width
    Y = q[:, sel]
    std = Y.std(axis=0)
    std[std == 0] = 1.0
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
        Gm = gyro_matrix(cfg)
        gy = {"names": list(cfg.gyro_names), "G": Gm}
        rates = np.column_stack([np.interp(time_s, gyro_time_s, gyro_rate[:, g]) for g in range(gyro_rate.shape[1])])
        gps_ang = q @ Gm.T
        for g, gname in enumerate(cfg.gyro_names):
            fw, pr = welch_psd(rates[:, g], fs, nperseg, opt.overlap, nfft)
            with np.errstate(divide="ignore", invalid="ignore"):
                psd[f"gyro_{gname}"] = np.where(fw > 0, pr / (2 * np.pi * fw) ** 2, np.nan)
            _, pa = welch_psd(gps_ang[:, g], fs, nperseg, opt.overlap, nfft)
            psd[f"gps_{gname}"] = pa
            _, coh = coherence_msc(gps_ang[:, g], rates[:, g], fs, nperseg, opt.overlap, nfft)
            psd[f"coherence_{gname}"] = coh
    modes = []
    Ystd = Y / std
    Wfilt = np.linalg.pinv(Um)                              # modal filter: ξ̂ = U⁺ y (standardized)
    for j, (mname, fm, tau) in enumerate(zip(cfg.mode_names, cfg.mode_frequency_hz, cfg.mode_time_constant_s)):
        if fm <= 0:
            continue
        zeta_model = 1.0 / (2 * np.pi * fm * tau)
        entry = {"mode": mname, "model_hz": float(fm), "model_damping": float(zeta_model), "gps_hz": None,
                 "gyro_hz": None, "error_pct": None, "damping": None, "damping_resolution_limited": None,
                 "mac": None, "singular_value": None, "fdd_peak_hz": None, "seen": False, "gyro": None}
        phi = Um[:, j]
        if np.linalg.norm(phi) == 0:
            modes.append(entry)
            continue
        # 1. modal filter + single-mode fit, with a resolution matched to the model's bandwidth
        bw_model = 2 * zeta_model * fm
        seg_j = min(duration, max(60.0, 8.0 / bw_model))
        npj = int(min(N, round(seg_j * fs)))
        nfj = int(2 ** np.ceil(np.log2(npj * opt.pad)))
        fj, pj = welch_psd(Ystd @ Wfilt[j], fs, npj, opt.overlap, nfj)
        res_j = 1.44 * fs / npj
        half = max(4 * bw_model, 4 * res_j, fm * opt.band_pct / 100)
        # the fit's formal sigma treats bins as independent; zero padding (pad) and the Hann window
        # correlate neighbours and the log-periodogram is not Gaussian: the factor 7·pad was
        # calibrated on 12 seeds × 8 modes of the testbed (normalized error RMS 2.6 → 1.0)
        f_fit, z_fit, f_sig = sdof_fit(fj, pj, fm, zeta_model, half, correlated_bins=7 * opt.pad, with_sigma=True)
        # 2. FDD: singular-value peak in the band whose vector matches the model shape
        band = (f >= fm * (1 - opt.band_pct / 100)) & (f <= fm * (1 + opt.band_pct / 100))
        best = None
        for k in range(min(3, S_sv.shape[1])):
            idx = np.flatnonzero(band)
            if idx.size == 0:
                continue
            macs = np.array([mac(U_sv[i, :, k], phi) for i in idx])
            score = S_sv[idx, k] * macs
            ib = int(np.argmax(score))
            i = int(idx[ib])
            if best is None or score[ib] > best[0]:
                best = (score[ib], k, i, macs[ib])
        if best is not None:
            _, k, i, m_mac = best
            entry.update(fdd_peak_hz=_parabolic(f, S_sv[:, k], i), mac=float(m_mac), singular_value=k + 1)
        f_id = f_fit if f_fit is not None else entry["fdd_peak_hz"]
        if f_id is not None:
            err = 100.0 * (f_id - fm) / fm
            entry.update(gps_hz=f_id, gps_hz_sigma=f_sig if f_fit is not None else None, error_pct=err, damping=z_fit,
                         damping_resolution_limited=bool(z_fit is None or 2 * z_fit * f_id < 1.5 * res_j),
                         seen=bool(abs(err) <= opt.seen_pct and (entry["mac"] or 0) >= opt.min_mac))
        if gy is not None:
            U_full = np.asarray(cfg.mode_shapes)[:, j]
            weights = np.abs(gy["G"] @ U_full)
            visible = np.linalg.norm(gy["G"], axis=1) * np.linalg.norm(U_full) * 1e-6
            if np.any(weights > visible):
                g = int(np.argmax(weights))
                gname = gy["names"][g]
                center = entry["gps_hz"] or fm
                gb = (f >= center * (1 - opt.band_pct / 100)) & (f <= center * (1 + opt.band_pct / 100))
                pg = psd[f"gyro_{gname}"]
                if gb.any():
                    band_idx = np.flatnonzero(gb)
                    ii = int(band_idx[np.nanargmax(pg[gb])])
                    entry["gyro"] = gname
                    entry["coherence"] = float(psd[f"coherence_{gname}"][ii])
                    # a maximum on the band edge is the flank of something else, not a peak
                    if band_idx[0] < ii < band_idx[-1]:
                        entry["gyro_hz"] = _parabolic(f, pg, ii)
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
