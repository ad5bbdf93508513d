"""Exact response of the modal model to thruster pulses that start and stop inside a sample period.

With ẋ = A_c x + B_c u and u piecewise constant, the state change over a period of length T due to a
force F on thruster j during [a, b] ⊂ [0, T] is

    ∫_a^b e^{A_c (T − s)} ds B_c[:, j] F = (Γ(T − a) − Γ(T − b)) B_c[:, j] F,   Γ(τ) = ∫_0^τ e^{A_c s} ds.

A_c is diagonalizable for modal damping (distinct eigenvalues per mode), so with A_c = V Λ V⁻¹,
Γ(τ) = V diag(φ(λ, τ)) V⁻¹ and φ(λ, τ) = (e^{λτ} − 1)/λ (τ for λ = 0).  A pulse over the whole
period gives the zero-order-hold B (tested against :func:`cdgps_cli.model.dynamics.zoh`).
"""

from __future__ import annotations

import numpy as np


def _phi(lam: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(e^{λτ} − 1)/λ, with its limit τ where λ = 0; shapes broadcast."""
    lt = lam * tau
    small = np.abs(lam) < 1e-12
    safe = np.where(small, 1.0, lam)
    return np.where(small, tau * (1 + lt / 2), np.expm1(lt) / safe)


class PulseResponse:
    """State change over one period from on-intervals of thrusters (see the module docstring).

    Parameters
    ----------
    Ac : ndarray, shape (n, n)
        Continuous state matrix.
    Bc : ndarray, shape (n, m)
        Continuous input matrix (per newton of each thruster).
    period_s : float
        T, s.
    """

    def __init__(self, Ac: np.ndarray, Bc: np.ndarray, period_s: float):
        lam, V = np.linalg.eig(np.asarray(Ac, dtype=float))
        self.lam, self.V = lam, V
        self.W = np.linalg.solve(V, np.asarray(Bc, dtype=float))      # V⁻¹ B_c, (n, m)
        self.T = float(period_s)

    def __call__(self, thruster, start_s, end_s, force_n) -> np.ndarray:
        """Sum of the responses of pulses (arrays of equal length: thruster index, start, end, force).

        Returns
        -------
        ndarray, shape (n,)
            State change at the end of the period, in the state's units.
        """
        j = np.asarray(thruster, dtype=int)
        if j.size == 0:
            return np.zeros(self.V.shape[0])
        a = np.asarray(start_s, dtype=float)
        b = np.asarray(end_s, dtype=float)
        g = _phi(self.lam[:, None], (self.T - a)[None, :]) - _phi(self.lam[:, None], (self.T - b)[None, :])
        coef = (g * self.W[:, j] * np.asarray(force_n, dtype=float)[None, :]).sum(axis=1)
        return (self.V @ coef).real
