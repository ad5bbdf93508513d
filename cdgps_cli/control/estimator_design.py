"""The in-loop filter's process noise, chosen for the regulator it serves (separation rule).

The EKF of the closed loop does not know the disturbances it must help reject (the Fig. 9 pulse is
fired open loop); how fast it follows them is set by its fictitious process noise W against the
measurement noise R.  The paper tuned W = diag(0.5², …, 0.05²) "for fast response with small
overshoot" on its own modal scaling and reports an estimator converging in 0.5–1 s against
vibration poles settling in about 5 s.  With our thruster model the regulator's vibration poles are
faster (about 1.7 s), and the paper's W leaves the estimator barely faster than the regulator
(about 1.2 s), so the estimate lags the pulse and the regulator reacts late.

Rule (Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, the paper's Ref. 25: place
the estimator's roots 2–6 times faster than the controller's): W_loop = s·W with s ≥ 1 the smallest
scale for which, mode by mode, every pole of the steady-state filter's error dynamics settles (2 %)
at least :data:`ESTIMATOR_SEPARATION` times faster than the regulator's slowest pole of that mode.
Modes the regulator does not move (its closed-loop settling equals the open loop's, e.g. the
testbed's swing mode, which the jets cannot force) are exempt.  The filter is linearized about the
rest state x = 0; R is the config's σ per channel (what the loop's EKF weights with).

The rule answers a pulse the filter does not know.  The paper's time update (Eq. 18) predicts with
the thruster commands its computer issued; read as including the Fig. 9 pulse, the filter follows it
with the paper's W itself, and the rule is not needed for the pulse (docs/testbed-model.md, "What
limits the closed-loop pulse"; ``pulse_known`` of :mod:`cdgps_cli.pipeline.closed_loop`).

Numerics only: arrays in, numbers out.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_discrete_are

from cdgps_cli.config.structure import StructureConfig, channel_sigma_m
from cdgps_cli.control.poles import pole_table, slowest_settling_by_mode
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.phase import EpochPhaseModel, all_channels
from cdgps_cli.model.dynamics import discrete_model

#: estimator poles settle at least this many times faster than the regulator's (Ref. 25: 2–6)
ESTIMATOR_SEPARATION = 3.0
#: largest process-noise scale searched (beyond it the Riccati equation loses conditioning)
MAX_PROCESS_NOISE_SCALE = 1e4
#: a mode counts as moved by the regulator when its settling time shrinks by more than this fraction
MOVED_FRACTION = 0.01


def estimator_error_matrix(A: np.ndarray, Q: np.ndarray, H: np.ndarray, sigma_m) -> np.ndarray:
    """A − A L H of the steady-state (predictor) Kalman filter, L = P̄Hᵀ(HP̄Hᵀ + R)⁻¹.

    Parameters
    ----------
    A, Q : ndarray, shape (n, n)
        Discrete transition and process-noise covariance per step.
    H : ndarray, shape (p, n)
        Measurement Jacobian, m per unit state.
    sigma_m : float or array_like, shape (p,)
        Measurement noise σ per row, m.
    """
    n = A.shape[0]
    R = np.diag(np.broadcast_to(np.asarray(sigma_m, dtype=float), (H.shape[0],)) ** 2)
    # a tiny floor keeps the DARE well posed for states the noise does not drive (rigid angle)
    try:
        P = solve_discrete_are(A.T, H.T, Q + 1e-12 * np.eye(n), R)
        L = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise CdgpsError(f"the in-loop filter has no steady state (a mode the measurements do not see?): {exc}") from None
    return A - A @ L @ H


def _shortfall(A, Q, H, sigma_m, T, names, limits: dict) -> float:
    """max over constrained modes of (estimator settling / allowed settling); ≤ 1 meets the rule
    (infinite when the filter has no steady state at this Q)."""
    try:
        t = slowest_settling_by_mode(pole_table(estimator_error_matrix(A, Q, H, sigma_m), T, names))
    except CdgpsError:
        return math.inf
    worst = 0.0
    for mode, allowed in limits.items():
        if mode in t:
            worst = max(worst, math.inf if t[mode] is None else t[mode] / allowed)
    return worst


def separation_limits(A: np.ndarray, B: np.ndarray, K: np.ndarray, T: float, names,
                      separation: float = ESTIMATOR_SEPARATION) -> dict:
    """Allowed estimator settling per mode moved by u = −K x: its regulator settling / separation, s."""
    ol = slowest_settling_by_mode(pole_table(A, T, names))
    cl = slowest_settling_by_mode(pole_table(A - B @ K, T, names))
    limits = {}
    for mode, tc in cl.items():
        to = ol.get(mode)
        if tc is not None and (to is None or tc < (1.0 - MOVED_FRACTION) * to):
            limits[mode] = tc / separation
    return limits


def loop_process_noise_scale(A: np.ndarray, B: np.ndarray, K: np.ndarray, Q: np.ndarray, H: np.ndarray, sigma_m,
                             T: float, names, separation: float = ESTIMATOR_SEPARATION) -> dict:
    """The separation rule's scale s of the filter's process noise (module docstring).

    Parameters
    ----------
    A, B : ndarray, shapes (n, n), (n, m)
        Discrete model, state [ξ, ξ̇].
    K : ndarray, shape (m, n)
        The regulator in use (u = −K x).
    Q : ndarray, shape (n, n)
        The filter's nominal process-noise covariance per step (the config's W through B_w).
    H : ndarray, shape (p, n)
        Measurement Jacobian at the linearization point.
    sigma_m : float or array_like, shape (p,)
        Measurement noise σ per row, m.
    T : float
        Sample period, s.
    names : sequence of str
        Mode names, length n / 2.
    separation : float
        Required ratio of regulator to estimator settling, > 0.

    Returns
    -------
    dict
        ``scale`` (s ≥ 1), ``separation``, ``met``, ``closest_scale`` (the scale that comes closest
        to the rule), ``limits_s`` (allowed estimator settling per mode) and ``estimator_settling_s``
        (per mode, at s).  When no scale up to :data:`MAX_PROCESS_NOISE_SCALE` meets the rule
        (``met`` False) the filter keeps the config's W (s = 1): a faster filter cannot restore the
        separation and only passes more measurement noise to the regulator (docs/control.md: the
        paper's weights slew in 26 s with s = 1, in 50 s with the closest scale, 1000).

    Raises
    ------
    CdgpsError
        If ``separation`` is not positive.
    """
    if not (np.isfinite(separation) and separation > 0):
        raise CdgpsError(f"estimator separation: expected a positive number, got {separation!r}")
    limits = separation_limits(A, B, K, T, names, separation)

    def meets(s):
        return _shortfall(A, s * Q, H, sigma_m, T, names, limits) <= 1.0

    # first scale on a grid of quarter decades that meets the rule, then bisection below it (the
    # filter's poles speed up with s until the Riccati equation loses conditioning, far above)
    grid = np.arange(0.0, math.log10(MAX_PROCESS_NOISE_SCALE) + 1e-9, 0.25)
    short = [_shortfall(A, 10.0**g * Q, H, sigma_m, T, names, limits) for g in grid]
    ok = [i for i, v in enumerate(short) if v <= 1.0][:1]
    met = bool(ok)
    closest = float(10.0 ** grid[int(np.argmin(short))])
    if not ok:                                    # reported, not refused; the config's W is kept
        scale = 1.0
    elif ok[0] == 0:
        scale = 1.0
    else:
        lo, hi = grid[ok[0] - 1], grid[ok[0]]
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if meets(10.0**mid) else (mid, hi)
        scale = 10.0**hi
    try:
        t = slowest_settling_by_mode(pole_table(estimator_error_matrix(A, scale * Q, H, sigma_m), T, names))
    except CdgpsError:
        t, met = {}, False
    return {"scale": float(scale), "separation": float(separation), "met": met,
            "closest_scale": float(scale) if met else closest, "limits_s": limits, "estimator_settling_s": t}


def loop_estimator(cfg: StructureConfig, K: np.ndarray) -> dict:
    """The in-loop EKF's process-noise scale for the regulator K by the separation rule
    (:func:`cdgps_cli.control.estimator_design.loop_process_noise_scale`, linearized at rest), with a
    ``rule`` sentence for the run's record."""
    model = discrete_model(cfg)
    ant, tx = all_channels(cfg)
    _, H = EpochPhaseModel(cfg, ant, tx)(np.zeros(model.A.shape[0]))
    sigma = channel_sigma_m(cfg, [(cfg.antenna_names[a], cfg.transmitter_names[t]) for a, t in zip(ant, tx)])
    out = loop_process_noise_scale(model.A, model.B, K, model.Q, H, sigma, model.T, list(cfg.mode_names))
    rule = f"estimator poles {out['separation']:g}x faster than the regulator's, mode by mode"
    out["rule"] = (f"config W scaled by {out['scale']:.4g}: {rule}" if out["met"] else
                   f"the config's W is kept (scale 1): the rule ({rule}) is NOT met by any scale up to "
                   f"{MAX_PROCESS_NOISE_SCALE:g} (closest {out['closest_scale']:.4g})")
    return out
