"""Time-correlated phase errors (multipath) as first-order Gauss–Markov states, one per channel.

Each channel c (antenna, transmitter) carries m_c with

    m_{k+1} = a m_k + √q ω_k,   a = exp(−T/τ),   q = σ_mp² (1 − a²),   ω_k ~ N(0, 1),

stationary prior m_1 ~ N(0, σ_mp²), and enters its phase measurement additively
(λ·Δφ = h(q) + b + m + white noise).  The batch (:mod:`cdgps_cli.estimation.initializer`), the window states
(:mod:`cdgps_cli.estimation.window_smoother`) and the filter (:mod:`cdgps_cli.estimation.filter`) append these C states to the
structure's state; this module holds the model, its transition and process noise, and its record
in INIT.json (``multipath`` object) so that ``estimate`` uses the model ``init`` used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.limits import CONFIG_BOUNDS


@dataclass(frozen=True)
class MultipathModel:
    """First-order Gauss–Markov multipath: σ (m, 0 = not modelled) and time constant τ (s)."""

    sigma_m: float = 0.0
    time_constant_s: float = 30.0

    @property
    def active(self) -> bool:
        return self.sigma_m > 0.0

    def transition(self, dt_s: float) -> float:
        """a = exp(−dt/τ) (dimensionless)."""
        return math.exp(-dt_s / self.time_constant_s)

    def process_variance_m2(self, dt_s: float) -> float:
        """q = σ² (1 − exp(−2 dt/τ)) (m²): the stationary variance is kept over a step of dt."""
        return self.sigma_m**2 * -math.expm1(-2.0 * dt_s / self.time_constant_s)

    def echo(self) -> dict:
        return {"sigma_m": float(self.sigma_m), "time_constant_s": float(self.time_constant_s)}


def model_from(cfg, sigma_m: float | None = None, time_constant_s: float | None = None) -> MultipathModel:
    """The config's ``[model] multipath_sigma_m`` / ``multipath_time_constant_s``, each overridden
    when given (``cdgps init --multipath-sigma-m / --multipath-tau-s``)."""
    s = cfg.multipath_sigma_m if sigma_m is None else float(sigma_m)
    t = cfg.multipath_time_constant_s if time_constant_s is None else float(time_constant_s)
    for key, v in (("multipath_sigma_m", s), ("multipath_time_constant_s", t)):
        b = CONFIG_BOUNDS[f"model.{key}"]
        if not (math.isfinite(v) and b.contains(v)):
            raise CdgpsError(f"{key} = {v!r} is outside {b.text()}")
    return MultipathModel(s, t)


def augment(A: np.ndarray, G: np.ndarray, C: int, mp: MultipathModel, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition (n+C, n+C) and noise input (n+C, r+C) with C Gauss–Markov states appended.

    ``A`` (n, n) and ``G`` (n, r): the structure's transition and whitened process-noise input."""
    n, r = G.shape
    Aa = np.zeros((n + C, n + C))
    Aa[:n, :n] = A
    Aa[n:, n:] = np.eye(C) * mp.transition(dt_s)
    Ga = np.zeros((n + C, r + C))
    Ga[:n, :r] = G
    Ga[n:, r:] = np.eye(C) * math.sqrt(mp.process_variance_m2(dt_s))
    return Aa, Ga


def from_init(init: dict) -> MultipathModel:
    """The model recorded in INIT.json (``multipath`` object; absent = not modelled)."""
    m = init.get("multipath")
    if m is None:
        return MultipathModel(0.0)
    try:
        s, t = m["sigma_m"], m["time_constant_s"]
        if isinstance(s, bool) or isinstance(t, bool):
            raise TypeError
        s, t = float(s), float(t)
    except (KeyError, TypeError, ValueError):
        raise CdgpsError("INIT.json: multipath: expected an object with numbers sigma_m and time_constant_s") from None
    for key, v in (("sigma_m", s), ("time_constant_s", t)):
        b = CONFIG_BOUNDS[f"model.multipath_{key}"]
        if not (math.isfinite(v) and b.contains(v)):
            raise CdgpsError(f"INIT.json: multipath.{key} = {v!r} is outside {b.text()}")
    return MultipathModel(s, t)


def init_states(init: dict, chans: list, n: int, mp: MultipathModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Multipath means (C,), their covariance (C, C) and cross-covariance with the structure state
    (n, C) at INIT's state time, for the filter's channels ``chans``.  Channels INIT has no state
    for start from the stationary prior (0, σ²) uncorrelated with the rest."""
    C = len(chans)
    x = np.zeros(C)
    P = np.eye(C) * mp.sigma_m**2
    X = np.zeros((n, C))
    rec = init.get("multipath") or {}
    names = rec.get("channels")
    if not names:
        return x, P, X
    try:
        xm = np.asarray(rec["x_m"], dtype=float)
        Pm = np.asarray(rec["P_m2"], dtype=float)
        Xm = np.asarray(rec["cross_P"], dtype=float)
        if xm.shape != (len(names),) or Pm.shape != (len(names),) * 2 or Xm.shape != (n, len(names)):
            raise ValueError
        if not (np.isfinite(xm).all() and np.isfinite(Pm).all() and np.isfinite(Xm).all()):
            raise ValueError
    except (KeyError, TypeError, ValueError):
        raise CdgpsError(f"INIT.json: multipath: expected channels, x_m ({len(names)}), P_m2 "
                         f"({len(names)}×{len(names)}) and cross_P ({n}×{len(names)}) finite numbers") from None
    where = {str(c): i for i, c in enumerate(names)}
    ours = [where.get(f"{a}/{t}", -1) for a, t in chans]
    for c, j in enumerate(ours):
        if j < 0:
            continue
        x[c] = xm[j]
        X[:, c] = Xm[:, j]
        for c2, j2 in enumerate(ours):
            if j2 >= 0:
                P[c, c2] = Pm[j, j2]
    return x, P, X


# --- detection and estimation from the residuals of a white-noise batch fit (``init`` by default)

#: lags (s) of the pooled Ljung–Box test of the per-run residual autocorrelation
DETECT_LAGS_S = (1.0, 2.0, 4.0)
#: Ljung–Box false-alarm probability under white residuals (chi-square, C × lags dof)
DETECT_PROBABILITY = 1e-6
#: … and the fitted multipath must at least multiply the variance of a bias estimated from a
#: stretch (the mean of its median length) by 1 + this ratio (a correlation that matters for the
#: fix, not the few per cent the fit itself induces in white residuals).  A multipath σ well below
#: the white σ can still matter: over τ/T epochs it does not average out as white noise does
#: (5 mm, τ 30 s under 1 cm white at 10 Hz: ≈ 80 times the white noise's bias variance)
DETECT_MIN_BIAS_VARIANCE_RATIO = 1.0
#: lags (s) of the autocovariance fit, up to a third of the typical run length
FIT_LAGS_S = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
#: time constants tried by the fit (log grid across the clamp bounds)
FIT_TAU_GRID = 61
#: longest time constant fitted, as a fraction of the median stretch: beyond it a demeaned stretch
#: shows only the drift σ²/τ of the process (σ and τ trade off), so the fit stops there and the
#: equivalent (σ, τ) with that drift is used
TAU_MAX_STRETCH_FRACTION = 0.5
#: shortest contiguous run (epochs) of one channel's residuals used
MIN_RUN = 20


def segment_stretches(resid: np.ndarray, segment: np.ndarray, min_len: int):
    """``(channel, start, stop)`` of every contiguous stretch of finite residuals of one channel within
    one bias segment, at least ``min_len`` epochs long, by channel then time (the one definition
    used by the multipath fit and the slip test, :func:`cdgps_cli.measurement.slips.residual_steps`).

    ``resid`` (N, C) m, NaN where missing; ``segment`` (N, C) bias-segment index (−1 = none)."""
    for c in range(resid.shape[1]):
        ok = np.isfinite(resid[:, c]) & (segment[:, c] >= 0)
        key = np.where(ok, segment[:, c], -1)
        edges = np.flatnonzero(np.diff(np.r_[-1, key, -1]) != 0)
        for a, b in zip(edges[:-1], edges[1:]):
            if key[a] >= 0 and b - a >= min_len:
                yield c, int(a), int(b)


def residual_runs(resid: np.ndarray, segment: np.ndarray) -> list[np.ndarray]:
    """Contiguous finite stretches of each channel's residuals within one bias segment
    (:func:`segment_stretches`), each with its own mean removed (so that the expected
    autocovariance below is exact for it)."""
    return [r - r.mean() for r in (resid[a:b, c] for c, a, b in segment_stretches(resid, segment, MIN_RUN))]


def _lagged_sums(runs: list, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Σ y_i y_{i+k} (m²) and the number of pairs, over all runs, per lag k (samples)."""
    s = np.zeros(len(lags))
    n = np.zeros(len(lags))
    for r in runs:
        for j, k in enumerate(lags):
            if k < len(r):
                s[j] += float(np.dot(r[:len(r) - k], r[k:]))
                n[j] += len(r) - k
    return s, n


def _expected_sums(lengths: np.ndarray, lags: np.ndarray, a: float) -> tuple[np.ndarray, np.ndarray]:
    """E[Σ y_i y_{i+k}] per unit σ_mp² and per unit σ_white² for demeaned runs of the given lengths.

    A demeaned stretch y = (I − 11ᵀ/L) x of x with covariance σ² a^|i−j| has
    E[y_i y_j] = σ² (a^|i−j| − r_i − r_j + r̄), r_i = (1/L) Σ_j a^|i−j| (a geometric sum), r̄ = mean r_i;
    white noise gives σ_w² (δ_ij − 1/L).  Summed over the L − k pairs at lag k: O(L) per run."""
    gm = np.zeros(len(lags))
    wh = np.zeros(len(lags))
    uniq, count = np.unique(np.asarray(lengths, dtype=np.int64), return_counts=True)
    for L, n_runs in zip(uniq.tolist(), count.tolist()):
        i = np.arange(L)
        r = ((1 - a ** (i + 1)) + (1 - a ** (L - i))) / (1 - a) - 1.0
        r /= L
        cs = np.r_[0.0, np.cumsum(r)]
        rbar = cs[-1] / L
        for j, k in enumerate(lags):
            if k >= L:
                continue
            m = L - k
            gm[j] += n_runs * (m * a**k - cs[m] - (cs[L] - cs[k]) + m * rbar)
            wh[j] += n_runs * m * ((1.0 if k == 0 else 0.0) - 1.0 / L)
    return gm, wh


def fit_autocovariance(resid: np.ndarray, segment: np.ndarray, dt_s: float) -> dict | None:
    """Gauss–Markov σ, τ and white σ from the pooled residual autocovariance, and the detection test.

    Estimator (moment matching): the residuals of each channel, per contiguous stretch of one bias
    segment and demeaned, give the pooled sample autocovariance sums Ŝ_k = Σ y_i y_{i+k} at the lags
    ``FIT_LAGS_S`` (below a third of the median stretch).  For each τ of a log grid over
    :data:`~cdgps_cli.config.limits.AUTO_MULTIPATH_TAU`, the expected sums of a demeaned
    first-order Gauss–Markov process plus white noise (:func:`_expected_sums`, exact for the
    demeaning) are linear in (σ_mp², σ_w²); those are fitted by non-negative least squares to
    Ŝ_k / n_k (n_k = pairs) and the τ of least misfit is kept, then σ_mp and τ are clamped to
    ``AUTO_MULTIPATH_SIGMA`` / ``AUTO_MULTIPATH_TAU``.  The grid ends at
    ``TAU_MAX_STRETCH_FRACTION`` × the median stretch: a longer τ is not identifiable from demeaned
    stretches (only σ²/τ is), and the fit at that end gives the σ with the same drift.  What the batch's state trajectory absorbed of
    the multipath is not in the residuals, so σ_mp is if anything underestimated.

    Detection: the pooled Ljung–Box statistic Q = Σ_runs L(L+2) Σ_k ρ_k²/(L−k) at ``DETECT_LAGS_S``
    above its chi-square (runs × lags) quantile 1 − ``DETECT_PROBABILITY``, and the fitted
    multipath's variance of a stretch mean at least ``DETECT_MIN_BIAS_VARIANCE_RATIO`` × the white
    noise's (:func:`mean_variance_ratio`).  Returns None when no stretch is long enough."""
    from scipy.optimize import nnls
    from scipy.stats import chi2
    from cdgps_cli.config.limits import AUTO_MULTIPATH_SIGMA, AUTO_MULTIPATH_TAU

    runs = residual_runs(resid, segment)
    if not runs:
        return None
    lengths = np.array([len(r) for r in runs])
    L_med = float(np.median(lengths))
    lags = sorted({int(round(s / dt_s)) for s in FIT_LAGS_S if s / dt_s <= L_med / 3} | {0, 1})
    lags = np.array(lags, dtype=np.int64)
    s_hat, n_pairs = _lagged_sums(runs, lags)
    use = n_pairs > 0
    gamma = s_hat[use] / n_pairs[use]
    best = None
    tau_lo = max(AUTO_MULTIPATH_TAU.lo, 2 * dt_s)
    tau_hi = max(min(AUTO_MULTIPATH_TAU.hi, TAU_MAX_STRETCH_FRACTION * L_med * dt_s), tau_lo)
    for tau in np.geomspace(tau_lo, tau_hi, FIT_TAU_GRID):
        gm, wh = _expected_sums(lengths, lags, math.exp(-dt_s / tau))
        M = np.column_stack([gm[use] / n_pairs[use], wh[use] / n_pairs[use]])
        coef, misfit = nnls(M, gamma)
        if best is None or misfit < best[0]:
            best = (misfit, tau, coef)
    _, tau, (v_mp, v_w) = best
    sigma_mp, sigma_w = math.sqrt(v_mp), math.sqrt(v_w)
    # pooled Ljung–Box on the detection lags
    q, dof = 0.0, 0
    # (samples further apart than the lags, e.g. a 15 s log: its first lag, not none)
    detect_lags = sorted({max(1, int(round(s / dt_s))) for s in DETECT_LAGS_S})
    for r in runs:
        L, den = len(r), float(np.dot(r, r))
        for k in detect_lags:
            if k < L and den > 0:
                rho = float(np.dot(r[:L - k], r[k:])) / den
                q += L * (L + 2) * rho**2 / (L - k)
                dof += 1
    q_limit = float(chi2.isf(DETECT_PROBABILITY, max(dof, 1)))
    bias_ratio = mean_variance_ratio(sigma_mp, tau, sigma_w, dt_s, int(round(L_med)))
    detected = dof > 0 and q > q_limit and bias_ratio >= DETECT_MIN_BIAS_VARIANCE_RATIO
    return {"detected": bool(detected), "ljung_box_q": q, "ljung_box_dof": dof, "ljung_box_limit": q_limit,
            "lags_s": [float(k * dt_s) for k in detect_lags],
            "sigma_m": float(min(max(sigma_mp, AUTO_MULTIPATH_SIGMA.lo), AUTO_MULTIPATH_SIGMA.hi)),
            "time_constant_s": float(min(max(tau, AUTO_MULTIPATH_TAU.lo), AUTO_MULTIPATH_TAU.hi)),
            "raw_sigma_m": sigma_mp, "raw_time_constant_s": float(tau), "white_sigma_m": sigma_w,
            "runs": len(runs), "lag_samples": [int(k) for k in lags], "bias_variance_ratio": bias_ratio}


def mean_variance_ratio(sigma_mp: float, tau_s: float, sigma_w: float, dt_s: float, n: int) -> float:
    """Variance of the mean of ``n`` samples of a Gauss–Markov process (σ_mp, τ) over that of ``n``
    white samples (σ_w): (σ_mp/σ_w)² (1 + 2 Σ_{k=1}^{n−1} (1 − k/n) a^k), a = exp(−dt/τ) (∞ when σ_w = 0)."""
    if sigma_mp <= 0.0:
        return 0.0
    if sigma_w <= 0.0:
        return math.inf
    n = max(int(n), 1)
    a = math.exp(-dt_s / tau_s)
    k = np.arange(1, n)
    return float((sigma_mp / sigma_w) ** 2 * (1.0 + 2.0 * np.sum((1.0 - k / n) * a**k)))
