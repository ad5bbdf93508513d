"""The exactly linear 3-mode structure and the textbook Kalman filter/RTS smoother used as oracles
by the filter, kernel, rest-mode and window-smoother tests (imported as ``_linear_case``)."""

from __future__ import annotations

import numpy as np

LINEAR_CONFIG = """
# exactly linear h(x): modal coordinates, antennas moved by displacement_m only, far-field sources
[model]
name = "linear-3"
sample_period_s = 0.2
measurement_sigma_m = 0.01

[[coordinates]]
name = "u1"
kind = "modal"
[[coordinates]]
name = "u2"
kind = "modal"
[[coordinates]]
name = "u3"
kind = "modal"

[[antennas]]
name = "m"
position_m = [0.0, 0.0, 0.0]
master = true
displacement_m = { u1 = [0.0, 0.1, 0.02] }

[[antennas]]
name = "r1"
position_m = [2.0, 0.0, 0.0]
line_bias_m = 0.013
displacement_m = { u1 = [0.3, 0.5, 0.1], u2 = [0.0, 0.4, -0.2] }

[[antennas]]
name = "r2"
position_m = [0.0, 2.0, 0.0]
displacement_m = { u2 = [0.6, -0.1, 0.2], u3 = [0.1, 0.0, 0.5] }

[[antennas]]
name = "r3"
position_m = [-2.0, -1.0, 0.5]
line_bias_m = -0.021
displacement_m = { u1 = [-0.2, 0.1, 0.3], u3 = [0.4, 0.4, 0.0] }

[[transmitters]]
name = "S1"
direction = [0.0, 0.0, 1.0]
[[transmitters]]
name = "S2"
direction = [0.6, 0.0, 0.8]
[[transmitters]]
name = "S3"
direction = [0.0, -0.6, 0.8]
[[transmitters]]
name = "S4"
direction = [-0.48, 0.64, 0.6]

[[modes]]
name = "m1"
frequency_hz = 0.3
time_constant_s = 20.0
shape = [1.0, 0.5, 0.0]
[[modes]]
name = "m2"
frequency_hz = 0.7
time_constant_s = 10.0
shape = [0.0, 1.0, -0.5]
[[modes]]
name = "m3"
frequency_hz = 1.1
time_constant_s = 5.0
shape = [0.3, 0.0, 1.0]

[process_noise]
space = "modal"
sigma = [0.2, 0.3, 0.4]

[simulation]
phase_sigma_m = 0.01
initial_modal_sigma = 0.2
disturbance_scale = 1.0
"""
LIN_SIGMA = 0.01
LIN_SLIP = "r2:S3:12.0:+3"


def textbook_kf(A, Q, H, R, z, x0, P0, inflate=None):
    """Covariance-form Kalman filter with the Joseph update; ``inflate`` {k: [(i, q)]} adds q to
    P[i, i] after the time update of epoch k.  Returns filtered x, P, priors and NIS."""
    N, p = len(z), len(x0)
    I = np.eye(p)
    x, P = x0.copy(), P0.copy()
    xf, Pf, xp, Pp, nis = np.empty((N, p)), np.empty((N, p, p)), np.empty((N, p)), np.empty((N, p, p)), np.empty(N)
    for k in range(N):
        if k:
            x = A @ x
            P = A @ P @ A.T + Q
        for i, q in (inflate or {}).get(k, ()):
            P[i, i] += q
        xp[k], Pp[k] = x, P
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        nu = z[k] - H @ x
        nis[k] = nu @ np.linalg.solve(S, nu)
        x = x + K @ nu
        IKH = I - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T
        xf[k], Pf[k] = x, P
    return xf, Pf, xp, Pp, nis


def textbook_rts(A, xf, Pf, xp, Pp):
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(len(xf) - 2, -1, -1):
        G = Pf[k] @ A.T @ np.linalg.inv(Pp[k + 1])
        xs[k] = xf[k] + G @ (xs[k + 1] - xp[k + 1])
        Ps[k] = Pf[k] + G @ (Ps[k + 1] - Pp[k + 1]) @ G.T
    return xs, Ps


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))
