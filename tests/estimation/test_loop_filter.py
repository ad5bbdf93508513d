"""The closed loop's step filter (estimation/loop_filter.py) against a dense textbook Kalman filter."""

import numpy as np

from cdgps_cli.estimation.loop_filter import INITIAL_ESTIMATE_SIGMA, LoopFilter


class _Inactive:
    active = False


def _textbook(x, P, z, H, R):
    """Covariance-form update x + K(z − Hx), (I − KH) P (I − KH)ᵀ + K R Kᵀ."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    v = z - H @ x
    IKH = np.eye(len(x)) - K @ H
    return x + K @ v, IKH @ P @ IKH.T + K @ R @ K.T, float(v @ np.linalg.solve(S, v))


def test_steps_equal_the_textbook_filter_on_a_linear_model():
    g = np.random.default_rng(3)
    n, C = 4, 6
    A = np.eye(n) + 0.05 * g.normal(size=(n, n))
    Q = 1e-4 * np.eye(n)
    H = g.normal(size=(C, n))
    sigma = np.full(C, 0.02)
    f = LoopFilter(A, Q, C, _Inactive(), 0.1)
    x_true = g.normal(size=n)
    f.start(x_true)
    x, P = x_true.copy(), INITIAL_ESTIMATE_SIGMA**2 * np.eye(n)
    h_of = lambda s: (H @ s, H)  # noqa: E731
    for k in range(20):
        z = H @ x_true + sigma * g.normal(size=C)
        xf, Pf, nis = f.update(z, h_of, sigma)
        x, P, nis_ref = _textbook(x, P, z, H, np.diag(sigma**2))
        np.testing.assert_allclose(xf, x, rtol=0, atol=1e-10)
        np.testing.assert_allclose(Pf, P, rtol=0, atol=1e-12)
        assert nis == np.float64(nis) and abs(nis - nis_ref) < 1e-8 * max(1.0, nis_ref)
        u = 0.01 * g.normal(size=n)                      # the known state change of the firings
        f.predict(u)
        x, P = A @ x + u, A @ P @ A.T + Q
        x_true = A @ x_true + u
