"""Integer ambiguity resolution with the LAMBDA method.

This module solves the integer least-squares (ILS) problem

.. math::

    \\check{a} = \\arg\\min_{z \\in \\mathbb{Z}^n} (\\hat{a} - z)^T Q^{-1} (\\hat{a} - z)

for a float ambiguity vector :math:`\\hat{a}` (cycles) with covariance
:math:`Q` (cycles^2), following the Least-squares AMBiguity Decorrelation
Adjustment of Teunissen (1993) with the shrinking-ellipsoid search of the
modified LAMBDA method (Chang, Yang & Zhou, 2005).  The algorithmic
structure mirrors the well known RTKLIB implementation (``lambda.c``):

1. ``ld_factorize``: :math:`Q = L^T \\operatorname{diag}(d) L` with ``L``
   unit lower triangular (note: *not* the usual :math:`L D L^T`; the
   factorisation runs from the last ambiguity to the first so that the
   search below conditions on the last component first).
2. ``decorrelate``: integer Gauss transformations and adjacent
   permutations (the LAMBDA "reduction") produce a unimodular integer
   matrix ``Z`` such that :math:`z = Z^T a` has covariance
   :math:`Z^T Q Z = L^T \\operatorname{diag}(d) L` with ``L`` (close to)
   size reduced and ``d`` (close to) ordered.
3. ``search``: depth-first Schnorr-Euchner enumeration whose radius
   shrinks to the worst of the best ``m`` candidates found so far.

The public entry points are :func:`lambda_search`, :func:`ratio_test` and
:func:`partial_fix`.  All functions are pure: they never modify their
array arguments.

Units: ambiguities in cycles, covariances in cycles^2, squared norms are
dimensionless (cycles^2 / cycles^2).
"""

from __future__ import annotations

import math
import numbers
import os

import numpy as np

from cdgps_cli.config.options import RATIO_THRESHOLD
from cdgps_cli.core.errors import AmbiguityError  # noqa: F401 (defined there, raised and named here)

try:
    from cdgps_cli.estimation import _lambdacore
except ImportError:                      # not compiled (no C compiler at install time): the Python loops
    _lambdacore = None

#: the API of ``_lambdacore`` this module calls
LAMBDA_API = 2

__all__ = [
    "bootstrap_success_rate",
    "success_tail",
    "success_tail_rate",
    "AmbiguityError",
    "SearchLimitError",
    "ld_factorize",
    "ld_factorize_symmetric",
    "decorrelate",
    "resolve_cascaded",
    "conditioned_on_integers",
    "search_reduced",
    "search",
    "lambda_search",
    "ratio_test",
    "partial_fix",
    "resolve",
]

#: Relative tolerance used when checking that ``Q`` is symmetric: the
#: largest asymmetry ``|Q - Q^T|`` must not exceed this times ``max|Q|``.
SYMMETRY_RTOL = 1e-9

#: A pivot ``d[i]`` of the L^T D L factorisation is considered non-positive
#: (matrix not positive definite) when ``d[i] <= PIVOT_RTOL * n * max(diag Q)``.
PIVOT_RTOL = np.finfo(float).eps

#: The permutation step of the reduction is only taken when it reduces the
#: conditional variance ``d[k+1]`` by more than this *relative* amount
#: (prevents cycling on ties caused by rounding; relative so that the
#: reduction does not depend on the scale of ``Q``).
PERM_RTOL = 1e-6

#: Largest accepted magnitude of a float ambiguity (cycles): beyond 2**52 a
#: float64 cannot carry a fractional part any more.
MAX_ABS_AMBIGUITY = 2.0**52


#: Default cap on the nodes one integer search may visit (RTKLIB's LOOPMAX is 10000 loops of its
#: search; a node here is one loop).  A decorrelated, well-determined set of 500 ambiguities
#: needs about 1000-3000 nodes per search; a search that gets near the cap is enumerating a
#: float solution too weak to fix, which is refused with :class:`SearchLimitError` instead of
#: running for minutes.
SEARCH_MAX_NODES = 200_000

#: Levels of the search at or above this index update the conditional estimates with one numpy
#: slice operation; below it, with a Python list (numpy's per-call overhead exceeds the work).
SEARCH_NUMPY_LEVEL = 24




class SearchLimitError(AmbiguityError):
    """The integer search exceeded its node cap (:data:`SEARCH_MAX_NODES` by default)."""


def _kernel():
    """The compiled kernels ``_lambdacore`` (the same arithmetic as :func:`_reduce` and :func:`_enumerate`,
    bit-identical results), or None when not compiled, of another API, or disabled by the environment
    variable ``CDGPS_NO_KERNEL`` (anything but ``""`` / ``"0"``, as for the EKF kernel)."""
    if _lambdacore is None or getattr(_lambdacore, "API", None) != LAMBDA_API:
        return None
    return None if os.environ.get("CDGPS_NO_KERNEL", "") not in ("", "0") else _lambdacore


def _check_cap(max_nodes):
    """Validate a node cap (None: the default), return it as int."""
    if max_nodes is None:
        return SEARCH_MAX_NODES
    if isinstance(max_nodes, bool) or not isinstance(max_nodes, numbers.Integral) or max_nodes < 1:
        raise AmbiguityError(f"max_nodes must be an integer >= 1, got {max_nodes!r}")
    return int(max_nodes)


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def _round_half_up(x):
    """Round to nearest integer with ties towards +inf (``floor(x + 0.5)``)."""
    return np.floor(np.asarray(x, dtype=float) + 0.5)


def _as_square_matrix(Q, name="Q"):
    Qa = np.asarray(Q, dtype=float)
    if Qa.ndim != 2 or Qa.shape[0] != Qa.shape[1]:
        raise AmbiguityError(f"{name} must be a square 2-D matrix, got shape {Qa.shape}")
    if Qa.shape[0] < 1:
        raise AmbiguityError(f"{name} must be at least 1x1, got shape {Qa.shape}")
    if not np.all(np.isfinite(Qa)):
        raise AmbiguityError(f"{name} contains non-finite values (NaN or inf)")
    return Qa


def _asymmetry(Q):
    """Return (max |Q - Q^T|, allowed tolerance)."""
    scale = float(np.max(np.abs(Q))) if Q.size else 0.0
    return float(np.max(np.abs(Q - Q.T))), SYMMETRY_RTOL * max(scale, np.finfo(float).tiny)


# ---------------------------------------------------------------------------
# 1. factorisation
# ---------------------------------------------------------------------------


def ld_factorize(Q):
    """Factorise a covariance matrix as ``Q = L^T diag(d) L``.

    Parameters
    ----------
    Q : array_like, shape (n, n)
        Symmetric positive definite covariance of the float ambiguities
        (cycles^2).  Asymmetry up to ``SYMMETRY_RTOL * max|Q|`` is tolerated
        and removed by symmetrising.

    Returns
    -------
    L : ndarray, shape (n, n), float64
        Unit lower-triangular factor.
    d : ndarray, shape (n,), float64
        Positive diagonal (conditional variances, cycles^2); ``d[i]`` is the
        variance of ambiguity ``i`` conditioned on ambiguities ``i+1..n-1``.

    Raises
    ------
    AmbiguityError
        If ``Q`` is not a finite, square, symmetric positive definite matrix.

    Notes
    -----
    ``d[i]`` is the pivot obtained when eliminating from the last ambiguity
    upwards.  It is computed as a Cholesky factorisation of the
    index-reversed matrix: with ``J`` the reversal permutation,
    ``J Q J = C C^T`` (``C`` lower) gives ``Q = U U^T`` with
    ``U = J C J`` upper triangular, hence ``d = diag(U)**2`` and
    ``L = (U / sqrt(d)).T``.  A pivot ``d[i] <= PIVOT_RTOL * n * max(diag Q)``
    is treated as loss of positive definiteness.  Cost O(n^3) in LAPACK.
    """
    Qa = _as_square_matrix(Q)
    asym, tol = _asymmetry(Qa)
    if asym > tol:
        raise AmbiguityError(
            f"Q is not symmetric positive definite: not symmetric "
            f"(max |Q - Q^T| = {asym:.3g} > tolerance {tol:.3g})"
        )
    return ld_factorize_symmetric(0.5 * (Qa + Qa.T))


def ld_factorize_symmetric(A):
    """:func:`ld_factorize` of a matrix already exactly symmetric (e.g. ``0.5 * (Q + Q.T)``): the same
    factors, without the input checks (shape, finiteness, asymmetry), for per-epoch callers that
    symmetrise themselves.  A non-finite or indefinite ``A`` still fails, in the Cholesky
    factorisation or the pivot check (AmbiguityError).

    Parameters
    ----------
    A : ndarray, shape (n, n), float64
        Symmetric covariance, cycles².

    Returns
    -------
    L : ndarray, shape (n, n)
    d : ndarray, shape (n,)
        As :func:`ld_factorize`.
    """
    n = A.shape[0]
    try:
        C = np.linalg.cholesky(A[::-1, ::-1])
    except np.linalg.LinAlgError as exc:
        raise AmbiguityError(
            "Q is not symmetric positive definite (Cholesky factorisation failed)"
        ) from exc
    U = C[::-1, ::-1]
    sq = U.diagonal().copy()
    d = sq * sq
    pivot_floor = PIVOT_RTOL * n * max(float(A.diagonal().max()), 0.0)
    low = ~(d > pivot_floor)
    if low.any():
        i = int(np.flatnonzero(low)[-1])
        raise AmbiguityError(
            f"Q is not symmetric positive definite: pivot d[{i}] = {d[i]:.6g} "
            f"is not significantly positive in the L^T D L factorisation"
        )
    L = np.ascontiguousarray((U / sq).T)
    return L, d


# ---------------------------------------------------------------------------
# 2. reduction (decorrelation)
# ---------------------------------------------------------------------------


def _reduce(L, d, *, z=None, on_tail=None):
    """LAMBDA reduction (integer Gauss transformations and adjacent permutations), vectorized.

    Parameters
    ----------
    L : array_like, shape (n, n)
        Unit lower-triangular factor of ``Q = L^T diag(d) L`` (:func:`ld_factorize`).
    d : array_like, shape (n,)
        Conditional variances, cycles^2.
    z : list of float, length n, optional
        Float ambiguities, transformed in place along with ``L`` (``z <- Z^T z``).
    on_tail : callable, optional
        ``on_tail(k, L, d, z, n_ops)`` is called once for every ``k = n-1 … 1`` at the moment the
        trailing block ``[k, n)`` is reduced, before the reduction goes on with index ``k - 1``
        (the arrays are the working ones: read, do not keep or modify).  Every operation recorded
        up to then involves only indices ``>= k``, so ``L[k:, k:]``, ``d[k:]``, ``z[k:]`` and
        ``ops[:n_ops]`` are a complete reduction of the ambiguities ``k … n-1`` on their own
        (without the final size-reduction pass, which changes neither ``d`` nor the integer
        solution).  This is what lets :func:`partial_fix` resolve every nested subset from one
        reduction.

    Returns
    -------
    Lr : ndarray, shape (n, n)
        Reduced unit lower-triangular factor.
    dl : ndarray, shape (n,)
        Reduced conditional variances.
    ops : list of (i, j, mu) tuples
        The transformation as a sequence of elementary operations on the
        ambiguity vector ``z``: ``mu != 0`` is the integer Gauss
        transformation ``z_j <- z_j - mu z_i``; ``mu == 0`` swaps ``z_i``
        and ``z_j`` (``j == i + 1``).  ``Z`` is the product of the
        corresponding elementary matrices in order.

    Notes
    -----
    Strategy: walk the adjacent pairs ``(k, k+1)`` from the end; before testing a pair the whole
    column ``k`` below the diagonal is size-reduced (as in the original LAMBDA and RTKLIB's
    ``reduction``); after a swap the walk steps back one pair, since only the pairs ``k-1``, ``k``
    and ``k+1`` are affected by the swap.  Every column right of the walk is thus size-reduced
    at all times.  Reducing only the sub-diagonal element ``L[k+1, k]`` (MLAMBDA's lazy strategy)
    lets the other entries grow through the swaps' row combinations without bound: on a
    well-conditioned 47x47 real-data covariance (eigenvalues 8.6e-5..7.5, 1066 swaps) they reached
    1e39, the Gauss integers 1e80, and ``Z`` could not be formed (and was meaningless in floating
    point); reduced eagerly the largest integer there is 23.  A final pass size-reduces any entry
    still beyond 1/2 (none when the walk ends normally).

    Each elementary step updates one row/column slice with numpy (O(n) work per call, no Python
    loop over the elements); recording the operations instead of updating ``Z`` makes each O(1)
    in ``z``, and ``Z`` is only materialised when asked for (:func:`decorrelate`).  Without ``z``
    and ``on_tail`` the compiled twin (:func:`_kernel`) runs the same steps (bit-identical).
    """
    if z is None and on_tail is None and _kernel() is not None:
        Lc, dc = _reduce_inputs(L, d)
        ops = _lambdacore.reduce(Lc, dc, PERM_RTOL)
        if ops is not None:          # None: an integer beyond 2**62 (the Python loop handles any size)
            return Lc, dc, ops
    L, d = _reduce_inputs(L, d)
    n = d.shape[0]
    ops = []
    k = n - 2
    lowest = n - 1
    while k >= 0:
        if on_tail is not None and k < lowest:
            lowest = k
            on_tail(k + 1, L, d, z, len(ops))
        _reduce_column(L, ops, z, k, k + 1)
        if _swap_if_shorter(L, d, ops, z, k):
            if k < n - 2:
                k += 1          # the swap changed the pair (k+1, k+2): test it again
        else:
            k -= 1
    _size_reduce(L, ops, z)
    return L, d, ops


def _reduce_inputs(L, d):
    """Working copies (float64, C order) of the factors ``L`` (n, n) and ``d`` (n,) of :func:`_reduce`."""
    L = np.array(L, dtype=float, order="C")
    d = np.array(d, dtype=float, order="C")
    n = d.shape[0]
    if d.ndim != 1 or L.shape != (n, n):
        raise AmbiguityError(
            f"L must have shape (n, n) matching d of shape (n,), got {L.shape} and {d.shape}"
        )
    return L, d


def _gauss(L, ops, z, i, j):
    """Integer Gauss transformation ``z_j <- z_j - mu z_i`` (``i > j``) making ``|L[i, j]| <= 1/2``.

    With ``G = I - mu e_i e_j^T``: ``L <- L G``, ``Z <- Z G``; in place on ``L`` (n, n), the
    operation list ``ops`` and the float ambiguities ``z`` (list, or None).  Nothing happens
    when ``mu`` rounds to 0.
    """
    mu = math.floor(L[i, j] + 0.5)
    if mu:
        L[i:, j] -= mu * L[i:, i]
        ops.append((i, j, mu))
        if z is not None:
            z[j] -= mu * z[i]


def _swap_if_shorter(L, d, ops, z, k):
    """Permute the adjacent pair ``(k, k+1)`` when that lowers ``d[k+1]`` by more than
    :data:`PERM_RTOL` (relative); update ``L``, ``d``, ``ops``, ``z`` in place.

    Returns
    -------
    bool
        Whether the pair was swapped.
    """
    lk = float(L[k + 1, k])
    dk = float(d[k])
    dk1 = float(d[k + 1])
    # conditional variance of the last of the pair after swapping
    delta = dk + lk * lk * dk1
    if not delta < dk1 * (1.0 - PERM_RTOL):
        return False
    eta = dk / delta
    lam = dk1 * lk / delta
    d[k] = eta * dk1
    d[k + 1] = delta
    if k:
        old_k = L[k, :k].copy()
        old_k1 = L[k + 1, :k].copy()
        L[k, :k] = old_k1 - lk * old_k
        L[k + 1, :k] = eta * old_k + lam * old_k1
    L[k + 1, k] = lam
    if k + 2 < d.shape[0]:
        L[k + 2:, [k, k + 1]] = L[k + 2:, [k + 1, k]]
    ops.append((k, k + 1, 0))
    if z is not None:
        z[k], z[k + 1] = z[k + 1], z[k]
    return True


def _size_reduce(L, ops, z):
    """Final size reduction of the strictly lower triangle of ``L`` below the sub-diagonal
    (only where ``|L[i, j]| > 1/2``); changes neither ``d`` nor the integer solution.  Column by
    column from the right, rows top down: a transformation at ``(i, j)`` changes only ``L[i:, j]``,
    so the next row of column ``j`` to transform is searched below ``i`` (numpy) in the column as
    it is then.  A transformation in column ``j`` changes no other column, so the columns with work
    to do are those with an entry beyond 1/2 to begin with."""
    n = L.shape[0]
    if n < 3:
        return
    todo = np.flatnonzero((np.abs(np.tril(L, -2)) > 0.5).any(axis=0))
    for j in todo[::-1].tolist():
        _reduce_column(L, ops, z, j, j + 2)


def _reduce_column(L, ops, z, j, start):
    """Size-reduce column ``j`` of ``L`` (n, n) from row ``start`` down: an integer Gauss
    transformation (:func:`_gauss`) at every row ``i >= start``, top down, where ``|L[i, j]| > 1/2``
    in the column as it is then (a transformation at ``(i, j)`` changes only ``L[i:, j]``)."""
    n = L.shape[0]
    i = start
    while i < n:
        big = np.flatnonzero(np.abs(L[i:, j]) > 0.5)
        if not big.size:
            break
        i += int(big[0])
        _gauss(L, ops, z, i, j)
        i += 1


def _forward(ops, v):
    """Apply the recorded transformation: ``v <- Z^T v`` (in place, list)."""
    for i, j, mu in ops:
        if mu:
            v[j] -= mu * v[i]
        else:
            v[i], v[j] = v[j], v[i]
    return v


def _backward(ops, v):
    """Apply the inverse transformation: ``v <- Z^{-T} v`` (in place, list)."""
    for i, j, mu in reversed(ops):
        if mu:
            v[j] += mu * v[i]
        else:
            v[i], v[j] = v[j], v[i]
    return v


def _z_matrix(ops, n):
    """Materialise ``Z`` (int64, shape (n, n)) from the recorded operations.

    Column operations on an int64 array, with every column's largest entry ``b`` kept along: when
    a transformed column could reach 2**62 (``|Z_j - mu Z_i| <= b_j + |mu| b_i``) the product is
    formed again in Python integers, which cannot overflow, and checked.  (A bound accumulated
    through the operations instead of the columns' actual maxima reached 2**62 on real 47x47
    reductions whose Z entries stay below 30, and sent them to the slow exact form.)  The compiled
    twin (:func:`_kernel`) runs the same steps."""
    Z = np.eye(n, dtype=np.int64)
    if _kernel() is not None:
        if not ops:
            return Z
        return Z if _lambdacore.z_matrix(ops, Z) else _z_matrix_exact(ops, n)
    bound = [1.0] * n
    for i, j, mu in ops:
        if mu:
            if bound[j] + abs(float(mu)) * bound[i] >= 2.0**62:
                return _z_matrix_exact(ops, n)
            Z[:, j] -= mu * Z[:, i]
            bound[j] = float(np.abs(Z[:, j]).max())
        else:
            Z[:, [i, j]] = Z[:, [j, i]]
            bound[i], bound[j] = bound[j], bound[i]
    return Z


def _z_matrix_exact(ops, n):
    """:func:`_z_matrix` in Python integers; AmbiguityError when an entry does not fit int64."""
    cols = [[int(r == c) for r in range(n)] for c in range(n)]
    for i, j, mu in ops:
        if mu:
            cols[j] = [x - mu * y for x, y in zip(cols[j], cols[i])]
        else:
            cols[i], cols[j] = cols[j], cols[i]
    big = max((abs(x) for col in cols for x in col), default=0)
    if big >= 2**62:
        raise AmbiguityError("decorrelation produced integer entries too large for int64")
    return np.array(cols, dtype=np.int64).T.copy()


def decorrelate(L, d):
    """Decorrelate ambiguities with integer Gauss transforms and permutations.

    Parameters
    ----------
    L : array_like, shape (n, n)
        Unit lower-triangular factor from :func:`ld_factorize`.
    d : array_like, shape (n,)
        Conditional variances from :func:`ld_factorize` (cycles^2).

    Returns
    -------
    L : ndarray, shape (n, n), float64
        Reduced unit lower-triangular factor (``|L[i, j]| <= 1/2`` below the
        diagonal).
    d : ndarray, shape (n,), float64
        Reduced conditional variances; adjacent entries satisfy
        ``d[k] + L[k+1, k]**2 * d[k+1] >= (1 - PERM_RTOL) * d[k+1]`` (no
        swap would reduce ``d[k+1]`` noticeably).
    Z : ndarray, shape (n, n), int64
        Unimodular (``|det Z| = 1``) integer transformation.  If the input
        factors satisfy ``Q = L^T diag(d) L`` then the transformed float
        ambiguities ``z = Z^T a`` have covariance
        ``Z^T Q Z = L_out^T diag(d_out) L_out``.

    Notes
    -----
    The inputs are not modified.  Integer solutions in the transformed space
    map back with ``a = Z^{-T} z`` (exactly, since ``Z^{-1}`` is integer).
    """
    Lr, dl, ops = _reduce(L, d)
    return Lr, dl, _z_matrix(ops, dl.shape[0])


# ---------------------------------------------------------------------------
# 3. search
# ---------------------------------------------------------------------------


def search(L, d, zs, candidates, *, max_nodes=None):
    """Shrinking-ellipsoid integer least-squares search (MLAMBDA style).

    Finds the ``candidates`` integer vectors ``z`` with the smallest
    ``(zs - z)^T (L^T diag(d) L)^{-1} (zs - z)``.

    Parameters
    ----------
    L : array_like, shape (n, n)
        Unit lower-triangular factor (normally the reduced one).
    d : array_like, shape (n,)
        Positive conditional variances (cycles^2).
    zs : array_like, shape (n,)
        Float ambiguities in the same space as ``L``/``d`` (cycles).
    candidates : int
        Number ``m >= 1`` of best integer vectors to return.
    max_nodes : int, optional
        Cap on the search loop (nodes of the enumeration tree visited); default
        :data:`SEARCH_MAX_NODES`.  Exceeding it raises :class:`SearchLimitError`.

    Returns
    -------
    zn : ndarray, shape (m, n), float64
        Integer-valued candidate vectors, best first.
    s : ndarray, shape (m,), float64
        Their squared norms, ascending.

    Raises
    ------
    SearchLimitError
        The enumeration visited more than ``max_nodes`` nodes (the float solution is too weak
        for these many ambiguities: partial fixing, a longer span or a float solution instead).

    Notes
    -----
    Depth-first enumeration from the last component (conditioned on
    nothing) to the first; at each level the integers are visited in
    zig-zag order around the conditional estimate so that partial distances
    are non-decreasing, which allows backtracking as soon as the partial
    distance exceeds the current radius.  The radius is infinite until
    ``m`` full candidates have been collected and then shrinks to the worst
    retained one.  The conditional-estimate update of a descent is one numpy
    slice operation for levels ``>= SEARCH_NUMPY_LEVEL`` (a Python list
    below, where numpy's per-call cost exceeds the work); the arithmetic is the same either way.
    """
    L, d, zs, m, cap = _search_inputs(L, d, zs, candidates, max_nodes)
    n = d.shape[0]
    if _kernel() is not None:
        out_z, out_s = np.empty((m, n)), np.empty(m)
        found, over = _lambdacore.enumerate(np.ascontiguousarray(L), np.ascontiguousarray(d),
                                            np.ascontiguousarray(zs), m, cap, out_z, out_s)
        if over:
            raise _limit_error(cap, n, found, m)
        out_z, out_s = out_z[:found], out_s[:found].tolist()
    else:
        out_z, out_s = _enumerate(L, d, zs, m, cap)
    order = sorted(range(len(out_s)), key=out_s.__getitem__)
    zn = np.array([out_z[i] for i in order], dtype=float).reshape(len(order), n)
    s = np.array([out_s[i] for i in order], dtype=float)
    return zn, s


def search_reduced(L, d, zs):
    """:func:`search` of the best two candidates (default node cap) on factors a caller has just
    reduced (:func:`ld_factorize` / :func:`decorrelate`: positive ``d``, consistent shapes), without
    re-checking them: the same ``zn`` (2, n) and ``s`` (2,); SearchLimitError alike."""
    n = d.shape[0]
    if _kernel() is None or n < 1:
        return search(L, d, zs, 2)
    out_z, out_s = np.empty((2, n)), np.empty(2)
    found, over = _lambdacore.enumerate(np.ascontiguousarray(L, dtype=float), np.ascontiguousarray(d, dtype=float),
                                        np.ascontiguousarray(zs, dtype=float), 2, SEARCH_MAX_NODES, out_z, out_s)
    if over:
        raise _limit_error(SEARCH_MAX_NODES, n, found, 2)
    if found == 2 and out_s[0] <= out_s[1]:                   # already in order (no NaN): what the sort gives
        return out_z, out_s
    order = np.argsort(out_s[:found], kind="stable")          # as search's sort of the norms (stable)
    return out_z[order], out_s[order]


def _search_inputs(L, d, zs, candidates, max_nodes):
    """Checked arrays ``L`` (n, n), ``d`` (n,), ``zs`` (n,), the candidate count and the node cap
    of :func:`search`."""
    L = np.asarray(L, dtype=float)
    d = np.asarray(d, dtype=float)
    zs = np.asarray(zs, dtype=float)
    n = d.shape[0]
    if d.ndim != 1 or n < 1 or L.shape != (n, n) or zs.shape != (n,):
        raise AmbiguityError(
            f"inconsistent shapes: L {L.shape}, d {d.shape}, zs {zs.shape} "
            "(need (n, n), (n,), (n,))"
        )
    if (
        isinstance(candidates, bool)
        or not isinstance(candidates, numbers.Integral)
        or candidates < 1
    ):
        raise AmbiguityError(f"candidates must be an integer >= 1, got {candidates!r}")
    if not np.all(d > 0):
        raise AmbiguityError("conditional variances d must all be > 0")
    return L, d, zs, int(candidates), _check_cap(max_nodes)


def _enumerate(L, d, zs, m, cap):
    """The depth-first enumeration of :func:`search` (see its Notes); returns the retained
    candidates (lists, length n) and their squared norms, unsorted.

    ``S[k][:k+1]`` accumulates ``sum_{i>k} L[i, :k+1] * (z_i - zb_i)``; the conditional estimate
    of component k is ``zb_k = zs_k + S[k][k]``.  Levels ``>= T`` keep ``S`` as numpy arrays,
    the others as lists.
    """
    n = d.shape[0]
    T = min(SEARCH_NUMPY_LEVEL, n)
    Ln = np.ascontiguousarray(L)
    Lr = Ln[:T + 1, :T].tolist()       # rows used by the list updates (levels < T)
    dl = d.tolist()
    zsl = zs.tolist()
    floor = math.floor
    S = [None] * n
    S[n - 1] = np.zeros(n) if n > T else [0.0] * n
    dist, zb, z, step = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
    out_z, out_s = [], []              # retained candidates (lists) and their squared norms
    maxdist, imax, nodes = math.inf, 0, 0
    k = n - 1
    zb[k] = zsl[k]
    z[k] = floor(zb[k] + 0.5)
    y = zb[k] - z[k]
    step[k] = 1.0 if y > 0 else -1.0
    while True:
        nodes += 1
        if nodes > cap:
            raise _limit_error(cap, n, len(out_z), m)
        newdist = dist[k] + y * y / dl[k]
        if newdist < maxdist:
            if k:
                # descend one level: condition component k-1 on z[k:]
                e = z[k] - zb[k]
                k -= 1
                dist[k] = newdist
                if k >= T:
                    Sk = S[k + 1][:k + 1] + e * Ln[k + 1, :k + 1]
                    sk = float(Sk[k])
                else:
                    src = S[k + 1]
                    if k + 1 >= T:
                        src = src[:k + 1].tolist()
                    Sk = [sv + e * lv for sv, lv in zip(src, Lr[k + 1])]
                    sk = Sk[k]
                S[k] = Sk
                zb[k] = zbk = zsl[k] + sk
                z[k] = zk = floor(zbk + 0.5)
                y = zbk - zk
                step[k] = 1.0 if y > 0 else -1.0
                continue
            # a full candidate has been reached; then the next integer at the bottom level
            maxdist, imax = _retain(out_z, out_s, z, newdist, m, imax)
            st = step[0]
            z[0] += st
            y = zb[0] - z[0]
            step[0] = -st - (1.0 if st > 0 else -1.0)
        else:
            if k == n - 1:
                break
            # move up one level and on to the next integer there
            k += 1
            st = step[k]
            z[k] += st
            y = zb[k] - z[k]
            step[k] = -st - (1.0 if st > 0 else -1.0)
    return out_z, out_s


def _retain(out_z, out_s, z, dist, m, imax):
    """Keep the full candidate ``z`` (squared norm ``dist``) among the best ``m``, replacing the
    worst (index ``imax``) once ``m`` are kept; return the new search radius (inf until ``m``
    candidates are kept) and the index of the worst kept."""
    if len(out_z) < m:
        out_z.append(z[:])
        out_s.append(dist)
        if len(out_z) < m:
            return math.inf, imax
    else:
        out_z[imax] = z[:]
        out_s[imax] = dist
    imax = max(range(m), key=out_s.__getitem__)
    return out_s[imax], imax


def _limit_error(cap, n, found, m):
    """The :class:`SearchLimitError` of a search stopped at ``cap`` nodes."""
    return SearchLimitError(
        f"LAMBDA search stopped after {cap} nodes for {n} ambiguities without completing "
        f"({found} of {m} candidates found): the float ambiguities are too weakly "
        f"determined to enumerate (try partial fixing, a longer span, or a float solution)"
    )


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------


def _validate(a, Q, candidates):
    """Validate and normalise inputs of :func:`lambda_search`."""
    errors = []
    try:
        aa = np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        aa = None
        errors.append("a must be convertible to a float array")
    try:
        Qa = np.asarray(Q, dtype=float)
    except (TypeError, ValueError):
        Qa = None
        errors.append("Q must be convertible to a float array")

    if aa is not None:
        if aa.ndim != 1:
            errors.append(f"a must be 1-D, got shape {aa.shape}")
        elif aa.shape[0] < 1:
            errors.append("a must contain at least one ambiguity (n >= 1)")
        if not np.all(np.isfinite(aa)):
            errors.append("a contains non-finite values (NaN or inf)")
        elif aa.size and float(np.max(np.abs(aa))) >= MAX_ABS_AMBIGUITY:
            errors.append(
                f"a has entries with magnitude >= 2**52 (max |a| = {np.max(np.abs(aa)):.6g})"
            )
    Q_shape_ok = False
    if Qa is not None:
        if Qa.ndim != 2 or Qa.shape[0] != Qa.shape[1]:
            errors.append(f"Q must be a square (n, n) matrix, got shape {Qa.shape}")
        else:
            Q_shape_ok = True
            if aa is not None and aa.ndim == 1 and Qa.shape[0] != aa.shape[0]:
                errors.append(
                    f"size mismatch: a has {aa.shape[0]} elements but Q is {Qa.shape}"
                )
        if not np.all(np.isfinite(Qa)):
            errors.append("Q contains non-finite values (NaN or inf)")
            Q_shape_ok = False
        elif Q_shape_ok and Qa.size:
            asym, tol = _asymmetry(Qa)
            if asym > tol:
                errors.append(
                    f"Q is not symmetric (max |Q - Q^T| = {asym:.3g} > tolerance {tol:.3g})"
                )
    if isinstance(candidates, bool) or not isinstance(candidates, numbers.Integral):
        errors.append(f"candidates must be an integer, got {candidates!r}")
    elif candidates < 1:
        errors.append(f"candidates must be >= 1, got {candidates}")

    if errors:
        raise AmbiguityError("invalid LAMBDA input: " + "; ".join(errors))
    return aa, 0.5 * (Qa + Qa.T), int(candidates)


def lambda_search(a, Q, candidates=2, *, max_nodes=None):
    """Integer least-squares ambiguity estimation with LAMBDA.

    Parameters
    ----------
    a : array_like, shape (n,)
        Float ambiguities (cycles), ``n >= 1``, finite, ``|a| < 2**52``.
        Large integer offsets are harmless: the search runs on
        ``a - round(a)`` and the offset is added back exactly.
    Q : array_like, shape (n, n)
        Covariance of ``a`` (cycles^2); finite, symmetric (relative
        tolerance ``SYMMETRY_RTOL``) and positive definite.
    candidates : int, optional
        Number ``m >= 1`` of best integer vectors to return (default 2, as
        needed by :func:`ratio_test`).
    max_nodes : int, optional
        Cap on the search loop (default :data:`SEARCH_MAX_NODES`).

    Returns
    -------
    cands : ndarray, shape (m, n), int64
        Integer ambiguity vectors in the original space, best first.
    squared_norms : ndarray, shape (m,), float64
        ``(a - cands[k])^T Q^{-1} (a - cands[k])``, ascending.

    Raises
    ------
    AmbiguityError
        On invalid input (all detected problems are listed in the message)
        or if ``Q`` is not positive definite; :class:`SearchLimitError` (a
        subclass) if the search exceeds ``max_nodes``.

    Examples
    --------
    >>> cands, s = lambda_search([0.1, -0.2], [[0.1, 0.0], [0.0, 0.1]])
    >>> cands[0].tolist(), round(float(s[0]), 6)
    ([0, 0], 0.5)
    """
    aa, Qs, m = _validate(a, Q, candidates)
    cap = _check_cap(max_nodes)
    offset = _round_half_up(aa)
    af = aa - offset  # exact for |a| < 2**52
    L, d = ld_factorize(Qs)
    Lr, dr, ops = _reduce(L, d)
    zs = _forward(ops, af.tolist())
    zn, s = search(Lr, dr, zs, m, max_nodes=cap)
    return _to_original(ops, zn, offset), s


def _to_original(ops, zn, offset):
    """Back-transform integer candidates ``a = Z^{-T} z + offset`` with exact (Python int)
    arithmetic; ``zn`` (m, n) float, ``offset`` (n,) → (m, n) int64."""
    base = np.asarray(offset).astype(np.int64).tolist()
    rows = []
    for zk in np.asarray(zn).tolist():
        ak = _backward(ops, [int(x) for x in zk])
        rows.append([x + b for x, b in zip(ak, base)])
    if any(abs(x) >= 2**62 for r in rows for x in r):
        raise AmbiguityError("integer candidates too large for int64: Q is numerically singular")
    return np.array(rows, dtype=np.int64).reshape(len(rows), len(base))


def ratio_test(squared_norms, threshold=RATIO_THRESHOLD):
    """Ratio test for accepting the best integer candidate.

    Parameters
    ----------
    squared_norms : array_like, shape (m,), m >= 2
        Squared norms of the candidates, ascending (from
        :func:`lambda_search`).
    threshold : float, optional
        Acceptance threshold on ``s[1] / s[0]`` (default :data:`cdgps_cli.config.options.RATIO_THRESHOLD`, 3).

    Returns
    -------
    accepted : bool
        ``ratio >= threshold``.
    ratio : float
        ``s[1] / s[0]``; ``inf`` when ``s[0] == 0 < s[1]`` and ``1.0`` when
        both are zero (two equally good candidates).

    Raises
    ------
    AmbiguityError
        If fewer than two norms are given, they are negative/non-finite, or
        not in ascending order in their first two entries, or the threshold
        is not a finite number.
    """
    s = np.asarray(squared_norms, dtype=float).ravel()
    if s.shape[0] < 2:
        raise AmbiguityError("ratio_test needs at least two squared norms")
    s0, s1 = float(s[0]), float(s[1])          # (the checks on Python floats: a per-epoch call)
    if not (math.isfinite(s0) and math.isfinite(s1)) or s0 < 0 or s1 < 0:
        raise AmbiguityError(f"squared norms must be finite and >= 0, got {s[:2]}")
    if s1 < s0:
        raise AmbiguityError(f"squared norms must be ascending, got {s[:2]}")
    thr = float(threshold)
    if not math.isfinite(thr):
        raise AmbiguityError(f"threshold must be finite, got {threshold!r}")
    if s0 > 0:
        ratio = s1 / s0
    else:
        ratio = math.inf if s1 > 0 else 1.0
    return bool(ratio >= thr), ratio


def bootstrap_success_rate(d) -> float:
    """Success rate of integer bootstrapping, the sharp lower bound of the integer least-squares
    success rate (Teunissen 1998, "Success probability of integer GPS ambiguity rounding and
    bootstrapping", J. Geodesy 72; used by LAMBDA's partial ambiguity resolution).

    Parameters
    ----------
    d : array_like, shape (n,)
        Conditional variances of the (decorrelated) ambiguities, cycles² (:func:`ld_factorize`,
        :func:`decorrelate`).

    Returns
    -------
    float
        ``Π_i (2 Φ(1 / (2 σ_i)) − 1) = Π_i erf(1 / (2 √(2 d_i)))``; 1 for an empty set.
    """
    dd = np.asarray(d, dtype=float).ravel()
    if np.any(~np.isfinite(dd)) or np.any(dd <= 0):
        raise AmbiguityError(f"conditional variances must be finite and > 0, got {dd}")
    return float(np.prod([math.erf(1.0 / (2.0 * math.sqrt(2.0 * x))) for x in dd]))


def success_tail(d, min_success_rate: float) -> int:
    """First index ``k`` of the longest tail ``d[k:]`` whose bootstrapped success rate is at least
    ``min_success_rate`` (``len(d)``: not even the last ambiguity qualifies).

    With :func:`ld_factorize`'s convention (``d[i]`` conditioned on ``i+1 … n−1``) the tail is a
    set that bootstrapping fixes first, and its success rate is the product over the tail alone:
    the subset for partial ambiguity resolution with a success-rate criterion.
    """
    dd = np.asarray(d, dtype=float).ravel()
    p = 1.0
    k = dd.size
    for i in range(dd.size - 1, -1, -1):
        p *= math.erf(1.0 / (2.0 * math.sqrt(2.0 * dd[i])))
        if p < min_success_rate:
            break
        k = i
    return k


def success_tail_rate(d, min_success_rate: float) -> tuple[int, float]:
    """:func:`success_tail`'s ``k`` and the bootstrapped success rate of the tail ``d[k:]`` (its
    running product, taken in the same pass; 0.0 when no tail qualifies).  The rate equals
    :func:`bootstrap_success_rate` of ``d[k:]`` up to the order of the product's rounding."""
    dd = np.asarray(d, dtype=float).ravel().tolist()
    p = p_tail = 1.0
    k = len(dd)
    for i in range(k - 1, -1, -1):
        p *= math.erf(1.0 / (2.0 * math.sqrt(2.0 * dd[i])))
        if p < min_success_rate:
            break
        k, p_tail = i, p
    return k, (p_tail if k < len(dd) else 0.0)


def partial_fix(a, Q, threshold=RATIO_THRESHOLD, min_fixed=1, *, max_nodes=None, progress=None,
                min_success_rate=None):
    """Partial ambiguity resolution: the largest subset, in order of decreasing variance, that
    passes the ratio test — from one decomposition and one reduction.

    The full set is resolved first (:func:`lambda_search` and :func:`ratio_test`).  If it fails,
    ambiguities are dropped by decreasing *marginal variance in the original space* (largest
    ``Q[i, i]`` first; ties: the lowest index first) and the largest remaining subset that passes
    is fixed, with its marginal covariance ``Q[np.ix_(sub, sub)]``.  Working in the original
    space keeps the result a mask over the input ambiguities.

    One factorization and one reduction serve all the nested subsets (:class:`_NestedSearch`);
    the answer is the one the drop-one-and-redo loop gives.

    Parameters
    ----------
    a : array_like, shape (n,)
        Float ambiguities (cycles).
    Q : array_like, shape (n, n)
        Their covariance (cycles^2), symmetric positive definite.
    threshold : float, optional
        Ratio-test threshold (default :data:`cdgps_cli.config.options.RATIO_THRESHOLD`, 3).
    min_fixed : int, optional
        Smallest subset size that may be fixed, ``1 <= min_fixed <= n``.
    max_nodes : int, optional
        Node cap of each search (default :data:`SEARCH_MAX_NODES`).  A subset whose search
        exceeds it counts as failed; larger subsets (which contain it) are then not searched.
    progress : callable, optional
        ``progress(done, total)`` after each subset searched (``total = n - min_fixed + 1``: the
        full set, then the nested subsets of sizes ``min_fixed … n-1``; fewer when one passes or
        a search hits the cap).
    min_success_rate : float, optional
        A set (or subset) passes only if, besides the ratio test, its bootstrapped success rate
        (:func:`bootstrap_success_rate` of its decorrelated conditional variances) reaches this
        value — partial ambiguity resolution with a success-rate criterion.  None: ratio test only.

    Returns
    -------
    dict
        ``fixed_mask`` : ndarray of bool, shape (n,)
            True for fixed ambiguities (all False if nothing passed).
        ``integers`` : ndarray of int64, shape (n,)
            Fixed integer values where ``fixed_mask``; 0 elsewhere (not
            meaningful there).
        ``ratio`` : float
            Ratio of the accepted subset; if no subset passed, the ratio of
            the full set (NaN if its search exceeded the cap).
        ``ratio_full_set`` : float
            Ratio of the full set (NaN if its search exceeded the cap).
        ``n_fixed`` : int
            Number of fixed ambiguities.
        ``subsets_searched`` : int
            Searches run (the full set included).
        ``search_limited`` : int
            Searches stopped by the node cap.
        ``success_rate`` : float
            Bootstrapped success rate of the fixed set (of the full set when nothing was fixed).

    Raises
    ------
    AmbiguityError
        On invalid input (see :func:`lambda_search`) or invalid
        ``min_fixed`` / ``min_success_rate``.
    """
    aa, Qs, _ = _validate(a, Q, 2)
    n = aa.shape[0]
    if isinstance(min_fixed, bool) or not isinstance(min_fixed, numbers.Integral):
        raise AmbiguityError(f"min_fixed must be an integer, got {min_fixed!r}")
    if not 1 <= min_fixed <= n:
        raise AmbiguityError(f"min_fixed must be between 1 and n={n}, got {min_fixed}")
    cap = _check_cap(max_nodes)
    if min_success_rate is not None and not (isinstance(min_success_rate, numbers.Real)
                                             and 0.0 <= float(min_success_rate) < 1.0):
        raise AmbiguityError(f"min_success_rate must be a probability in [0, 1), got {min_success_rate!r}")
    nested = _NestedSearch(n, min_fixed, float(threshold), cap, progress, min_success_rate)
    var = np.diag(Qs)
    perm = np.array(sorted(range(n), key=lambda i: (-var[i], i)), dtype=np.int64)
    ap = aa[perm]
    offset = _round_half_up(ap)
    L, d = ld_factorize(Qs[np.ix_(perm, perm)])
    # 1. the full set
    Lr, dr, ops = _reduce(L, d)
    full_ratio = nested(0, Lr, dr, _forward(ops, (ap - offset).tolist()), len(ops))
    # 2. the nested subsets, all from one more pass of the reduction
    if nested.best is None and n > 1:
        nested.stop = False
        _, _, ops = _reduce(L, d, z=(ap - offset).tolist(), on_tail=nested)
    return _partial_result(nested, ops, perm, offset, full_ratio)


class _NestedSearch:
    """The ``on_tail`` callback of :func:`_reduce` that searches the nested subsets of
    :func:`partial_fix`.

    The subsets are not resolved one full LAMBDA each (O(n) decompositions and reductions, O(n^4)
    in all, which is what kept a 150-segment init from finishing): with the ambiguities ordered
    so that those dropped first come first, each subset is a *trailing* block, whose
    ``L^T D L`` factor is the trailing block of the full one, and the reduction, which works
    from the end, completes every trailing block on its way (see ``on_tail`` of
    :func:`_reduce`).  So one factorization and one reduction serve all ``n`` subsets; each
    subset only costs its search, run while the reduction passes it.  The answer is the one
    the drop-one-and-redo loop gives (the largest passing subset of the same nested sequence).

    Attributes
    ----------
    best : tuple or None
        ``(k, z, n_ops, ratio)`` of the largest trailing block ``[k, n)`` that passed so far.
    done, limited : int
        Searches run, and those stopped by the node cap.
    stop : bool
        A block hit the cap: the larger ones (which contain it) are not searched.
    """

    def __init__(self, n, min_fixed, threshold, cap, progress, min_success_rate=None):
        self.n, self.min_fixed, self.threshold, self.cap = n, min_fixed, threshold, cap
        self.progress, self.min_success_rate = progress, min_success_rate
        self.full_success_rate = math.nan
        self.total = n - min_fixed + 1      # the full set, then the subsets of sizes min_fixed … n-1
        self.done, self.limited, self.best, self.stop = 0, 0, None, False

    def __call__(self, k, Lw, dw, zw, n_ops):
        """Search the trailing block [k, n); remember it if it passes (larger blocks come later).
        Returns its ratio (NaN when the search hit the cap; None when not searched)."""
        if self.n - k < self.min_fixed or self.stop:
            return None
        self.done += 1
        try:
            zn, s = search(Lw[k:, k:], dw[k:], zw[k:], 2, max_nodes=self.cap)
        except SearchLimitError:
            self.limited += 1
            self.stop = k > 0
            ratio = math.nan
        else:
            ok, ratio = ratio_test(s, self.threshold)
            p_s = bootstrap_success_rate(dw[k:])
            if k == 0:
                self.full_success_rate = p_s
            if ok and (self.min_success_rate is None or p_s >= self.min_success_rate):
                self.best = (k, zn[0].tolist(), n_ops, ratio, p_s)
        if self.progress is not None:
            self.progress(self.done, self.total)
        return ratio


def _partial_result(nested, ops, perm, offset, full_ratio):
    """The result dict of :func:`partial_fix` from the nested search (``ops``: the reduction's
    operations, ``perm`` (n,): the drop order, ``offset`` (n,): the rounding taken off ``a``)."""
    n = perm.shape[0]
    fixed_mask = np.zeros(n, dtype=bool)
    integers = np.zeros(n, dtype=np.int64)
    result = {"fixed_mask": fixed_mask, "integers": integers, "ratio": float(full_ratio),
              "ratio_full_set": float(full_ratio), "n_fixed": 0,
              "subsets_searched": nested.done, "search_limited": nested.limited,
              "success_rate": float(nested.full_success_rate)}
    if nested.best is None:
        return result
    k, zbest, n_ops, ratio, p_s = nested.best
    result["success_rate"] = float(p_s)
    # the operations recorded up to this block's completion involve indices >= k only
    a_tail = _to_original(ops[:n_ops], [[0.0] * k + zbest], offset)[0]
    fixed_mask[perm[k:]] = True
    integers[perm[k:]] = a_tail[k:]
    result.update(ratio=float(ratio), n_fixed=int(n - k))
    return result


def _success_rate(Q) -> float:
    """Bootstrapped success rate of a whole set after decorrelation (:func:`decorrelate`)."""
    L, d = ld_factorize(np.asarray(Q, dtype=float))
    _, dz, _ = decorrelate(L, d)
    return bootstrap_success_rate(dz)


def resolve(a, Q, threshold=RATIO_THRESHOLD, *, partial=True, max_nodes=None, progress=None, min_success_rate=None):
    """The integer fixing of the solvers: the full set, then (``partial``) nested subsets.

    :func:`partial_fix` when ``partial`` (its first step is the full set), else
    :func:`lambda_search` + :func:`ratio_test`; a search over the node cap makes the set (or
    subset) count as not fixable instead of raising.

    Parameters
    ----------
    a, Q, threshold, max_nodes, progress, min_success_rate
        As for :func:`partial_fix`.
    partial : bool
        Try subsets when the full set fails.

    Returns
    -------
    dict
        The keys of :func:`partial_fix`, plus ``accepted`` (bool: something was fixed),
        ``partial`` (bool: a proper subset was fixed) and ``limit_message`` (str or None: the
        :class:`SearchLimitError` text when the full set's search hit the cap).
    """
    n = np.asarray(a).shape[0] if np.ndim(a) == 1 else 0
    if partial and n > 1:
        res = partial_fix(a, Q, threshold, max_nodes=max_nodes, progress=progress, min_success_rate=min_success_rate)
        limit = None
        if math.isnan(res["ratio_full_set"]):
            limit = (f"the LAMBDA search of the full set of {n} ambiguities exceeded "
                     f"{_check_cap(max_nodes)} nodes")
    else:
        mask = np.zeros(n, dtype=bool)
        ints = np.zeros(n, dtype=np.int64)
        res = {"fixed_mask": mask, "integers": ints, "n_fixed": 0, "subsets_searched": 1, "search_limited": 0}
        limit = None
        if n == 0:       # nothing to fix (every ambiguity float: GLONASS alone, not glonass_fix): an empty set
            res.update(ratio=math.nan, ratio_full_set=math.nan, success_rate=1.0, subsets_searched=0)
        else:
            limit = _search_full_set(a, Q, threshold, max_nodes, min_success_rate, res)
        if progress is not None:
            progress(1, 1)
    res["accepted"] = res["n_fixed"] > 0
    res["partial"] = 0 < res["n_fixed"] < n
    res["limit_message"] = limit
    return res


def _search_full_set(a, Q, threshold, max_nodes, min_success_rate, res: dict):
    """:func:`resolve`'s full-set LAMBDA search and ratio test, into ``res`` (its mask and integers filled when
    accepted); the search-limit message, or None."""
    try:
        cands, s = lambda_search(a, Q, 2, max_nodes=max_nodes)
    except SearchLimitError as exc:
        res.update(ratio=math.nan, ratio_full_set=math.nan, search_limited=1)
        return str(exc)
    ok, ratio = ratio_test(s, threshold)
    res.update(ratio=float(ratio), ratio_full_set=float(ratio), success_rate=_success_rate(Q))
    if ok and (min_success_rate is None or res["success_rate"] >= min_success_rate):
        res["fixed_mask"][:] = True
        res["integers"][:] = cands[0]
        res["n_fixed"] = res["fixed_mask"].size
    return None


def conditioned_on_integers(a, Q, fixed_mask, integers):
    """The float ambiguities not in ``fixed_mask`` given the fixed ones equal ``integers`` (cycles).

    ``â_r|f = â_r − Q_rf Q_ff⁻¹ (â_f − z_f)`` and ``Q_r|f = Q_rr − Q_rf Q_ff⁻¹ Q_fr`` (the Gaussian
    conditional; Teunissen 1995's conditional float of the remaining ambiguities).  Returns ``(a_r, Q_r)``,
    shapes (r,) and (r, r), ``Q_r`` exactly symmetric.
    """
    m = np.asarray(fixed_mask, dtype=bool)
    f, r = np.flatnonzero(m), np.flatnonzero(~m)
    K = np.linalg.solve(Q[np.ix_(f, f)], Q[np.ix_(f, r)]).T          # Q_rf Q_ff⁻¹
    a_r = a[r] - K @ (a[f] - np.asarray(integers)[f])
    Q_r = Q[np.ix_(r, r)] - K @ Q[np.ix_(f, r)]
    return a_r, 0.5 * (Q_r + Q_r.T)


def resolve_cascaded(a, Q, threshold=RATIO_THRESHOLD, *, max_nodes=None, progress=None, min_success_rate=None,
                     max_stages: int = 10):
    """Partial fixing repeated on what is left, conditioned on what is fixed (cascaded partial resolution).

    :func:`resolve` (partial) fixes the largest subset that passes; the remaining ambiguities are then
    conditioned on those integers, ``â_r|f = â_r − Q_rf Q_ff⁻¹ (â_f − z_f)``, ``Q_r|f = Q_rr − Q_rf Q_ff⁻¹ Q_fr``
    (the float solution with the fixed ones known exactly), and resolved again under the same ratio test and
    success-rate criterion, until a stage fixes nothing or nothing is left.  A static baseline's float with
    many short lock arcs (a u-blox receiver's slips and half-cycle flags) passes with a subset of its long arcs
    only; once those are fixed the position is known to millimetres and the short arcs' conditional floats are
    close to integers.  Each stage trusts the integers of the stages before it: a wrong fix propagates, as in
    any bootstrapped fixing, so every stage keeps the ratio test and success-rate criterion of the first.

    Parameters
    ----------
    a, Q, threshold, max_nodes, progress, min_success_rate
        As for :func:`resolve` (``progress`` serves the first stage only).
    max_stages : int
        Most stages (the first included).

    Returns
    -------
    dict
        :func:`resolve`'s keys for the first stage (``ratio``, ``ratio_full_set``, ``success_rate``, …) with
        ``fixed_mask``, ``integers``, ``n_fixed``, ``accepted`` and ``partial`` over all stages, and ``stages``:
        one ``{"candidates", "fixed", "ratio"}`` per stage (ambiguities offered, fixed, the stage's ratio).
    """
    a = np.asarray(a, dtype=np.float64)
    Q = np.asarray(Q, dtype=np.float64)
    res = resolve(a, Q, threshold, partial=True, max_nodes=max_nodes, progress=progress,
                  min_success_rate=min_success_rate)
    mask, ints = res["fixed_mask"].copy(), res["integers"].copy()
    stages = [{"candidates": int(a.size), "fixed": int(mask.sum()), "ratio": float(res["ratio"])}]
    while len(stages) < max_stages and mask.any() and not mask.all():
        r = np.flatnonzero(~mask)
        a_r, Q_r = conditioned_on_integers(a, Q, mask, ints)
        more = resolve(a_r, Q_r, threshold, partial=True, max_nodes=max_nodes, min_success_rate=min_success_rate)
        stages.append({"candidates": int(r.size), "fixed": int(more["n_fixed"]), "ratio": float(more["ratio"])})
        if not more["n_fixed"]:
            break
        mask[r[more["fixed_mask"]]] = True
        ints[r[more["fixed_mask"]]] = more["integers"][more["fixed_mask"]]
    n = int(mask.sum())
    return {**res, "fixed_mask": mask, "integers": np.where(mask, ints, 0), "n_fixed": n, "accepted": n > 0,
            "partial": 0 < n < a.size, "stages": stages}
