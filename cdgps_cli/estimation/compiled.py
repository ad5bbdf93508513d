"""The compiled extension ``cdgps_cli.estimation._ekfcore``: loading, API check, and the wrapper of its
geometry-free routine, the batch solver's epoch loop (:func:`srif_forward`).

:mod:`cdgps_cli.estimation.kernel` holds the wrappers that need the structure's geometry (the forward
filter, the measurement model) and re-exports these names.  The extension is optional:
:func:`available` is false when it was not compiled, when its API does not match this module, or
when the environment variable ``CDGPS_NO_KERNEL`` is set to anything but ``""`` / ``"0"`` (tests use
it to force the numpy paths).
"""

from __future__ import annotations

import os

import numpy as np

try:
    from cdgps_cli.estimation import _ekfcore
except ImportError:                      # not compiled (no C compiler at install time)
    _ekfcore = None

API = 5                                 # 2: per-channel measurement variance (R = diag(r_var)); 3: dd_span;
                                        # 4: filter_span writes H(x_k) P_k H(x_k)ᵀ per used channel (hph);
                                        # 5: srif_forward and phase_model_batch (batch initialization)


def available() -> bool:
    """True when the compiled kernel is importable, current, and not disabled by CDGPS_NO_KERNEL."""
    if os.environ.get("CDGPS_NO_KERNEL", "") not in ("", "0"):
        return False
    return _ekfcore is not None and getattr(_ekfcore, "API", None) == API


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def srif_forward(AG: np.ndarray, X: np.ndarray, meas: np.ndarray, smooth: np.ndarray, left: np.ndarray) -> None:
    """The epoch loop of :func:`cdgps_cli.estimation.batch_solver._forward` in C (same arithmetic as its numpy
    twin ``_forward_numpy`` up to rounding: one Householder QR per epoch, triangular in the ω and x columns).

    Parameters
    ----------
    AG : ndarray (n, r+n)
        A⁻¹[−B_w W^{1/2} | I] (x_{k−1} = AG [ω_{k−1}; x_k]).
    X : ndarray (n, r+n+m+K), updated in place
        The state rows [0 | R_x | R_xb | d] after epoch 0 on entry, after the last epoch on return (zero
        below R_x's diagonal and in the ω columns).
    meas : ndarray (N, q, r+n+m+K)
        Each epoch's compressed measurement rows, zero in the ω columns (epoch 0 is not read).
    smooth : ndarray (N−1, r, r+n+m+K), written
        The ω rows of each update, for the smoother.
    left : ndarray (N−1, q, m+K), written
        The bias-only rows each update leaves (not triangular).
    """
    n, w = AG.shape
    N, q, ncol = meas.shape
    for name, arr in (("X", X), ("smooth", smooth), ("left", left)):
        if arr.dtype != np.float64 or not arr.flags.c_contiguous or not arr.flags.writeable:
            raise ValueError(f"srif_forward: {name} must be a writable C-contiguous float64 array")
    _ekfcore.srif_forward(_f64(AG), X, _f64(meas), smooth, left, N, w - n, n, q, ncol)


def reduce_rows(H: np.ndarray, J: np.ndarray, present: np.ndarray, ys: np.ndarray, bi: np.ndarray, m: int,
                s: float, r: int, meas: np.ndarray, full: bool) -> np.ndarray | None:
    """Per epoch k the Householder QR H[k][:, J] = Q_k R_k (LAPACK's convention) and the rows Q_kᵀ[E_k | y_k]
    of :func:`cdgps_cli.estimation.batch_solver._reduced_rows` in C (its numpy twin: ``_split_rows_numpy``).

    Parameters
    ----------
    H : ndarray (N, C, n)
        Whitened measurement Jacobians; only the columns ``J`` (q < C of them) are non-zero.
    J : ndarray (q,) int
    present : ndarray (N, C) bool
        Rows of absent channels take no part (zero).
    ys : ndarray (N, C, K)
        Whitened right-hand sides (zero where absent).
    bi : ndarray (N, C) int
        Bias parameter of each row (−1: none); E_k[c, bi[k, c]] = ``s``.
    m : int
        Number of bias parameters.
    s : float
        1/σ, the whitening of the bias incidence and of R (R₁ is written as s·R).
    r : int
        ω columns before the state's in ``meas``.
    meas : ndarray (N, q, r+n+m+K), written
        s·R_k in the columns r + J, the first q rows of Q_kᵀ[E_k | y_k] in the last m+K columns.
    full : bool
        Also return the C − q rows that involve only the biases, (N, C−q, m+K); else None.
    """
    N, C, n = H.shape
    q, K = len(J), ys.shape[2]
    if meas.dtype != np.float64 or not meas.flags.c_contiguous or not meas.flags.writeable:
        raise ValueError("reduce_rows: meas must be a writable C-contiguous float64 array")
    other = np.empty((N, C - q, m + K)) if full else np.empty(0)
    _ekfcore.reduce_rows(_f64(H), np.ascontiguousarray(J, dtype=np.int64), np.ascontiguousarray(present, dtype=np.uint8),
                         _f64(ys), np.ascontiguousarray(bi, dtype=np.int64), meas, other,
                         N, C, n, q, m, K, r, meas.shape[2], float(s), bool(full))
    return other if full else None


def srif_smooth(smooth: np.ndarray, AG: np.ndarray, z: np.ndarray, N: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The Dyer–McReynolds smoother of :func:`cdgps_cli.estimation.batch_solver._smooth` in C (its numpy
    twin: ``_smooth_numpy``): ω_{k−1} = R_w⁻¹(d_w − R_wx x_k − R_wb b), x_{k−1} = AG [ω_{k−1}; x_k].

    Parameters
    ----------
    smooth : ndarray (N−1, r, r+n+m+K)
        The ω rows of each update (:func:`srif_forward`).
    AG : ndarray (n, r+n)
    z : ndarray (n+m,) or (n+m, K)
        [x_N; b].
    N, m : int
        Epochs and bias parameters.

    Returns
    -------
    x : ndarray (N, n[, K]) and ω : ndarray (N−1, r[, K]), with z's trailing axis.
    """
    n, w = AG.shape
    r = w - n
    tail = z.shape[1:]
    K = int(np.prod(tail)) if tail else 1
    xs = np.empty((N, n, K))
    ws = np.empty((max(N - 1, 0), r, K))
    _ekfcore.srif_smooth(_f64(smooth), _f64(AG), _f64(z).reshape(-1), xs, ws, N, r, n, m, K)
    return xs.reshape((N, n) + tail), ws.reshape((max(N - 1, 0), r) + tail)
