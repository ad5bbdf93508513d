"""One Kalman step: prediction through a linear(ized) transition and an information-form update.

The update takes one epoch's linearized rows — residuals ρ = z − h(x̄) (m), the Jacobian H and the
noise as a diagonal σ or a full covariance's Cholesky factor — whitens them (ρ_w = L⁻¹ρ, H_w = L⁻¹H),
and applies

    P⁺ = (P̄⁻¹ + H_wᵀ H_w)⁻¹,   x⁺ = x̄ + P⁺ H_wᵀ ρ_w,   NIS = ρ_wᵀ ρ_w − (H_wᵀρ_w)ᵀ P⁺ (H_wᵀρ_w)

(the last is ρᵀ(H P̄ Hᵀ + R)⁻¹ρ by the matrix inversion lemma).  1998 paper Eq. (16)–(23) in
information form; both noise kinds of the architecture's filter.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular


def predict(x: np.ndarray, P: np.ndarray, A: np.ndarray, Q: np.ndarray, known_input=None):
    """x̄ = A x (+ known input), P̄ = A P Aᵀ + Q.

    Parameters
    ----------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    A, Q : ndarray, shape (n, n)
        Transition and process-noise covariance over the step.
    known_input : ndarray, shape (n,), optional
        The state change due to known inputs over the step (e.g. B u, or the exact response to
        fired thruster pulses).
    """
    xb = A @ x if known_input is None else A @ x + known_input
    Pb = A @ P @ A.T + Q
    return xb, 0.5 * (Pb + Pb.T)


def whiten(residual_m, H, sigma_m=None, noise_chol=None):
    """Whitened rows: (ρ/σ, H/σ) for a diagonal noise, (L⁻¹ρ, L⁻¹H) for R = L Lᵀ."""
    r = np.asarray(residual_m, dtype=float)
    H = np.asarray(H, dtype=float)
    if noise_chol is not None:
        L = np.asarray(noise_chol, dtype=float)
        return solve_triangular(L, r, lower=True), solve_triangular(L, H, lower=True)
    s = np.broadcast_to(np.asarray(sigma_m, dtype=float), r.shape)
    return r / s, H / s[:, None]


def update(xb: np.ndarray, Pb: np.ndarray, residual_m, H, sigma_m=None, noise_chol=None):
    """Information-form measurement update of one epoch.

    Parameters
    ----------
    xb, Pb : ndarray, shapes (n,), (n, n)
        Predicted state and covariance.
    residual_m : array_like, shape (p,)
        ρ = z − h(x̄), m.
    H : array_like, shape (p, n)
        ∂h/∂x at x̄.
    sigma_m : float or array_like, shape (p,), optional
        Diagonal noise standard deviations, m.
    noise_chol : array_like, shape (p, p), optional
        Lower Cholesky factor of a full noise covariance (instead of ``sigma_m``).

    Returns
    -------
    x, P : ndarray
        Updated state and covariance.
    nis : float
        Normalized innovation squared ρᵀ S⁻¹ ρ with S = H P̄ Hᵀ + R (dof p).
    """
    rw, Hw = whiten(residual_m, H, sigma_m, noise_chol)
    info = _inverse_spd(Pb) + Hw.T @ Hw
    c = cho_factor(info, lower=True)
    v = Hw.T @ rw
    dx = cho_solve(c, v)
    P = cho_solve(c, np.eye(len(xb)))
    return xb + dx, 0.5 * (P + P.T), float(rw @ rw - v @ dx)


def _inverse_spd(M: np.ndarray) -> np.ndarray:
    c = cho_factor(M, lower=True)
    inv = cho_solve(c, np.eye(M.shape[0]))
    return 0.5 * (inv + inv.T)
