"""Batch dynamic least squares (Teague, How & Parkinson 1998, Eq. 9–15) in linear time.

The linearized batch problem of Eq. (13)–(15) is

    minimize  Σ_k ‖ρ_k − H_k δx_k − E_k δb‖²_{R⁻¹} + Σ_k ‖w_k‖²_{W⁻¹}
              + ‖δx₁‖²_{X₁⁻¹} + ‖δb‖²_{𝓑⁻¹}
    subject to δx_{k+1} = A δx_k + B_w w_k

(E_k selects the biases of the channels present at epoch k).  Forming Θ of Eq. (13) costs
O(N²) memory and O(N³) time.  :func:`srif_solve` solves the same problem with a square-root
information filter (Bierman) over the augmented state z_k = [x_k; b] followed by the
Dyer–McReynolds smoother: a QR per epoch, so O(N) time and memory, and numerically stable with
zero prior information (X₁⁻¹ = 𝓑⁻¹ = 0 is allowed, as in the paper).  :func:`dense_solve` is the
literal Eq. (13)–(15) reference used by the tests on short windows.

Both work in absolute variables: given pseudo-measurements ỹ_k = y_k − h(x̂_k) + H_k x̂_k they
return the trajectory x_k, the process-noise sequence w_k and the biases b that minimize the
linearized cost (one Gauss–Newton step).  Priors are given as means and square-root weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dgeqrf, dtrtrs

_MASKS: dict = {}


def _qr_r(M: np.ndarray) -> np.ndarray:
    """Upper-trapezoidal R of a QR factorization (LAPACK dgeqrf; sign convention irrelevant)."""
    qr, _, _, info = dgeqrf(M, overwrite_a=1)
    if info != 0:  # pragma: no cover - LAPACK argument error
        raise RuntimeError(f"dgeqrf failed (info={info})")
    k = min(M.shape)
    shape = (k, M.shape[1])
    mask = _MASKS.get(shape)
    if mask is None:
        mask = _MASKS[shape] = np.triu(np.ones(shape))
    return qr[:k] * mask


def _tri_solve(R: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve R x = b for upper-triangular R (LAPACK dtrtrs, no checks)."""
    x, info = dtrtrs(R, b)
    if info > 0:
        raise np.linalg.LinAlgError("singular triangular factor")
    return x


@dataclass
class LinearProblem:
    """One linearized batch problem on a regular epoch grid.

    Attributes
    ----------
    A : ndarray (n, n)
        Discrete transition.
    Bw_L : ndarray (n, r)
        B_w W^{1/2}: process noise enters as B_w W^{1/2} ω_k with ω_k ~ N(0, I); r may be 0.
    H : ndarray (N, C, n)
        Measurement Jacobians per epoch and channel.
    y : ndarray (N, C)
        Pseudo-measurements ỹ (metres); NaN where a channel is absent.
    bias_index : ndarray (N, C) int
        Bias parameter of each (epoch, channel), −1 where the bias is known (already in ỹ).
    n_bias : int
    sigma_m : float
        Measurement noise (R = σ² I).
    x1_mean, x1_sqrt_info : (n,), (n, n)
        Prior on x₁ (square-root information; zeros = no prior).
    b_mean, b_sqrt_info : (m,), (m, m)
        Prior on the biases.
    """

    A: np.ndarray
    Bw_L: np.ndarray
    H: np.ndarray
    y: np.ndarray
    bias_index: np.ndarray
    n_bias: int
    sigma_m: float
    x1_mean: np.ndarray
    x1_sqrt_info: np.ndarray
    b_mean: np.ndarray
    b_sqrt_info: np.ndarray


@dataclass
class LinearSolution:
    x: np.ndarray            # (N, n) trajectory
    w: np.ndarray            # (N-1, r) whitened process noise ω_k (w_k = W^{1/2} ω_k)
    b: np.ndarray            # (m,)
    cost: float              # minimum of the linearized cost
    R_end: np.ndarray        # (n+m, n+m) square-root information of z_N = [x_N; b]
    P_end: np.ndarray | None  # covariance of z_N, None if not observable
    rank_deficient: bool


def srif_solve(prob: LinearProblem) -> LinearSolution:
    """Solve a :class:`LinearProblem` with a square-root information filter and smoother.

    Cost O(N (n+m)² (n+m+C)) time and O(N r (r+n+m)) memory.
    """
    A, G = prob.A, prob.Bw_L
    N, C, n = prob.H.shape
    m = prob.n_bias
    r = G.shape[1]
    p = n + m
    Ainv = np.linalg.inv(A)
    AinvG = Ainv @ G
    inv_sigma = 1.0 / prob.sigma_m
    # prior information array [R | d] on z_1
    R = np.zeros((p, p))
    d = np.zeros(p)
    R[:n, :n] = prob.x1_sqrt_info
    d[:n] = prob.x1_sqrt_info @ prob.x1_mean
    R[n:, n:] = prob.b_sqrt_info
    d[n:] = prob.b_sqrt_info @ prob.b_mean
    cost = 0.0
    store_R_w = np.empty((max(N - 1, 0), r, r))
    store_R_wz = np.empty((max(N - 1, 0), r, p))
    store_d_w = np.empty((max(N - 1, 0), r))
    for k in range(N):
        # measurement update
        ok = ~np.isnan(prob.y[k])
        if ok.any():
            Hk = prob.H[k, ok] * inv_sigma
            c = Hk.shape[0]
            M = np.zeros((p + c, p + 1), order="F")
            M[:p, :p] = R
            M[:p, p] = d
            M[p:, :n] = Hk
            bi = prob.bias_index[k, ok]
            known = bi >= 0
            M[p + np.flatnonzero(known), n + bi[known]] = inv_sigma
            M[p:, p] = prob.y[k, ok] * inv_sigma
            T = _qr_r(M)
            R = T[:p, :p]
            d = T[:p, p]
            if T.shape[0] > p:
                cost += T[p, p] ** 2
        if k == N - 1:
            break
        # time update: eliminate z_k = F⁻¹ (z_{k+1} − G ω_k)
        M = np.zeros((r + n, r + p + 1), order="F")
        M[:r, :r] = np.eye(r)
        Rxx = R[:n, :n]
        M[r:, :r] = -Rxx @ AinvG
        M[r:, r:r + n] = Rxx @ Ainv
        M[r:, r + n:r + p] = R[:n, n:]
        M[r:, r + p] = d[:n]
        T = _qr_r(M)
        store_R_w[k] = T[:r, :r]
        store_R_wz[k] = T[:r, r:r + p]
        store_d_w[k] = T[:r, r + p]
        Rn = np.zeros((p, p))
        dn = np.zeros(p)
        rows = min(T.shape[0] - r, n)
        Rn[:rows, :] = T[r:r + rows, r:r + p]
        dn[:rows] = T[r:r + rows, r + p]
        # bias rows are untouched by the time update (b is constant)
        Rn[n:, n:] = R[n:, n:]
        dn[n:] = d[n:]
        # re-triangularize (the x rows may now have entries left of the diagonal only if rows < n)
        R, d = Rn, dn
    # final estimate
    diag = np.abs(np.diag(R))
    scale = max(diag.max(initial=0.0), 1e-300)
    rank_deficient = bool(diag.min(initial=1.0) <= 1e-10 * scale)
    if rank_deficient:
        z = np.linalg.lstsq(R, d, rcond=1e-12)[0]
        P = None
    else:
        z = solve_triangular(R, d)
        Rinv = solve_triangular(R, np.eye(p))
        P = Rinv @ Rinv.T
    xs = np.empty((N, n))
    ws = np.zeros((max(N - 1, 0), r))
    xs[-1] = z[:n]
    b = z[n:]
    for k in range(N - 2, -1, -1):
        zk1 = np.concatenate([xs[k + 1], b])
        if r:
            ws[k] = _tri_solve(store_R_w[k], store_d_w[k] - store_R_wz[k] @ zk1)
            xs[k] = Ainv @ (xs[k + 1] - G @ ws[k])
        else:
            xs[k] = Ainv @ xs[k + 1]
    return LinearSolution(xs, ws, b, float(cost), R, P, rank_deficient)


def dense_solve(prob: LinearProblem) -> LinearSolution:
    """Literal Eq. (13)–(15): build Θ and solve the normal equations (reference, O(N³)).

    Unknowns are (x₁, ω₁…ω_{N−1}, b) in absolute form; with zero priors and ŵ = 0 this is exactly
    Eq. (15) of the paper.
    """
    A, G = prob.A, prob.Bw_L
    N, C, n = prob.H.shape
    m = prob.n_bias
    r = G.shape[1]
    nv = n + (N - 1) * r + m
    rows, rhs = [], []
    # Φ_k = ∂x_k/∂[x₁, ω]: x_k = A^{k-1} x₁ + Σ_{i<k} A^{k-1-i} G ω_i
    Phi = np.zeros((n, n + (N - 1) * r))
    Phi[:, :n] = np.eye(n)
    for k in range(N):
        if k > 0:
            Phi = A @ Phi
            Phi[:, n + (k - 1) * r:n + k * r] += G
        ok = ~np.isnan(prob.y[k])
        for c in np.flatnonzero(ok):
            row = np.zeros(nv)
            row[:n + (N - 1) * r] = prob.H[k, c] @ Phi
            if prob.bias_index[k, c] >= 0:
                row[n + (N - 1) * r + prob.bias_index[k, c]] = 1.0
            rows.append(row / prob.sigma_m)
            rhs.append(prob.y[k, c] / prob.sigma_m)
    Theta = np.array(rows)
    yv = np.array(rhs)
    # normal equations (Eq. 15) with priors: X₁⁻¹, 𝒲⁻¹ = I (whitened ω), 𝓑⁻¹
    Nmat = Theta.T @ Theta
    v = Theta.T @ yv
    Sx = prob.x1_sqrt_info.T @ prob.x1_sqrt_info
    Nmat[:n, :n] += Sx
    v[:n] += Sx @ prob.x1_mean
    idx_w = slice(n, n + (N - 1) * r)
    Nmat[idx_w, idx_w] += np.eye((N - 1) * r)
    Sb = prob.b_sqrt_info.T @ prob.b_sqrt_info
    Nmat[n + (N - 1) * r:, n + (N - 1) * r:] += Sb
    v[n + (N - 1) * r:] += Sb @ prob.b_mean
    sol = np.linalg.solve(Nmat, v)
    x1 = sol[:n]
    w = sol[idx_w].reshape(N - 1, r) if r else np.zeros((N - 1, 0))
    b = sol[n + (N - 1) * r:]
    xs = np.empty((N, n))
    xs[0] = x1
    for k in range(1, N):
        xs[k] = A @ xs[k - 1] + (G @ w[k - 1] if r else 0.0)
    res = Theta @ sol - yv
    cost = float(res @ res + np.sum(w**2) + (x1 - prob.x1_mean) @ Sx @ (x1 - prob.x1_mean)
                 + (b - prob.b_mean) @ Sb @ (b - prob.b_mean))
    return LinearSolution(xs, w, b, cost, np.zeros((0, 0)), None, False)
