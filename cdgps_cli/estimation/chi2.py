"""Chi-square quantiles for the NIS, zero-velocity and wrong-fix tests, without importing scipy.

The filter needs a handful of quantiles per run; importing ``scipy.special`` for them costs more
start-up time (≈ 45 ms) than computing them here. The quantile x of χ²_k at probability p is
2·y where P(k/2, y) = p, P the regularized lower incomplete gamma function (Abramowitz & Stegun
26.4.19). ``P`` and its complement ``Q`` are evaluated by their power series and Legendre's
continued fraction (Numerical Recipes §6.2; A&S 6.5.29, 6.5.31), whichever converges and does
not cancel, and the root is found by Halley's method from the Wilson–Hilferty start
(A&S 26.4.17). It agrees with ``scipy.stats.chi2.ppf`` to about 1e-14 relative
(tests/estimation/test_chi2.py), and exactly where the quantile has a closed form (2 degrees of
freedom: −2 ln(1 − p)).
"""

from __future__ import annotations

import math
from functools import lru_cache
from statistics import NormalDist

import numpy as np

_EPS = 1e-16           # series / continued-fraction convergence (relative)
_ROOT_RTOL = 4e-16     # Halley iterations stop when the step is this small relative to the root
_MAX_TERMS = 10_000
_MAX_STEPS = 200
_TINY = 1e-300


def _log_kernel(a: float, y: float) -> float:
    """log(y^a e^−y / Γ(a))."""
    return a * math.log(y) - y - math.lgamma(a)


def _p_series(a: float, y: float) -> float:
    """P(a, y) by its power series Σ yⁿ / (a (a+1) … (a+n)) · y^a e^−y / Γ(a) (y < a + 1)."""
    term = total = 1.0 / a
    ap = a
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= y / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(_log_kernel(a, y))


def _q_fraction(a: float, y: float) -> float:
    """Q(a, y) = 1 − P(a, y) by Legendre's continued fraction, modified Lentz (y ≥ a + 1)."""
    b = y + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * math.exp(_log_kernel(a, y))


def _lower_upper(a: float, y: float) -> tuple[float, float]:
    """(P(a, y), Q(a, y)), the smaller of the two computed directly (no cancellation)."""
    if y <= 0.0:
        return 0.0, 1.0
    if y < a + 1.0:
        p = _p_series(a, y)
        return p, 1.0 - p
    q = _q_fraction(a, y)
    return 1.0 - q, q


def _start(a: float, p: float) -> float:
    """Wilson–Hilferty start for y = x/2 (A&S 26.4.17), the small-y series where it fails."""
    k = 2.0 * a
    h = 2.0 / (9.0 * k)
    w = 1.0 - h + NormalDist().inv_cdf(p) * math.sqrt(h)
    if w > 0.0 and k * w ** 3 > 0.2 * k:
        return 0.5 * k * w ** 3
    return math.exp((math.log(p) + math.lgamma(a + 1.0)) / a)      # P(a, y) ≈ y^a / Γ(a + 1)


@lru_cache(maxsize=4096)
def _quantile(p: float, k: float) -> float:
    """x with P(χ²_k ≤ x) = p, for 0 < p < 1 and k > 0."""
    a = 0.5 * k
    upper = p > 0.5                       # solve on the smaller tail: Q(a, y) = 1 − p there
    target = (1.0 - p) if upper else p
    y = _start(a, p)
    for _ in range(_MAX_STEPS):
        if y == 0.0:                      # the quantile underflows (tiny p and dof)
            break
        lo, hi = _lower_upper(a, y)
        f = (hi - target) if upper else (lo - target)
        slope = math.exp(_log_kernel(a, y)) / y * (-1.0 if upper else 1.0)   # d/dy of P (or of Q)
        if slope == 0.0:
            break
        newton = f / slope
        step = newton / (1.0 - 0.5 * newton * ((a - 1.0) / y - 1.0))       # Halley: f'' / f' = (a − 1)/y − 1
        if not math.isfinite(step) or y - step <= 0.0:
            step = newton if (y - newton > 0.0) else 0.5 * y
        y -= step
        if abs(step) <= _ROOT_RTOL * y:
            break
    return 2.0 * y


def _scalar(p: float, k: float) -> float:
    if not (0.0 <= p <= 1.0 and k > 0.0):      # NaN in: NaN out (the comparisons are False)
        return math.nan
    if p == 0.0:
        return 0.0
    if p == 1.0:
        return math.inf
    return _quantile(p, k)


def chi2_quantile(probability, dof):
    """Chi-square quantile: the x with P(χ²_dof ≤ x) = ``probability``.

    Agrees with ``scipy.stats.chi2.ppf(probability, dof)`` to about 1e-14 relative, with the same
    edge values: 0 at probability 0, inf at 1, NaN for a probability outside [0, 1] or dof ≤ 0.

    Parameters
    ----------
    probability : float or array_like
        In [0, 1].
    dof : int, float or array_like
        Degrees of freedom, > 0 (broadcast against ``probability``).

    Returns
    -------
    numpy.float64 or ndarray
        The quantile(s), shape of the broadcast inputs.

    References
    ----------
    Abramowitz & Stegun, Handbook of Mathematical Functions, 6.5 and 26.4; Press et al.,
    Numerical Recipes, 3rd ed., §6.2 (series and continued fraction of the incomplete gamma function).
    """
    if np.ndim(probability) == 0 and np.ndim(dof) == 0:      # a filter's per-epoch test: no arrays (_quantile caches)
        return np.float64(_scalar(float(probability), float(dof)))
    p, k = np.broadcast_arrays(np.asarray(probability, dtype=float), np.asarray(dof, dtype=float))
    key = np.empty(p.size, dtype=complex)                 # (p, dof) as one sortable key
    key.real, key.imag = p.ravel(), k.ravel()
    pairs, row = np.unique(key, return_inverse=True)
    values = np.fromiter((_scalar(float(c.real), float(c.imag)) for c in pairs), dtype=float, count=len(pairs))
    return values[row.ravel()].reshape(p.shape)[()]     # each distinct (p, dof) once (a per-epoch dof array)
