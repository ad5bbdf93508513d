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
