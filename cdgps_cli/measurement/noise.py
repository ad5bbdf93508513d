"""Measurement-noise model: the per-channel prior σ and its estimation from the data.

One source of truth for the σ of each carrier-phase channel (antenna, transmitter):

* :func:`prior_sigma_m` — the σ the config (or an explicit ``--sigma-m``) promises, one value per
  channel.  Config keys for σ per antenna / transmitter / channel fill this same vector.
* :func:`snr_sigma_factor` — where the run's channels differ in carrier-to-noise density, the prior
  σ of each channel scaled by its mean C/N₀ (σ² = σ₀² · 10^((C/N₀_ref − C/N₀)/10), the usual
  receiver / RTKLIB-style SNR weighting; ref = the median channel, which keeps the config's σ₀).
* :func:`variance_factors` — the a-posteriori variance factor of a batch least-squares solution per
  channel, σ̂_c² = Σ_k e_kc² / Σ_k r_kc, with the redundancy numbers r_kc = 1 − h_kc (h: the
  diagonal of the hat matrix, i.e. the leverage of each observation).  Σ_k h_kc is found with
  Hutchinson's trace estimator (random ±1 probes solved through the same O(N) batch solver), so
  the cost is a few linear solves, never an N×N matrix.  With the redundancy the estimate is
  unbiased even when the fit absorbs a large part of a channel's data (short windows, many
  biases), where the naive residual RMS is too small.
* :func:`filter_sigma_estimate` — the same idea in the filter: E[e_i²] = σ_i² − H_i P⁺ H_iᵀ for the
  post-fit residual, so σ̂_i² = mean(e_i² + H_i P⁺ H_iᵀ) (residual-based adaptive estimation).
"""

from __future__ import annotations

import math

import numpy as np

from cdgps_cli.core.errors import CdgpsError

HUTCHINSON_PROBES = 8        # random probes of the leverage trace per channel
HUTCHINSON_SEED = 20260601   # fixed: same data → same estimate (byte-identical outputs)
SNR_SPREAD_MIN_DB = 3.0      # channel mean C/N₀ spread (max − min) below this: no SNR weighting


def snr_sigma_factor(snr_dbhz) -> np.ndarray | None:
    """Per-channel σ factor 10^((C/N₀_ref − C/N₀_c)/20) from each channel's mean C/N₀ (dB-Hz), (C,).

    C/N₀_ref is the median of the channels' means (that channel keeps the config's σ).  None (no
    weighting, the arithmetic unchanged) when fewer than two channels report C/N₀ or their means
    span less than :data:`SNR_SPREAD_MIN_DB`; a channel without C/N₀ keeps factor 1."""
    snr = np.asarray(snr_dbhz, dtype=float).ravel()
    ok = np.isfinite(snr)
    if ok.sum() < 2 or float(snr[ok].max() - snr[ok].min()) < SNR_SPREAD_MIN_DB:
        return None
    ref = float(np.median(snr[ok]))
    return np.where(ok, 10.0 ** ((ref - np.where(ok, snr, ref)) / 20.0), 1.0)


def prior_sigma_m(cfg, channels, override_m: float | None = None, snr_dbhz=None) -> np.ndarray:
    """Per-channel prior measurement σ (m), shape (C,).

    Parameters
    ----------
    cfg : StructureConfig
    channels : list of (antenna, transmitter)
    override_m : float, optional
        An explicit σ (``--sigma-m``) for every channel (no SNR weighting then).
    snr_dbhz : array (C,), optional
        Each channel's mean C/N₀ (dB-Hz, NaN = none): scales the config's σ by
        :func:`snr_sigma_factor` when the channels differ.

    Otherwise :func:`cdgps_cli.config.structure.channel_sigma_m` (the config's per channel / antenna /
    transmitter ``sigma_m`` keys, falling back to ``measurement_sigma_m``).
    """
    if override_m is not None:
        if not (np.isfinite(override_m) and override_m > 0):
            raise CdgpsError(f"--sigma-m must be a positive number of metres, got {override_m!r}")
        return np.full(len(channels), float(override_m))
    from cdgps_cli.config.structure import channel_sigma_m  # noqa: PLC0415 (the config reader: not on the rtk path)
    out = np.asarray(channel_sigma_m(cfg, list(channels)), dtype=float).reshape(len(channels))
    if not np.all(np.isfinite(out) & (out > 0)):
        raise CdgpsError(f"{cfg.name}: measurement sigma must be positive for every channel")
    f = None if snr_dbhz is None else snr_sigma_factor(snr_dbhz)
    return out if f is None else out * f


def leverage_per_channel(solve_fitted, present: np.ndarray, probes: int = HUTCHINSON_PROBES,
                         seed: int = HUTCHINSON_SEED, batched: bool = False) -> np.ndarray:
    """Σ_k h_kc per channel by Hutchinson's estimator.

    Parameters
    ----------
    solve_fitted : callable
        ``solve_fitted(eps) -> fitted``: the whitened fitted values (N, C) of the linear LS problem
        whose whitened data are ``eps`` (N, C; NaN where absent), priors at zero mean.  Linear in eps.
        With ``batched``, all probes at once: eps and fitted (N, C, probes) (one solve with several
        right-hand sides).
    present : (N, C) bool
        Observations that exist.
    probes : int
        Number of random ±1 probes (E[εᵀ D_c Ĥ ε] = tr(D_c Ĥ) for each).
    seed : int
        Seed of the probes (the same probes batched or not).

    Returns
    -------
    (C,) estimated sum of leverages of each channel's observations.
    """
    rng = np.random.default_rng(seed)
    eps = [np.where(present, rng.choice((-1.0, 1.0), size=present.shape), np.nan) for _ in range(probes)]
    fits = np.moveaxis(solve_fitted(np.stack(eps, axis=2)), 2, 0) if batched else (solve_fitted(e) for e in eps)
    acc = np.zeros(present.shape[1])
    for e, fit in zip(eps, fits):
        acc += np.nansum(np.where(present, e * fit, 0.0), axis=0)
    return acc / probes


def variance_factors(resid_m: np.ndarray, sigma_m: np.ndarray, leverage: np.ndarray) -> dict:
    """Per-channel a-posteriori σ from residuals and redundancy numbers.

    Parameters
    ----------
    resid_m : (N, C)
        Residuals of the converged solution (m), NaN where absent.
    sigma_m : (C,)
        σ the solution was weighted with (m).
    leverage : (C,)
        Σ_k h_kc (:func:`leverage_per_channel`).

    Returns
    -------
    dict with ``sigma_m`` (C,) the estimate, ``redundancy`` (C,) Σ_k (1 − h_kc), ``n_obs`` (C,),
    ``variance_factor`` (C,) σ̂²/σ² and ``rms_m`` (C,) the naive residual RMS.
    """
    ok = np.isfinite(resid_m)
    n_obs = ok.sum(axis=0)
    ss = np.where(ok, resid_m, 0.0) ** 2
    ss = ss.sum(axis=0)
    red = np.maximum(n_obs - leverage, 0.5)
    var = ss / red
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(ss / np.maximum(n_obs, 1))
    return {"sigma_m": np.sqrt(var), "redundancy": red, "n_obs": n_obs,
            "variance_factor": var / sigma_m**2, "rms_m": rms}


def filter_sigma_estimate(resid_m: np.ndarray, hph_m2: np.ndarray, block_rows: int | None = None,
                          release=None) -> tuple[np.ndarray, np.ndarray]:
    """Residual-based σ per channel in the filter: σ̂² = mean(e² + H P⁺ Hᵀ).

    Parameters
    ----------
    resid_m : (N, C) post-fit residuals (m), NaN where the channel was not used.
    hph_m2 : (N, C) H_i P⁺ H_iᵀ per epoch and channel (m²).
    block_rows : int, optional
        Read the epochs in blocks of this many rows (temporaries of a block, not of the record).
        The sums are the same to the bit: each block's rows are added, in order, to the running
        total (numpy's reduction over the first axis of a C-contiguous array adds row after row).
    release : callable, optional
        ``release(arr, start, stop)`` after each block, for both arrays (arrays on disk drop its pages).

    Returns
    -------
    (sigma_m (C,), count (C,)): NaN where a channel has no residual.
    """
    N, C = resid_m.shape
    step = max(N if not block_rows else int(block_rows), 1)
    cnt = np.zeros(C, dtype=np.int64)
    tot = np.zeros(C)
    for a in range(0, max(N, 1), step):
        b = min(a + step, N)
        e, h = resid_m[a:b], hph_m2[a:b]
        ok = np.isfinite(e) & np.isfinite(h)
        cnt += ok.sum(axis=0)
        w = e**2
        w += h
        w[~ok] = 0.0
        if w.shape[0]:
            w[0] += tot                                   # (tot + row 0) + row 1 + …: the running total, in order
            tot = np.add.reduce(w, axis=0)
        if release is not None:
            release(resid_m, a, b)
            release(hph_m2, a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sqrt(tot / cnt)
    return np.where(cnt > 0, s, np.nan), cnt


def init_channel_sigma_m(init: dict, cfg, channels, override_m: float | None = None) -> tuple[np.ndarray, str]:
    """Per-channel measurement σ (m) of the filter and of INIT's window states, shape (C,).

    Parameters
    ----------
    init : dict
        INIT.json contents: ``sigma_m_per_channel`` {"antenna/transmitter": σ} (the batch's per-channel
        estimate) and ``sigma_m`` (their RMS) when present.
    cfg : StructureConfig
    channels : list of (antenna, transmitter)
    override_m : float, optional
        An explicit σ (``--sigma-m``) for every channel.

    Returns
    -------
    (sigma_m (C,), source): ``--sigma-m``; else INIT's per-channel σ (a channel INIT does not list
    takes INIT's ``sigma_m``); else INIT's ``sigma_m`` for every channel; else the config's
    per-channel prior (:func:`prior_sigma_m`).

    Raises CdgpsError naming the INIT.json key when ``sigma_m_per_channel`` is malformed.
    """
    from cdgps_cli.config.limits import OPTION_BOUNDS

    C = len(channels)
    if override_m is not None:
        return prior_sigma_m(cfg, channels, override_m), "--sigma-m"
    per = init.get("sigma_m_per_channel")
    s0 = init.get("sigma_m")
    if per is None:
        if s0:
            return np.full(C, float(s0)), "INIT (one σ)"
        return prior_sigma_m(cfg, channels), "config"
    if not isinstance(per, dict):
        raise CdgpsError("INIT.json: sigma_m_per_channel: expected an object {\"antenna/transmitter\": sigma_m}")
    known = {f"{a}/{t}" for a, t in cfg.channels}
    bound = OPTION_BOUNDS["sigma_m"]
    for key, v in per.items():
        if key not in known:
            raise CdgpsError(f"INIT.json: sigma_m_per_channel: {key!r} is not a channel (antenna/transmitter) "
                             f"of the config")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and bound.contains(v)):
            raise CdgpsError(f"INIT.json: sigma_m_per_channel[{key!r}] = {v!r}: expected a number of metres "
                             f"in {bound.text()}")
    fallback = float(s0) if s0 else float(np.sqrt(np.mean(np.square(list(per.values()) or [cfg.measurement_sigma_m]))))
    out = np.array([float(per.get(f"{a}/{t}", fallback)) for a, t in channels])
    return out, "INIT (estimated per channel)" if "noise" in init else "INIT (per channel)"


def correlated_variance_factor(interval_s: float, correlation_s: float) -> float:
    """Factor by which a white-noise variance is inflated so that N samples of a first-order
    Gauss–Markov error (correlation time ``correlation_s``, sampled every ``interval_s``) carry the
    information they really have about a constant: ``(1 + ρ) / (1 − ρ)``, ``ρ = exp(−Δt/τ)``, the
    large-N ratio of the variance of the mean of AR(1) samples to that of white samples.  1 for
    ``correlation_s`` = 0 (white).  Real code multipath is correlated over about a minute: τ = 60 s
    at 1 Hz gives 120 (σ × 11).
    """
    if not (math.isfinite(correlation_s) and correlation_s >= 0):
        raise ValueError(f"code correlation time must be >= 0 s, got {correlation_s!r}")
    if correlation_s == 0 or not (math.isfinite(interval_s) and interval_s > 0):
        return 1.0
    rho = math.exp(-interval_s / correlation_s)
    return (1.0 + rho) / (1.0 - rho)


def code_noise_factor(time_s, channel, code_m, phase_m, slip, var_model_m2, *, window_s: float, chunk_s: float,
                      min_windows: int) -> tuple[float, int]:
    """How much more a receiver's code errors weigh when averaged than its code model says, from its own
    code-minus-carrier (CMC).

    ``code − phase`` (both in metres) of one channel removes the geometry and the clocks and leaves twice
    the ionosphere, the ambiguity and the code's own error (multipath and noise; the phase's are ~100x
    smaller).  Each arc of a channel (a new one after a slip flag, a gap longer than a window and 1.5
    epochs, or a jump over 20 m) is cut into chunks of ``chunk_s`` s, and a quadratic in time is removed
    from each (the ambiguity and the slow ionosphere); what remains is averaged over windows of
    ``window_s`` s holding at least three rows (a receiver that logs with gaps, as a u-blox base
    interleaving RTCM, has fewer rows a window, each weighing more).  The
    factor is ``Σ mean_w² / Σ (mean model variance_w / n_w)``, each chunk's sum scaled by k/(k − 3) for
    the three parameters fitted over its k windows: the variance of the window means against what white
    errors of the modelled variance would give.  A filter that takes the codes as white with the model's
    variance counts ``window_s`` s of a receiver with a factor F as worth F times more than they are:
    multiplying the code variance by F makes their average honest over that span.

    Parameters
    ----------
    time_s : array_like (N,)
        Epoch of each row, s.
    channel : array_like of int (N,)
        Channel (satellite and signal) of each row.
    code_m, phase_m : array_like (N,)
        Pseudorange and carrier phase, m (NaN: missing; such rows are not used).
    slip : array_like of bool (N,)
        Loss of lock at the row.
    var_model_m2 : array_like (N,)
        The model's variance of the row's code, m².
    window_s, chunk_s : float
        Averaging window and detrending chunk, s.
    min_windows : int
        Fewest full windows for an estimate.

    Returns
    -------
    factor : float
        The variance factor (NaN when fewer than ``min_windows`` full windows were found).
    n_windows : int
    """
    t = np.asarray(time_s, dtype=np.float64)
    ch = np.asarray(channel, dtype=np.int64)
    cmc = np.asarray(code_m, dtype=np.float64) - np.asarray(phase_m, dtype=np.float64)
    ok = np.isfinite(cmc) & np.isfinite(t)
    t, ch, cmc = t[ok], ch[ok], cmc[ok]
    sl, var = np.asarray(slip, dtype=bool)[ok], np.asarray(var_model_m2, dtype=np.float64)[ok]
    if t.size < 2:
        return math.nan, 0
    order = np.lexsort((t, ch))
    t, ch, cmc, sl, var = t[order], ch[order], cmc[order], sl[order], var[order]
    steps = np.diff(np.unique(t))
    step = float(np.median(steps)) if steps.size else math.nan
    if not (math.isfinite(step) and step > 0):
        return math.nan, 0
    gap = max(1.5 * step, window_s)          # a logging gap shorter than a window keeps the arc (no slip flag)
    new = np.r_[True, (ch[1:] != ch[:-1]) | sl[1:] | (np.diff(t) > gap) | (np.abs(np.diff(cmc)) > 20.0)]
    arc = np.cumsum(new) - 1
    t_arc0 = t[new][arc]
    chunk_key = np.cumsum(np.r_[True, (arc[1:] != arc[:-1]) |
                                (np.floor((t[1:] - t_arc0[1:]) / chunk_s) != np.floor((t[:-1] - t_arc0[:-1]) / chunk_s))]) - 1
    first = np.r_[True, chunk_key[1:] != chunk_key[:-1]]
    u = t - t[first][chunk_key]
    r = _detrended(u, cmc, chunk_key)
    wkey = np.cumsum(np.r_[True, (chunk_key[1:] != chunk_key[:-1]) |
                           (np.floor(u[1:] / window_s) != np.floor(u[:-1] / window_s))]) - 1
    n_w = np.bincount(wkey)
    full = (n_w >= 3) & np.isfinite(np.bincount(wkey, weights=r))
    mean_w = np.bincount(wkey, weights=np.nan_to_num(r)) / np.maximum(n_w, 1)
    white_w = np.bincount(wkey, weights=var) / np.maximum(n_w, 1) ** 2
    chunk_of_w = chunk_key[np.r_[True, wkey[1:] != wkey[:-1]]]
    k = np.bincount(chunk_of_w, weights=full.astype(float))
    use = full & (k[chunk_of_w] >= 4)
    if int(use.sum()) < min_windows:
        return math.nan, int(use.sum())
    scale = k[chunk_of_w[use]] / (k[chunk_of_w[use]] - 3.0)      # the quadratic took 3 of each chunk's k windows
    return float(np.sum(scale * mean_w[use] ** 2) / np.sum(white_w[use])), int(use.sum())


def _detrended(u, y, group) -> np.ndarray:
    """``y`` minus the least-squares quadratic in ``u`` of its group (NaN for groups of fewer than 3 rows)."""
    n = group.max() + 1
    s = [np.bincount(group, weights=u ** p, minlength=n) for p in range(5)]
    b = [np.bincount(group, weights=y * u ** p, minlength=n) for p in range(3)]
    A = np.stack([np.stack([s[i + j] for j in range(3)], axis=-1) for i in range(3)], axis=-2)   # (n, 3, 3)
    good = (s[0] >= 3) & (np.abs(np.linalg.det(A)) > 1e-300)
    c = np.full((n, 3), np.nan)
    if good.any():
        c[good] = np.linalg.solve(A[good], np.stack(b, axis=-1)[good][:, :, None])[:, :, 0]
    cg = c[group]
    return y - (cg[:, 0] + cg[:, 1] * u + cg[:, 2] * u * u)


def effective_sample_size(series) -> float:
    """How many independent samples a serially correlated series (n,) is worth: n / (1 + 2 Σ ρ_k), ρ_k its
    autocorrelation at lag k summed while positive (the initial positive sequence, Geyer 1992); n when the
    series is constant, 0 when it is empty.

    A float position that converges over minutes changes slowly: 600 epochs of it are worth 3–6 samples of its
    error (the real and simulated pairs of ``rtk``'s float variance factor), which the mean of a statistic over
    those epochs must be judged by.  The autocorrelation by FFT: O(n log n)."""
    z = np.asarray(series, dtype=np.float64)
    n = z.size
    if n == 0:
        return 0.0
    z = z - z.mean()
    v = float(np.dot(z, z))
    if v == 0.0:
        return float(n)
    size = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(z, size)
    rho = np.fft.irfft(f * np.conj(f), size)[1:n // 2] / v
    neg = np.flatnonzero(rho <= 0.0)
    s = float(rho[:neg[0] if neg.size else rho.size].sum())
    return n / (1.0 + 2.0 * s)
