"""The one RTS smoother (cdgps_cli/estimation/smoother.py).

* :func:`rts_smooth_transitions` after the engine's forward filter equals the joint Gaussian posterior
  of the whole chain solved densely (the textbook independent check: smoothed means and marginal
  covariances of a linear-Gaussian state-space model are those of one batch least-squares problem),
  with two epoch spacings (the pass runs in stretches) and epochs without measurements;
* with one spacing it is :func:`rts_smooth` (the pseudolite filter's entry point) to rounding.
(The compiled pass against the numpy one: tests/estimation/test_kernel.py.)
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.estimation.model_filter import filter_numpy
from cdgps_cli.estimation.smoother import rts_smooth, rts_smooth_transitions
from cdgps_cli.measurement.model import MeasurementModel, Rows
from cdgps_cli.model.dynamics_models import Dynamics


class _ConstantVelocity(Dynamics):
    n, n_u = 2, 0

    def transition(self, dt_s):
        A = np.array([[1.0, dt_s], [0.0, 1.0]])
        Q = 0.01 * np.array([[dt_s**3 / 3, dt_s**2 / 2], [dt_s**2 / 2, dt_s]])
        return A, np.zeros((2, 0)), Q


class _Position(MeasurementModel):
    """z_k = x_k[0] + ν, σ = 0.1 (none at the epochs in ``missing``)."""

    def __init__(self, z, missing):
        self.z, self.missing = z, set(missing)
        self.n_epochs, self.n_state, self.segment_keys = len(z), 2, []

    def rows(self, k):
        if k in self.missing:
            return None
        return Rows(np.array([self.z[k]]), [("p",)], np.array([-1]), sigma_m=np.array([0.1]))

    def predict(self, x, rows):
        H = np.array([[1.0, 0.0]])
        return H @ x, H


def _dense_posterior(model, dyn, t, x0, P0):
    """Smoothed means and marginal covariances from the joint information matrix of the chain."""
    N, n = len(t), 2
    J, h = np.zeros((N * n, N * n)), np.zeros(N * n)
    J[:n, :n] += np.linalg.inv(P0)
    h[:n] += np.linalg.inv(P0) @ x0
    for k in range(1, N):
        A, _, Q = dyn.transition(t[k] - t[k - 1])
        Qi = np.linalg.inv(Q)
        T = np.zeros((n, N * n))                     # x_k − A x_{k−1}
        T[:, k * n:(k + 1) * n] = np.eye(n)
        T[:, (k - 1) * n:k * n] = -A
        J += T.T @ Qi @ T
    for k in range(N):
        mk = model.rows(k)
        if mk is None:
            continue
        _, H = model.predict(np.zeros(n), mk)
        W = np.diag(1.0 / mk.sigma_m**2)
        J[k * n:(k + 1) * n, k * n:(k + 1) * n] += H.T @ W @ H
        h[k * n:(k + 1) * n] += H.T @ W @ mk.z_m
    cov = np.linalg.inv(J)
    x = cov @ h
    return x.reshape(N, n), np.array([cov[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(N)])


def test_smoother_equals_the_dense_posterior_with_two_spacings():
    gen = np.random.default_rng(3)
    t = np.r_[np.arange(20.0), 22.0 + np.arange(15.0), 40.0 + 0.5 * np.arange(10)]
    z = np.sin(0.2 * t) + 0.1 * gen.standard_normal(t.size)
    model, dyn = _Position(z, missing=(5, 6, 21)), _ConstantVelocity()
    x0, P0 = np.array([0.0, 0.1]), np.diag([1.0, 0.5])
    fr = filter_numpy(model, dyn, t, x0, P0, max_iterations=1)
    xs, Ps = rts_smooth_transitions(fr["x"], fr["P"], fr["A"], fr["Q"])
    xd, Pd = _dense_posterior(model, dyn, t, x0, P0)
    np.testing.assert_allclose(xs, xd, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(Ps, Pd, rtol=1e-7, atol=1e-12)
    np.testing.assert_array_equal(xs[-1], fr["x"][-1])          # the last epoch is the filtered one


def test_one_spacing_is_the_pseudolite_entry_point():
    gen = np.random.default_rng(5)
    t = np.arange(30.0)
    model, dyn = _Position(gen.standard_normal(30), missing=()), _ConstantVelocity()
    fr = filter_numpy(model, dyn, t, np.zeros(2), np.eye(2), max_iterations=1)
    A, _, Q = dyn.transition(1.0)
    xs, Ps = rts_smooth_transitions(fr["x"], fr["P"], fr["A"], fr["Q"])
    xr, Pr = rts_smooth(A, Q, np.zeros((2, 0)), np.zeros((30, 0)), fr["x"], fr["P"])
    np.testing.assert_allclose(xs, xr, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(Ps, Pr, rtol=1e-12, atol=1e-14)
    one = rts_smooth_transitions(fr["x"][:1], fr["P"][:1], fr["A"][:1], fr["Q"][:1])
    np.testing.assert_array_equal(one[0], fr["x"][:1])
