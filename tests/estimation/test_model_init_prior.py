"""The stationary prior of the model-aided batch initialization (estimation/model_init.py, issue 30):
a direction the window cannot see (here a mode no row measures; on GNSS a mode at the data's Nyquist
frequency) is held by the prior instead of left arbitrary, and the batch posterior covariance is the
dense information-form posterior of the same linear-Gaussian problem (computed here independently,
by stacking every unknown [x₁, w, b] in one normal matrix)."""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.batch_init import InitOptions
from cdgps_cli.estimation.model_init import model_batch_init, stationary_covariance
from cdgps_cli.measurement.model import Rows

DT = 0.5
N_EP = 12
SIGMA = 0.01


def _oscillators(freqs_hz=(0.3, 0.9), zeta=0.05, q=0.2):
    """Two damped modes [ξ₁, ξ₂, ξ̇₁, ξ̇₂], exact discretization at DT (Euler–Maruyama force noise)."""
    from scipy.linalg import expm

    nm = len(freqs_hz)
    w = 2 * np.pi * np.asarray(freqs_hz)
    Ac = np.block([[np.zeros((nm, nm)), np.eye(nm)], [-np.diag(w**2), -np.diag(2 * zeta * w)]])
    A = expm(Ac * DT)
    G = np.vstack([np.zeros((nm, nm)), np.eye(nm) * q * np.sqrt(DT)])
    return A, G


class _Dyn:
    def __init__(self, A, G):
        self.A, self.G = A, G

    def transition(self, dt_s):
        return self.A, np.zeros((self.A.shape[0], 0)), self.G @ self.G.T

    def noise_factor(self, dt_s):
        return self.G


class _Model:
    """Linear rows z = H x + b (one bias per row, constant over the window), σ = SIGMA: H sees mode 1
    only (position and rate), so mode 2 is unobservable."""

    H = np.array([[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.3, 0.0], [0.0, 0.0, 1.0, 0.0]])

    def __init__(self, z):
        self.z = z

    def rows(self, k):
        return Rows(z_m=self.z[k], labels=[(0, c) for c in range(3)], segment=np.array([0, 1, -1]),
                    sigma_m=np.full(3, SIGMA))

    def predict(self, x, rows):
        return self.H @ x, self.H.copy()


def _data(A, G, seed=0):
    rng = np.random.default_rng(seed)
    x = [np.array([0.02, -0.01, 0.05, 0.03])]
    for _ in range(N_EP - 1):
        x.append(A @ x[-1] + G @ rng.standard_normal(G.shape[1]))
    b = np.array([3.0, -1.5, 0.0])
    return np.array([_Model.H @ xk + b + SIGMA * rng.standard_normal(3) for xk in x])


def _dense_posterior(A, G, P1):
    """Covariance of [x_N, b] from the dense normal matrix of θ = [x₁, w₁…w_{N−1}, b]: rows
    (H x_k + E b)/σ with x_k = A^{k−1} x₁ + Σ_j A^{k−1−j} G w_j, priors x₁ ~ N(0, P1), w ~ N(0, I)."""
    n, r = G.shape
    p = n + (N_EP - 1) * r + 2
    T = np.zeros((n, p))
    T[:, :n] = np.eye(n)
    E = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    J = []
    for k in range(N_EP):
        if k:
            T = A @ T
            T[:, n + (k - 1) * r:n + k * r] += G
        Tk = T.copy()
        Tk[:, -2:] = 0.0
        J.append(np.hstack([_Model.H @ Tk[:, :-2], E]) / SIGMA)
    J = np.vstack(J)
    info = J.T @ J
    info[:n, :n] += np.linalg.inv(P1)
    info[n:n + (N_EP - 1) * r, n:n + (N_EP - 1) * r] += np.eye((N_EP - 1) * r)
    T_end = np.vstack([np.hstack([T[:, :-2], np.zeros((n, 2))]), np.hstack([np.zeros((2, p - 2)), np.eye(2)])])
    return T_end @ np.linalg.solve(info, T_end.T)


def test_stationary_covariance_is_the_fixed_point():
    A, G = _oscillators()
    P = stationary_covariance(A, G @ G.T)
    np.testing.assert_allclose(A @ P @ A.T + G @ G.T, P, rtol=1e-10, atol=1e-14)
    assert stationary_covariance(np.eye(2), np.eye(2)) is None          # a random walk has no stationary spread


def test_posterior_with_the_prior_is_the_dense_information_form():
    A, G = _oscillators()
    P1 = stationary_covariance(A, G @ G.T)
    res = model_batch_init(_Model(_data(A, G)), _Dyn(A, G), range(N_EP), DT, 1.0,
                           InitOptions(fix_integers=False), prior_cov=P1)
    dense = _dense_posterior(A, G, P1)
    np.testing.assert_allclose(res.P_end, dense[:4, :4], rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(res.float_sigma_m, np.sqrt(np.diag(dense[4:, 4:])), rtol=1e-6)
    # the unobserved mode keeps its prior: neither invented by the fit nor more certain than the prior
    np.testing.assert_allclose(res.P_end[np.ix_([1, 3], [1, 3])], P1[np.ix_([1, 3], [1, 3])], rtol=1e-6)
    assert np.all(np.abs(res.x[:, [1, 3]]) < 1e-9)


def test_without_the_prior_the_unseen_mode_is_not_observable():
    A, G = _oscillators()
    with pytest.raises(CdgpsError, match="not observable|singular|converge"):
        model_batch_init(_Model(_data(A, G)), _Dyn(A, G), range(N_EP), DT, 1.0, InitOptions(fix_integers=False))


def test_modal_prior_is_the_stationary_sway_plus_the_broad_start():
    """tower-fusion's process noise is tuned to a stationary sway of about 5 cm, 2 cm, 5 mm, 1 mm at the top
    (its config); the prior adds the broad start σ; a rigid mode (gnss-tower) leaves the broad part alone."""
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.gnss_modal import modal_prior_covariance

    P = modal_prior_covariance(load_config("configs/tower-fusion.toml"), 0.0, 0.0)
    np.testing.assert_allclose(np.sqrt(np.diag(P))[:4], [0.05, 0.02, 0.005, 0.001], rtol=0.01)
    P1 = modal_prior_covariance(load_config("configs/tower-fusion.toml"), 0.1, 0.2)
    np.testing.assert_allclose(P1 - P, np.diag([0.01] * 4 + [0.04] * 4), atol=1e-15)
    np.testing.assert_array_equal(modal_prior_covariance(load_config("configs/gnss-tower.toml"), 1.0, 2.0),
                                  np.diag([1.0] * 3 + [4.0] * 3))
