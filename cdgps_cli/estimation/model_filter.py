"""Forward filter and RTS smoother over the engine's interfaces (a
:class:`~cdgps_cli.measurement.model.MeasurementModel` and a :class:`~cdgps_cli.model.dynamics_models.Dynamics`).

:func:`filter_numpy` is the reference path: an iterated extended Kalman filter whose measurement
update is in information form on the rows whitened by their noise (diagonal σ or the Cholesky
factor of a full covariance, so R = I after whitening).  Integrity is given to it as hooks on the
rows of each epoch (:class:`Integrity`): new ambiguity segments and the innovation outlier gate.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve

__all__ = ["filter_numpy", "iterated_update", "rts_smooth"]


def filter_numpy(model, dyn, time_s, x0, P0, max_iterations: int = 5, rows_hook=None) -> dict:
    """Iterated EKF over the epochs of ``model`` (reference numpy path).

    Each epoch: predict with ``dyn.transition(Δt)``, then the measurement update on the whitened
    rows, iterated (Gauss–Newton) while the correction exceeds 1e-9 of the state, at most
    ``max_iterations`` times.

    Parameters
    ----------
    model : MeasurementModel
    dyn : Dynamics
    time_s : ndarray (N,)
        Epoch times, s.
    x0, P0 : ndarray (n,), (n, n)
        Prior at the first epoch.
    max_iterations : int
    rows_hook : callable, optional
        ``rows_hook(k, rows, x, P) -> rows or None``: integrity on the epoch's rows before the
        update (drop rows, re-bias); None keeps them.

    Returns
    -------
    dict
        ``x`` (N, n), ``P`` (N, n, n) filtered; ``A``, ``Q`` (N, n, n) the transition into each
        epoch (zero at k = 0); ``nis`` (N,), ``nis_dof`` (N,) int; ``rows`` (list of Rows or None).
    """
    n, ns = len(time_s), len(x0)
    out = {"x": np.zeros((n, ns)), "P": np.zeros((n, ns, ns)), "A": np.zeros((n, ns, ns)), "Q": np.zeros((n, ns, ns)),
           "nis": np.full(n, np.nan), "nis_dof": np.zeros(n, dtype=np.int64), "rows": [None] * n}
    x, P = np.array(x0, dtype=float), np.array(P0, dtype=float)
    for k in range(n):
        if k:
            A, _, Q = dyn.transition(float(time_s[k] - time_s[k - 1]))
            out["A"][k], out["Q"][k] = A, Q
            x = A @ x
            P = A @ P @ A.T + Q
        mk = model.rows(k)
        if mk is not None and rows_hook is not None:
            mk = rows_hook(k, mk, x, P)
        if mk is not None:
            out["rows"][k] = mk
            x, P, out["nis"][k] = iterated_update(model, mk, x, P, max_iterations)
            out["nis_dof"][k] = mk.z_m.size
        out["x"][k], out["P"][k] = x, P
    return out


def iterated_update(model, mk, xbar, Pbar, max_iterations: int = 5):
    """(x, P, NIS) of one iterated information-form update on the whitened rows ``mk``.

    NIS uses the prior linearization: νᵀ(HPHᵀ + I)⁻¹ν = νᵀν − νᵀH(P⁻¹ + HᵀH)⁻¹Hᵀν (whitened ν, H).
    """
    zw = mk.whiten(mk.z_m)
    Pinv = np.linalg.inv(Pbar)
    xi = xbar.copy()
    nis = np.nan
    for it in range(max(int(max_iterations), 1)):
        h, H = model.predict(xi, mk)
        H = mk.whiten(H)
        hw = mk.whiten(h)
        cf = cho_factor(Pinv + H.T @ H)
        v = zw - hw - H @ (xbar - xi)               # whitened innovation at the iterate
        if it == 0:
            hv = H.T @ v
            nis = float(v @ v - hv @ cho_solve(cf, hv))
        x_new = xbar + cho_solve(cf, H.T @ v)
        step = np.max(np.abs(x_new - xi))
        xi = x_new
        if step <= 1e-9 * max(1.0, float(np.max(np.abs(xi)))):
            break
    P = cho_solve(cf, np.eye(len(xbar)))
    return xi, 0.5 * (P + P.T), nis


def rts_smooth(xf, Pf, As, Qs):
    """Rauch–Tung–Striebel pass over filtered (xf, Pf) (N, n), (N, n, n) with the transitions
    As[k], Qs[k] into epoch k; returns smoothed (xs, Ps)."""
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(len(xf) - 2, -1, -1):
        A, Q = As[k + 1], Qs[k + 1]
        Pp = A @ Pf[k] @ A.T + Q
        G = cho_solve(cho_factor(Pp), A @ Pf[k]).T
        xs[k] = xf[k] + G @ (xs[k + 1] - A @ xf[k])
        Pk = Pf[k] + G @ (Ps[k + 1] - Pp) @ G.T
        Ps[k] = 0.5 * (Pk + Pk.T)
    return xs, Ps
