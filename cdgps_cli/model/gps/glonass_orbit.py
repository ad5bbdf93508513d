"""GLONASS satellite positions and clocks from broadcast state vectors (GLONASS ICD, edition 5.1, §A.3.1.2).

A GLONASS broadcast ephemeris is a state vector in the Earth-fixed PZ-90 frame at the reference
time t_b — position, velocity and the luni-solar acceleration, the latter held constant over the
interval — plus the clock terms τ_n (bias) and γ_n (relative frequency offset).  The position at
another time comes from integrating the equations of motion in the rotating frame (ICD
§A.3.1.2, the simplified algorithm for |t − t_b| ≤ 15 min, used here up to 30 min):

    dx/dt = v_x,  dy/dt = v_y,  dz/dt = v_z
    dv_x/dt = −μ x/r³ − 3/2 J₂ μ a_e² x/r⁵ (1 − 5 z²/r²) + ω² x + 2 ω v_y + ẍ_ls
    dv_y/dt = −μ y/r³ − 3/2 J₂ μ a_e² y/r⁵ (1 − 5 z²/r²) + ω² y − 2 ω v_x + ÿ_ls
    dv_z/dt = −μ z/r³ − 3/2 J₂ μ a_e² z/r⁵ (3 − 5 z²/r²) + z̈_ls

with the fourth-order Runge–Kutta method (steps ≤ :data:`RK4_MAX_STEP_S`, each record its own).  The clock correction in
the GPS sense (t_sys = t_sv − Δt_sv) is Δt_sv = −τ_n + γ_n (t − t_b).  PZ-90.11 and WGS-84 (G1762)
agree to a few centimetres, so positions are used as WGS-84 without a transformation.  Times are GPS
seconds; the RINEX reader has already moved t_b from UTC(SU) to GPS time.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GM_GLONASS", "A_E_GLONASS", "J2_GLONASS", "OMEGA_E_GLONASS", "RK4_MAX_STEP_S", "glonass_derivative",
           "glonass_position"]

GM_GLONASS = 3.9860044e14
"""Earth gravitational constant of PZ-90 (GLONASS ICD 2008, Table 3.2), m³/s²."""
A_E_GLONASS = 6378136.0
"""Semi-major axis of the PZ-90 ellipsoid, m."""
J2_GLONASS = 1082625.75e-9
"""Second zonal harmonic of the geopotential, J₂⁰ (GLONASS ICD 2008), dimensionless."""
OMEGA_E_GLONASS = 7.292115e-5
"""Earth rotation rate of PZ-90, rad/s."""
RK4_MAX_STEP_S = 60.0
"""Largest Runge–Kutta step, s (the orbit error of 60 s steps over 15 min is below a millimetre)."""


def glonass_derivative(state: np.ndarray, accel_ls: np.ndarray) -> np.ndarray:
    """Time derivative of GLONASS states in the rotating PZ-90 frame (ICD §A.3.1.2).

    Parameters
    ----------
    state : ndarray, shape (N, 6)
        Position (m) and velocity (m/s), Earth-fixed.
    accel_ls : ndarray, shape (N, 3)
        Luni-solar acceleration of the broadcast record, m/s² (constant over the interval).

    Returns
    -------
    ndarray, shape (N, 6)
        [v, a] in m/s and m/s².
    """
    x, y, z = state[:, 0], state[:, 1], state[:, 2]
    vx, vy = state[:, 3], state[:, 4]
    r2 = x * x + y * y + z * z
    r = np.sqrt(r2)
    mu_r3 = GM_GLONASS / (r2 * r)
    j2 = 1.5 * J2_GLONASS * GM_GLONASS * A_E_GLONASS**2 / (r2 * r2 * r)
    zz = 5.0 * z * z / r2
    w2 = OMEGA_E_GLONASS**2
    ax = -mu_r3 * x - j2 * x * (1.0 - zz) + w2 * x + 2.0 * OMEGA_E_GLONASS * vy + accel_ls[:, 0]
    ay = -mu_r3 * y - j2 * y * (1.0 - zz) + w2 * y - 2.0 * OMEGA_E_GLONASS * vx + accel_ls[:, 1]
    az = -mu_r3 * z - j2 * z * (3.0 - zz) + accel_ls[:, 2]
    return np.column_stack([state[:, 3:6], ax, ay, az])


def glonass_position(state0: np.ndarray, accel_ls: np.ndarray, dt_s, *, max_step_s: float = RK4_MAX_STEP_S):
    """Integrate GLONASS broadcast states from t_b to t_b + ``dt_s`` (RK4, vectorized over records).

    Parameters
    ----------
    state0 : ndarray, shape (N, 6)
        Position (m) and velocity (m/s) at t_b, Earth-fixed PZ-90.
    accel_ls : ndarray, shape (N, 3)
        Luni-solar accelerations, m/s².
    dt_s : array_like, shape (N,)
        t − t_b per record, s (either sign).
    max_step_s : float
        Largest step, s: each record takes its own number of equal steps, max(1, ceil(|dt| / max_step_s)),
        so its value depends on its own state and time alone, never on the other records of the call (a
        window of a record gives the whole record's values bit for bit, issue 29).

    Returns
    -------
    ndarray, shape (N, 6)
        Position (m) and velocity (m/s) at t.
    """
    s = np.array(state0, dtype=np.float64, copy=True)
    acc = np.asarray(accel_ls, dtype=np.float64)
    dt = np.asarray(dt_s, dtype=np.float64).reshape(-1)
    if dt.size == 0:
        return s
    span = np.abs(dt) / max_step_s
    steps = np.ones(dt.size, dtype=np.int64)          # a time that is not finite: one step of it, NaN out
    finite = np.isfinite(span)
    steps[finite] = np.maximum(1.0, np.ceil(span[finite]))
    h = (dt / steps)[:, None]
    for k in range(int(steps.max())):
        go = np.flatnonzero(steps > k)          # the records still stepping (all of them while k < min(steps))
        s[go] = _rk4_step(s[go], acc[go], h[go])
    return s


def _rk4_step(s: np.ndarray, acc: np.ndarray, h: np.ndarray) -> np.ndarray:
    """One classical Runge–Kutta step of :func:`glonass_derivative` of length ``h`` (N, 1) s from ``s`` (N, 6)."""
    k1 = glonass_derivative(s, acc)
    k2 = glonass_derivative(s + 0.5 * h * k1, acc)
    k3 = glonass_derivative(s + 0.5 * h * k2, acc)
    k4 = glonass_derivative(s + h * k3, acc)
    return s + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
