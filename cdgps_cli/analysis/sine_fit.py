"""A sinusoid's amplitude and frequency from an irregular, gappy series (least squares).

Used to check that a known vibration added to real receiver data is recovered
(``tests/pipeline/test_vibration_real.py``, ``benchmarks/bench_vibration_real.py``): the model is

    y(t) = A·sin(2π f t + φ) + c₀ + c₁·t

with the offset c₀ and the drift c₁ taking the antenna's static position and a slow multipath or
ionosphere trend.  For each trial frequency the linear part (sin, cos, 1, t) is solved exactly;
the frequency minimising the residual sum of squares is found on a grid over
``[f_guess·(1 − span), f_guess·(1 + span)]`` and then refined by bounded scalar minimisation
between the grid point's neighbours.  Works on any time stamps (no regular sampling needed).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar

__all__ = ["SineFit", "fit_sine"]


class SineFit(NamedTuple):
    """Result of :func:`fit_sine`."""

    amplitude: float
    """A, units of y."""
    frequency_hz: float
    """f, Hz."""
    phase_rad: float
    """φ, rad (at t = 0)."""
    offset: float
    """c₀, units of y."""
    drift_per_s: float
    """c₁, units of y per second."""
    residual_rms: float
    """RMS of y − model, units of y."""
    n: int
    """Samples used (finite y)."""


def _linear(t: np.ndarray, y: np.ndarray, f: float):
    w = 2.0 * np.pi * f * t
    a = np.column_stack([np.sin(w), np.cos(w), np.ones_like(t), t])
    c, *_ = np.linalg.lstsq(a, y, rcond=None)
    r = y - a @ c
    return float(r @ r), c


def fit_sine(t_s, y, f_guess_hz: float, *, span: float = 0.2, n_grid: int = 401) -> SineFit:
    """Fit ``A sin(2πft + φ) + c₀ + c₁t`` to (t, y) (module docstring).

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Times, s (any origin, any spacing; shifted to their mean inside for conditioning).
    y : array_like, shape (N,)
        Values; NaN samples are left out.
    f_guess_hz : float
        Expected frequency, Hz (> 0).
    span : float
        Relative half-width of the frequency search around ``f_guess_hz`` (0 < span < 1).
    n_grid : int
        Grid points of the coarse search (≥ 3).

    Returns
    -------
    SineFit

    Raises
    ------
    ValueError
        Fewer than 5 finite samples, or a bad ``f_guess_hz`` / ``span`` / ``n_grid``.
    """
    t = np.asarray(t_s, dtype=float).ravel()
    yy = np.asarray(y, dtype=float).ravel()
    ok = np.isfinite(t) & np.isfinite(yy)
    t, yy = t[ok], yy[ok]
    if t.size < 5:
        raise ValueError(f"fit_sine needs at least 5 finite samples, got {t.size}")
    if not (f_guess_hz > 0 and 0 < span < 1 and n_grid >= 3):
        raise ValueError("fit_sine: f_guess_hz > 0, 0 < span < 1 and n_grid >= 3 are needed")
    t_mid = float(t.mean())
    tc = t - t_mid
    grid = np.linspace(f_guess_hz * (1 - span), f_guess_hz * (1 + span), n_grid)
    sse = np.array([_linear(tc, yy, f)[0] for f in grid])
    k = int(np.argmin(sse))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, n_grid - 1)]
    f = float(minimize_scalar(lambda x: _linear(tc, yy, x)[0], bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-9 * f_guess_hz}).x)
    s, c = _linear(tc, yy, f)
    amp = float(np.hypot(c[0], c[1]))
    phase_mid = float(np.arctan2(c[1], c[0]))            # at t_mid
    phase0 = float(np.angle(np.exp(1j * (phase_mid - 2.0 * np.pi * f * t_mid))))
    return SineFit(amp, f, phase0, float(c[2] - c[3] * t_mid), float(c[3]), float(np.sqrt(s / t.size)), int(t.size))
