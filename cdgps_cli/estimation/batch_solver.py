"""Batch dynamic least squares (Teague, How & Parkinson 1998, Eq. 9–15) in linear time.

The linearized batch problem of Eq. (13)–(15) is

    minimize  Σ_k ‖ρ_k − H_k δx_k − E_k δb‖²_{R⁻¹} + Σ_k ‖w_k‖²_{W⁻¹}
              + ‖δx₁‖²_{X₁⁻¹} + ‖δb‖²_{𝓑⁻¹}
    subject to δx_{k+1} = A δx_k + B_w w_k

(E_k selects the biases of the channels present at epoch k).  Forming Θ of Eq. (13) costs
O(N²) memory and O(N³) time.  :func:`srif_solve` solves the same problem with a square-root
information filter (Bierman) over x_k, the constant biases carried as extra columns, followed by
the Dyer–McReynolds smoother: one QR per epoch (time and measurement update fused), so O(N) time
and memory, with zero prior information allowed (X₁⁻¹ = 𝓑⁻¹ = 0, as in the paper).  Each row
touches one bias, and the measurement rows of an epoch that the state cannot explain (C channels,
fewer state directions) involve only the biases: they are pooled outside the recursion, as a Gram
matrix when the result is well conditioned, in square-root form otherwise.  :func:`dense_solve`
is the literal Eq. (13)–(15) reference used by the tests on short windows.

Both work in absolute variables: given pseudo-measurements ỹ_k = y_k − h(x̂_k) + H_k x̂_k they
return the trajectory x_k, the process-noise sequence w_k and the biases b that minimize the
linearized cost (one Gauss–Newton step).  Priors are given as means and square-root weights.

The SRIF's per-epoch loops (measurement-row split, filter pass, smoother) run in the compiled kernel
when it is available (:mod:`cdgps_cli.estimation.compiled`); the numpy code here is their twin, used
otherwise (``CDGPS_NO_KERNEL=1``) and tested equal to 1e-12.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.blas import dtrmm
from scipy.linalg.lapack import dgeqrf, dpotrf, dtrcon

from cdgps_cli.estimation import compiled

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
    y : ndarray (N, C) or (N, C, K)
        Pseudo-measurements ỹ (metres); NaN where a channel is absent.  With a third axis, K
        right-hand sides solved at once (the same rows absent in each): the solution's x, w, b
        gain the same trailing axis, its cost is NaN (see :func:`srif_solve`).
    bias_index : ndarray (N, C) int
        Bias parameter of each (epoch, channel), −1 where the bias is known (already in ỹ).
    n_bias : int
    sigma_m : float
        Measurement noise (R = σ² I).
    x1_mean, x1_sqrt_info : (n,) or (n, K), (n, n)
        Prior on x₁ (square-root information; zeros = no prior).
    b_mean, b_sqrt_info : (m,) or (m, K), (m, m)
        Prior on the biases.
    E : ndarray (N, C, m), optional
        A general bias incidence per row, for rows already whitened by a full noise covariance
        (each row then mixes several biases; ``bias_index`` is ignored).  Rows whose y is NaN
        are absent.
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
    E: np.ndarray | None = None


@dataclass
class LinearSolution:
    x: np.ndarray            # (N, n) trajectory ((N, n, K) for K right-hand sides)
    w: np.ndarray            # (N-1, r) whitened process noise ω_k (w_k = W^{1/2} ω_k) ((N-1, r, K))
    b: np.ndarray            # (m,) ((m, K))
    cost: float              # minimum of the linearized cost (NaN for K right-hand sides)
    R_end: np.ndarray        # (n+m, n+m) square-root information of z_N = [x_N; b]
    P_end: np.ndarray | None  # covariance of z_N, None if not observable
    rank_deficient: bool


def _qr_inplace(M: np.ndarray) -> np.ndarray:
    """Householder QR of a Fortran-ordered M in place (LAPACK dgeqrf): R on and above the diagonal,
    reflectors below it (callers read only the upper triangle)."""
    qr, _, _, info = dgeqrf(M, overwrite_a=1)
    if info != 0:  # pragma: no cover - LAPACK argument error
        raise RuntimeError(f"dgeqrf failed (info={info})")
    if qr is not M:  # pragma: no cover - f2py made a copy (M not Fortran-contiguous)
        M[...] = qr
    return M


class _BiasRows:
    """Accumulates rows [b | y] that involve only the biases (width m+k, k right-hand sides).

    ``square_root``: the rows are kept as a triangular factor, compressed by a QR about every
    thousand rows (numerically stable).  Otherwise only their Gram matrix Σ rowsᵀrows is kept (cheaper; its
    square root is taken once at the end), which squares the condition number — :func:`srif_solve`
    uses it when the result is well conditioned and redoes the solve in square-root form otherwise.
    """

    def __init__(self, m: int, square_root: bool, k: int = 1):
        self.m, self.k = m, k
        self.square_root = square_root
        self.gram = None if square_root else np.zeros((m + k, m + k))
        self.blocks: list = []
        self.rows = 0

    def add(self, rows: np.ndarray) -> None:
        if rows.shape[0] == 0:
            return
        if not self.square_root:
            self.gram += _gram(rows)
            return
        for i in range(0, rows.shape[0], 1024):           # QRs of at most ~1000 rows (see _gram)
            piece = rows[i:i + 1024]
            if self.rows + piece.shape[0] > 1024 + self.m + self.k:
                self._compress()
            self.blocks.append(piece)
            self.rows += piece.shape[0]

    def add_gram(self, gram: np.ndarray) -> None:
        self.gram += gram

    def _compress(self) -> None:
        if len(self.blocks) > 1 or self.rows > self.m + self.k:
            T = _qr_r(np.asfortranarray(np.vstack(self.blocks)))
            self.blocks = [T]
            self.rows = T.shape[0]

    def sqrt(self) -> np.ndarray | None:
        """Rows S with SᵀS = the accumulated information; None if the Gram's bias block is singular.

        With several right-hand sides (k > 1) the data block of S (which only carries the costs) is
        left zero: the solution does not depend on it."""
        m, k = self.m, self.k
        if self.square_root:
            self._compress()
            return self.blocks[0] if self.blocks else np.zeros((0, m + k))
        G = self.gram
        S = np.zeros((m + k, m + k))
        if m:
            U, info = dpotrf(G[:m, :m], lower=0, clean=1)
            if info != 0:
                return None
            S[:m, :m] = U
            S[:m, m:] = solve_triangular(U, G[:m, m:], trans="T")
        if k == 1:
            S[m, m] = math.sqrt(max(G[m, m] - float(S[:m, m] @ S[:m, m]), 0.0))
        return S


def _gram(rows: np.ndarray, chunk: int = 64) -> np.ndarray:
    """rowsᵀ rows as a sum of small products: OpenBLAS multithreads a single large GEMM, and on a
    busy machine waiting for its threads costs far more than the product itself."""
    R, c = rows.shape
    full = R - R % chunk
    X = rows[:full].reshape(-1, chunk, c)
    G = np.matmul(X.transpose(0, 2, 1), X).sum(axis=0) if full else np.zeros((c, c))
    if full < R:
        G += rows[full:].T @ rows[full:]
    return G


def _measurement_rows(prob: LinearProblem, r: int, pool: _BiasRows) -> np.ndarray:
    """Per-epoch compression of the measurement rows (vectorized over epochs).

    The rows of epoch k are [H_k | E_k | y_k] / σ (E_k: one 1 per row, in the column of the
    channel's bias).  H_k is non-zero only in the columns J (for a modal model: the positions,
    not the rates).  With C channels and |J| < C, a QR H_k[:, J] = Q₁ R₁ splits the rows
    orthogonally into |J| rows Q₁ᵀ[H_k | E_k | y_k] that involve the state, returned for the
    filter, and C − |J| rows Q₂ᵀ[E_k | y_k] that involve only the biases, added to ``pool``: in
    square-root form, or as their Gram matrix Σ [E|y]ᵀ[E|y] − Σ (Q₁ᵀ[E|y])ᵀ(Q₁ᵀ[E|y]), whose first
    term is diagonal (plus the y column) because each row touches one bias.

    Returns (N, q, r+n+m+K): the filter's rows in its column layout [ω | x | b | y] (zero in ω), K
    right-hand sides.
    """
    if prob.E is not None:
        return _measurement_rows_full(prob, r, pool)
    N, C, n = prob.H.shape
    m = prob.n_bias
    s = 1.0 / prob.sigma_m
    Y = _rhs(prob.y)
    present = ~np.isnan(Y[:, :, 0])
    all_present = bool(present.all())
    ys = (Y if all_present else np.where(present[..., None], Y, 0.0)) * s          # (N, C, K)
    bi = prob.bias_index if all_present else np.where(present, prob.bias_index, -1)
    J = np.flatnonzero(prob.H.reshape(-1, n).any(axis=0))
    w = r + n
    reduce = 0 < J.size < C
    q = J.size if reduce else C
    meas = np.zeros((N, q, w + m + ys.shape[2]))
    if not reduce:
        meas[:, :, r:w] = prob.H if all_present else np.where(present[..., None], prob.H, 0.0)
        meas[:, :, r:w] *= s
        meas[:, :, w + m:] = ys
        for c in range(C):
            ks = np.flatnonzero(bi[:, c] >= 0)
            if ks.size:
                meas[ks, c, w + bi[ks, c]] += s
        return meas
    _reduced_rows(prob, ys, bi, J, r, pool, meas)
    return meas


def _rhs(y: np.ndarray) -> np.ndarray:
    """The right-hand sides as (N, C, K) (a view)."""
    return y if y.ndim == 3 else y[:, :, None]


def _reduced_rows(prob: LinearProblem, ys: np.ndarray, bi: np.ndarray, J: np.ndarray, r: int, pool: "_BiasRows",
                  meas: np.ndarray) -> None:
    """:func:`_measurement_rows` when H_k spans |J| < C columns: the filter's rows into ``meas``
    (N, |J|, r+n+m+K), the bias-only rows to ``pool``.  ``ys`` (N, C, K) whitened data (0 where absent),
    ``bi`` (N, C) bias index (−1 where absent or known).  The per-epoch QRs run in the compiled kernel
    (:func:`cdgps_cli.estimation.compiled.reduce_rows`) when it is available, else in numpy
    (:func:`_split_rows_numpy`, its twin)."""
    N, C, n = prob.H.shape
    m, K, q = prob.n_bias, ys.shape[2], J.size
    s = 1.0 / prob.sigma_m
    w = r + n
    present = np.isfinite(_rhs(prob.y)[:, :, 0])
    use_c = compiled.available()
    if not use_c:
        HJ = prob.H[:, :, J]
        HJ[~present] = 0.0
        xcols = slice(r + J[0], r + J[-1] + 1) if J[-1] - J[0] + 1 == J.size else r + J
    step = 1024
    for k0 in range(0, N, step):
        k1 = min(N, k0 + step)
        if use_c:
            other = compiled.reduce_rows(prob.H[k0:k1], J, present[k0:k1], ys[k0:k1], bi[k0:k1], m, s, r,
                                         meas[k0:k1], pool.square_root)
        else:
            R1, EY = _split_rows_numpy(HJ[k0:k1], ys[k0:k1], bi, k0, m, s, pool.square_root)
            meas[k0:k1, :, xcols] = R1 * s
            meas[k0:k1, :, w:] = EY[:, :q]
            other = EY[:, q:]
        if pool.square_root:
            pool.add(other.reshape(-1, m + K))
    if not pool.square_root:
        # Σ [E|y]ᵀ[E|y]: diagonal counts, per-bias sums of y, Σ y²; minus the part kept for the filter
        ok = bi >= 0
        gram = np.zeros((m + K, m + K))
        idx = np.arange(m)
        gram[idx, idx] = s * s * np.bincount(bi[ok], minlength=m)
        for j in range(K):
            gram[idx, m + j] = gram[m + j, idx] = s * np.bincount(bi[ok], weights=ys[:, :, j][ok], minlength=m)
        if K == 1:
            gram[m, m] = float(np.einsum("kc,kc->", ys[:, :, 0], ys[:, :, 0]))
        else:
            gram[m:, m:] = np.einsum("kcl,kcj->lj", ys, ys)
        gram -= _gram(meas[:, :, w:].reshape(N * q, m + K))
        pool.add_gram(gram)


def _split_rows_numpy(HJ: np.ndarray, ys: np.ndarray, bi: np.ndarray, k0: int, m: int, s: float,
                      full: bool) -> tuple[np.ndarray, np.ndarray]:
    """The QRs HJ[k] = Q_k R_k of epochs k0 … k0+len(HJ)−1 (numpy/LAPACK): R₁ (·, q, q) (unscaled) and
    Q_kᵀ[E_k | y_k] (·, q, m+K), or with ``full`` all C rows (the last C − q involve only the biases).
    E_k: s in column ``bi[k, c]`` of row c (none where −1); ``ys`` (·, C, K); ``bi`` (N, C), all epochs."""
    nk, C, q = HJ.shape
    K = ys.shape[2]
    b0 = bi[0]
    ok0 = b0 >= 0
    chan0, bias0 = np.flatnonzero(ok0), b0[ok0]
    # the usual case: every epoch has the same channels, each with its own bias → Qᵀ E is a
    # permutation of Qᵀ's columns (no products needed), often the identity
    permutation = bool((bi == b0).all()) and np.unique(bias0).size == bias0.size
    identity = permutation and C == m and np.array_equal(bias0, np.arange(m))
    if full:
        Q, R = np.linalg.qr(HJ, mode="complete")
    else:
        Q, R = np.linalg.qr(HJ)
    out = np.zeros((nk, Q.shape[2], m + K))
    if identity:
        np.multiply(Q.transpose(0, 2, 1), s, out=out[:, :, :m])
    elif permutation:
        out[:, :, bias0] = s * Q[:, chan0, :].transpose(0, 2, 1)
    else:
        for c in range(C):
            ks = np.flatnonzero(bi[k0:k0 + nk, c] >= 0)
            if ks.size:
                out[ks, :, bi[k0 + ks, c]] += s * Q[ks, c, :]
    if K == 1:
        np.einsum("kcj,kc->kj", Q, ys[:, :, 0], out=out[:, :, m])
    else:
        np.einsum("kcj,kcl->kjl", Q, ys, out=out[:, :, m:])
    return R[:, :q], out


def _measurement_rows_full(prob: LinearProblem, r: int, pool: _BiasRows) -> np.ndarray:
    """:func:`_measurement_rows` for rows with a general bias incidence E_k (whitened full noise).

    The same split: a QR H_k[:, J] = Q R₁ per epoch; the first |J| rows Qᵀ[H_k | E_k | y_k] go to the
    filter, the other C − |J| rows Q₂ᵀ[E_k | y_k] (biases only) to ``pool``.
    """
    N, C, n = prob.H.shape
    m = prob.n_bias
    s = 1.0 / prob.sigma_m
    Y = _rhs(prob.y)
    present = np.isfinite(Y[:, :, 0])
    Hs = np.where(present[..., None], prob.H, 0.0) * s
    EY = np.concatenate([np.where(present[..., None], prob.E, 0.0), np.where(present[..., None], Y, 0.0)], axis=2) * s
    J = np.flatnonzero(Hs.reshape(-1, n).any(axis=0))
    w = r + n
    if not 0 < J.size < C:
        meas = np.zeros((N, C, w + m + Y.shape[2]))
        meas[:, :, r:w] = Hs
        meas[:, :, w:] = EY
        return meas
    q = J.size
    Q, R1 = np.linalg.qr(Hs[:, :, J], mode="complete")
    QtEY = np.matmul(Q.transpose(0, 2, 1), EY)
    meas = np.zeros((N, q, w + m + Y.shape[2]))
    meas[:, :, r + J] = R1[:, :q]
    meas[:, :, w:] = QtEY[:, :q]
    pool.add(np.ascontiguousarray(QtEY[:, q:]).reshape(-1, m + Y.shape[2]))
    return meas


# below this reciprocal condition number (1-norm) of R_end the Gram form of the bias-only rows is
# not accurate enough (it squares the condition number): the solve is redone in square-root form
_RCOND_GRAM = 1e-4


def srif_solve(prob: LinearProblem, square_root: bool | None = None) -> LinearSolution:
    """Solve a :class:`LinearProblem` with a square-root information filter and smoother.

    The filter's unknowns are the state x_k; the biases are carried as extra columns of its
    information array [R_x | R_xb | d] (they are constant, so they need no time update).  Each
    epoch is one QR of the fused time and measurement update

        [ I            0          0       0      ]   prior on ω_{k−1}
        [ −R_x A⁻¹G    R_x A⁻¹    R_xb    d      ]   x_{k−1} = A⁻¹(x_k − G ω_{k−1})
        [ 0            Q₁ᵀH_k     Q₁ᵀE_k  Q₁ᵀy_k ]   measurements of epoch k (:func:`_measurement_rows`)

    triangular in the ω_{k−1} and x_k columns: its first rows are kept for the smoother
    (Dyer–McReynolds), the next ones are the new [R_x | R_xb | d], and the remaining rows involve
    only the biases; they are pooled with the bias-only measurement rows (:class:`_BiasRows`) and
    factored once at the end.  Cost O(N (r+n+q)² (r+n+m)) time, O(N r (r+n+m)) memory.

    ``square_root``: None (default) pools the bias-only rows as a Gram matrix and repeats the solve
    in square-root form if R_end is ill-conditioned (reciprocal condition < 1e-4) or singular —
    e.g. a linearization about a motionless trajectory (H_k the same at every epoch: a constant
    state offset is then indistinguishable from a bias pattern), which goes to the square-root form
    directly; True/False forces one form.
    """
    if square_root is None and _constant_jacobian(prob.H):
        square_root = True              # linearized about a motionless trajectory: singular (see above)
    if square_root is None:
        sol = _srif(prob, square_root=False)
        if sol is not None and not sol.rank_deficient and dtrcon(sol.R_end, norm="1")[0] >= _RCOND_GRAM:
            return sol
        return _srif(prob, square_root=True)
    sol = _srif(prob, square_root=square_root)
    if sol is None:
        raise np.linalg.LinAlgError("bias information not positive definite in Gram form")
    return sol


def _constant_jacobian(H: np.ndarray) -> bool:
    """H_k the same at every epoch (cheap test on three epochs first)."""
    N = H.shape[0]
    if N < 2 or not (np.array_equal(H[0], H[-1]) and np.array_equal(H[0], H[N // 2])):
        return False
    return not np.any(H[1:] != H[:-1])


def _srif(prob: LinearProblem, square_root: bool) -> LinearSolution | None:
    """One SRIF pass and smoother (:func:`srif_solve`); None if the Gram form's bias block is singular."""
    n, m, r = prob.A.shape[0], prob.n_bias, prob.Bw_L.shape[1]
    K = 1 if prob.y.ndim == 2 else prob.y.shape[2]
    Ainv = np.linalg.inv(prob.A)
    AG = np.hstack([-(Ainv @ prob.Bw_L), Ainv])             # x_{k−1} = AG @ [ω_{k−1}; x_k]
    pool = _BiasRows(m, square_root, K)
    Mx, smooth = _forward(prob, AG, pool)
    S = pool.sqrt()
    if S is None:
        return None
    R, d, cost = _final_factor(Mx, n, m, K, S)
    diag = np.abs(np.diag(R))
    scale = max(diag.max(initial=0.0), 1e-300)
    rank_deficient = bool(diag.min(initial=1.0) <= 1e-10 * scale)
    p = n + m
    if rank_deficient:
        z = np.linalg.lstsq(R, d, rcond=1e-12)[0]
        P = None
    else:
        z = solve_triangular(R, d)
        Rinv = solve_triangular(R, np.eye(p))
        P = Rinv @ Rinv.T
    xs, ws = _smooth(smooth, AG, Ainv, z, n, m, r)
    return LinearSolution(xs, ws, z[n:], float(cost), R, P, rank_deficient)


def _forward(prob: LinearProblem, AG: np.ndarray, pool: "_BiasRows") -> tuple[np.ndarray, np.ndarray]:
    """The filter pass of :func:`srif_solve`: the state rows [· | R_x | R_xb | d] (n, r+n+m+K) after
    the last epoch and the smoother's ω rows (N−1, r, r+n+m+K); the bias-only rows go to ``pool``.
    The epoch loop runs in the compiled kernel (:func:`cdgps_cli.estimation.compiled.srif_forward`) when
    it is available, else in :func:`_forward_numpy` (its twin, tested equal)."""
    N, C, n = prob.H.shape
    m, r = prob.n_bias, prob.Bw_L.shape[1]
    K = pool.k
    p, w = n + m, r + n
    ncol = w + m + K
    meas = _measurement_rows(prob, r, pool)                 # zero in the ω columns
    q = meas.shape[1]
    # prior on b: bias-only rows
    pool.add(np.hstack([prob.b_sqrt_info, (prob.b_sqrt_info @ prob.b_mean).reshape(m, K)]))
    # epoch 0: prior on x₁ and the first measurements, columns [x | b | y]
    M0 = np.zeros((n + q, p + K), order="F")
    M0[:n, :n] = prob.x1_sqrt_info
    M0[:n, p:] = (prob.x1_sqrt_info @ prob.x1_mean).reshape(n, K)
    M0[n:, :] = meas[0, :, r:]
    T0 = _qr_r(M0)
    pool.add(T0[n:, n:])
    X = np.zeros((n, ncol))                                 # the state rows, columns [ω | x | b | y]
    X[:, r:w] = T0[:n, :n]
    X[:, w:] = T0[:n, n:]
    smooth = np.empty((max(N - 1, 0), r, ncol))             # ω rows for the smoother
    left = np.empty((max(N - 1, 0), q, m + K))              # bias-only rows left by each update
    if N > 1 and compiled.available():
        compiled.srif_forward(AG, X, meas, smooth, left)
    elif N > 1:
        X = _forward_numpy(X, AG, meas, smooth, left, r)
    if N > 1 and q:
        pool.add(left.reshape(-1, m + K))
    return X, smooth


def _forward_numpy(X: np.ndarray, AG: np.ndarray, meas: np.ndarray, smooth: np.ndarray, left: np.ndarray,
                   r: int) -> np.ndarray:
    """The epoch loop of :func:`_forward` in numpy (the compiled kernel's twin): per epoch k ≥ 1 the QR
    (LAPACK dgeqrf) of [prior on ω; time-updated state rows; measurement rows] (see :func:`srif_solve`).
    Writes ``smooth`` and ``left`` (made upper trapezoidal), returns the state rows after the last epoch."""
    n, ncol = X.shape
    w = r + n
    N, q = meas.shape[:2]
    M = np.zeros((w + q, ncol), order="F")  # rows [0, r): prior on ω, [r, w): x, [w, w+q): data
    M[r:w] = X
    top = np.zeros((r, ncol))
    top[:, :r] = np.eye(r)
    AG = np.asfortranarray(AG)
    for k in range(1, N):
        M[r:w, :w] = dtrmm(1.0, M[r:w, r:w], AG)            # R_x A⁻¹[−G | I]; R_xb and d stay in place
        M[:r] = top
        M[w:] = meas[k]
        _qr_inplace(M)
        smooth[k - 1] = M[:r]
        left[k - 1] = M[w:, w:]
    if q:
        left *= np.triu(np.ones((q, left.shape[2])))        # reflectors below the diagonal
    return M[r:w]


def _final_factor(Mx: np.ndarray, n: int, m: int, K: int, S: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """R_end (p, p), d_end (p,) or (p, K) and the cost (NaN for K > 1): the state rows ``Mx``
    [·| R_x | R_xb | d] at epoch N over the pooled bias rows S."""
    p = n + m
    w = Mx.shape[1] - m - K
    F = np.zeros((n + S.shape[0], p + K), order="F")
    F[:n, :n] = np.triu(Mx[:, w - n:w])
    F[:n, n:] = Mx[:, w:]
    F[n:, n:] = S
    T = _qr_r(F)
    R = np.zeros((p, p))
    d = np.zeros((p, K))
    kk = min(T.shape[0], p)
    R[:kk] = T[:kk, :p]
    d[:kk] = T[:kk, p:]
    if K > 1:
        return R, d, math.nan
    cost = float(T[p, p] ** 2) if T.shape[0] > p else 0.0
    return R, d[:, 0], cost


def _smooth(smooth: np.ndarray, AG: np.ndarray, Ainv: np.ndarray, z: np.ndarray, n: int, m: int, r: int):
    """Dyer–McReynolds smoother: ω_{k−1} = R_w⁻¹ (d_w − R_wx x_k − R_wb b), x_{k−1} = A⁻¹(x_k − G ω_{k−1}),
    from z = [x_N; b] ((p,) or (p, K)).  Returns x (N, n[, K]) and ω (N−1, r[, K]).  In the compiled
    kernel (:func:`cdgps_cli.estimation.compiled.srif_smooth`) when available, else :func:`_smooth_numpy`."""
    if compiled.available():
        return compiled.srif_smooth(smooth, AG, z, smooth.shape[0] + 1, m)
    return _smooth_numpy(smooth, AG, Ainv, z, n, m, r)


def _smooth_numpy(smooth: np.ndarray, AG: np.ndarray, Ainv: np.ndarray, z: np.ndarray, n: int, m: int, r: int):
    """:func:`_smooth` in numpy (the compiled kernel's twin): the gains of all epochs at once, then the
    recursion x_{k−1} = F_k x_k + g_k."""
    N = smooth.shape[0] + 1
    w = r + n
    tail = z.shape[1:]
    xs = np.empty((N, n) + tail)
    ws = np.zeros((max(N - 1, 0), r) + tail)
    xs[-1] = z[:n]
    b = z[n:]
    if N > 1 and r:
        Rw_inv = np.linalg.inv(np.triu(smooth[:, :, :r]))   # well conditioned: unit prior on ω
        Kg = Rw_inv @ smooth[:, :, r:w]                      # (N−1, r, n)
        dy = smooth[:, :, w + m:] if tail else smooth[:, :, -1]
        c = np.einsum("kij,kj...->ki...", Rw_inv, dy - np.einsum("kij,j...->ki...", smooth[:, :, w:w + m], b))
        Fk = AG[:, r:] - AG[:, :r] @ Kg                      # x_{k−1} = F x_k + g
        gk = np.einsum("ij,kj...->ki...", AG[:, :r], c)
        for k in range(N - 2, -1, -1):
            xs[k] = Fk[k] @ xs[k + 1] + gk[k]
        ws[:] = c - np.einsum("kij,kj...->ki...", Kg, xs[1:])
    elif N > 1:
        for k in range(N - 2, -1, -1):
            xs[k] = Ainv @ xs[k + 1]
    return xs, ws


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
            if prob.E is not None:
                row[n + (N - 1) * r:] = prob.E[k, c]
            elif prob.bias_index[k, c] >= 0:
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
