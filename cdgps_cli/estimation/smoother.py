"""The one Rauch–Tung–Striebel smoother of the engine (architecture.md "Smoother").

One backward pass, :func:`_rts_pass` (compiled in :mod:`cdgps_cli.estimation.kernel` when available,
numpy otherwise, same arithmetic), over filtered states x_k (N, n) and covariances P_k (N, n, n):

    x̄_{k+1} = A x_k + B u_k,   P̄_{k+1} = A P_k Aᵀ + Q,   G_k = P_k Aᵀ P̄_{k+1}⁻¹
    x^s_k = x_k + G_k (x^s_{k+1} − x̄_{k+1}),   P^s_k = P_k + G_k (P^s_{k+1} − P̄_{k+1}) G_kᵀ

Two entry points: :func:`rts_smooth` — one transition A (and input B) with a piecewise-constant Q,
recorded extra variances and unlinked epochs (the pseudolite filter, :mod:`cdgps_cli.estimation.filter`);
:func:`rts_smooth_transitions` — a transition (A_k, Q_k) into every epoch as recorded by the
forward filter over the interfaces (:func:`cdgps_cli.estimation.model_filter.filter_numpy`: GNSS
displacement and modal paths), run as one pass per stretch of equal transitions;
:func:`rts_smooth_indexed` — the same with each distinct transition stored once and its number per
epoch, in place and in blocks (the forward results may be on disk, :mod:`cdgps_cli.estimation.history`).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from cdgps_cli.estimation import kernel as ekf_kernel

__all__ = ["rts_smooth", "rts_smooth_transitions", "rts_smooth_indexed"]


def rts_smooth(A, Q, B, U_in, xf, Pf, extra_q=None, no_link=None, in_place=False, q_segments=None,
               chunk=None, on_done=None):
    """Rauch–Tung–Striebel smoother over filtered states (N, p) and covariances (N, p, p).

    The priors are recomputed from the filtered values (x̄ = A x + B u, P̄ = A P Aᵀ + Q_k) so that
    only the filtered arrays are stored; ``extra_q`` {epoch: [(index, variance)]} adds the
    variance inflations the filter applied at that epoch; ``no_link[k]`` leaves epoch k as it is
    (re-initialization boundaries and batch-filled epochs).  ``q_segments`` [(k_lo, k_hi, Q_seg)]
    replaces Q by Q_seg for the transitions k → k+1 with k_lo ≤ k < k_hi (a process noise that changes
    over the record, e.g. rest segments); by default Q throughout.  Returns smoothed states and
    covariances; with ``in_place`` they overwrite ``xf`` and ``Pf`` (epoch k is read before it is
    replaced, and epoch k+1 is already smoothed when k is processed, so this is exact and saves two
    copies).

    ``chunk`` (epochs): run each stretch as passes over at most ``chunk + 1`` epochs, latest first
    (each pass ends on an epoch the later pass has smoothed: the same numbers as one pass), and call
    ``on_done(start, stop)`` after each with the epochs start … stop−1 that are final (descending; the
    arrays may be on disk, :mod:`cdgps_cli.estimation.history`, and the caller copies out and drops them).
    """
    extra_q = extra_q or {}
    xs = xf if in_place else xf.copy()
    Ps = Pf if in_place else Pf.copy()
    N = xs.shape[0]
    if chunk is None and on_done is None and not (q_segments and not (len(q_segments) == 1 and q_segments[0][2] is Q)):
        _rts_pass(A, Q, B, U_in, xs, Ps, extra_q, no_link)
        return xs, Ps
    # piecewise-constant Q: one pass per stretch, latest first; each stretch ends on an epoch the
    # later pass has already smoothed, which is exactly what the recursion reads as "k+1"
    segs = q_segments if q_segments else ([(0, N - 1, Q)] if N > 1 else [])
    step = N if chunk is None else max(int(chunk), 1)
    for k_lo, k_hi, Qs in sorted(segs, reverse=True, key=lambda t: t[0]):
        if k_hi <= k_lo:
            continue
        for b in range(k_hi, k_lo, -step):
            a = max(b - step, k_lo)
            sub_q = {k - a: v for k, v in extra_q.items() if a < k <= b}
            sub_nl = None if no_link is None else np.asarray(no_link)[a:b + 1]
            _rts_pass(A, Qs, B, U_in[a:b + 1], xs[a:b + 1], Ps[a:b + 1], sub_q, sub_nl)
            if on_done is not None:
                on_done(a, b + 1)
    if on_done is not None and N == 1:
        on_done(0, 1)
    return xs, Ps


def _rts_pass(A, Q, B, U_in, xs, Ps, extra_q, no_link) -> None:
    """One RTS pass with a constant Q, in place on (xs, Ps) = filtered values (N, p), (N, p, p)."""
    N = xs.shape[0]
    xf, Pf = xs, Ps
    if (ekf_kernel.available() and xs.dtype == np.float64 and Ps.dtype == np.float64
            and xs.flags.c_contiguous and Ps.flags.c_contiguous and xs.flags.writeable and Ps.flags.writeable):
        # compiled pass on xs, Ps (= xf, Pf or their copies): epoch k is read before it is replaced
        ekf_kernel.rts(A, Q, B, U_in, xs, Ps, xs, Ps, extra_q, no_link)
        return
    for k in range(N - 2, -1, -1):
        if no_link is not None and no_link[k]:
            continue                      # a re-initialization boundary or batch-filled epoch
        xp = A @ xf[k] + B @ U_in[k]
        Pp = A @ Pf[k] @ A.T + Q
        for i, q in extra_q.get(k + 1, ()):
            Pp[i, i] += q
        c = cho_factor(Pp, check_finite=False)
        G = cho_solve(c, A @ Pf[k], check_finite=False).T      # P_k Aᵀ P̄⁻¹
        xs[k] = xf[k] + G @ (xs[k + 1] - xp)
        Pk = Pf[k] + G @ (Ps[k + 1] - Pp) @ G.T
        Ps[k] = 0.5 * (Pk + Pk.T)


def rts_smooth_transitions(xf, Pf, As, Qs):
    """RTS pass over filtered (xf, Pf) (N, n), (N, n, n) with the transition (As[k], Qs[k]) into
    epoch k (As[0], Qs[0] unused); returns smoothed (xs, Ps), new arrays.

    Consecutive transitions that are equal (the same epoch spacing) form one stretch, smoothed by
    one :func:`_rts_pass` (compiled when available), the latest stretch first: each stretch ends on
    an epoch the later pass has already smoothed.
    """
    xs = np.array(xf, dtype=np.float64, order="C")
    Ps = np.array(Pf, dtype=np.float64, order="C")
    As, Qs = np.asarray(As, dtype=np.float64), np.asarray(Qs, dtype=np.float64)
    N, n = xs.shape
    if N < 2:
        return xs, Ps
    same = np.all(As[2:] == As[1:-1], axis=(1, 2)) & np.all(Qs[2:] == Qs[1:-1], axis=(1, 2))
    starts = np.r_[0, 1 + np.flatnonzero(~same)]               # transition k → k+1 uses As[k+1], Qs[k+1]
    ends = np.r_[starts[1:], N - 1]
    B, U = np.zeros((n, 0)), np.zeros((N, 0))
    for k_lo, k_hi in zip(starts[::-1], ends[::-1]):
        _rts_pass(As[k_lo + 1], Qs[k_lo + 1], B, U[k_lo:k_hi + 1], xs[k_lo:k_hi + 1], Ps[k_lo:k_hi + 1], {}, None)
    return xs, Ps


def rts_smooth_indexed(xs, Ps, pairs, pair_of, chunk=None, on_done=None):
    """RTS pass in place over filtered (xs, Ps) (N, n), (N, n, n), C-contiguous float64 (in memory or
    on disk), with the transition into epoch k given as ``pairs[pair_of[k]]`` = (A, Q) (``pair_of[0]``
    unused): the numbers of :func:`rts_smooth_transitions` on the expanded arrays.

    Consecutive epochs with the same pair form a stretch, smoothed latest first; each stretch runs as
    passes over at most ``chunk + 1`` epochs, latest first (each ends on an epoch the later pass has
    smoothed: the same numbers as one pass), and ``on_done(start, stop)`` is called after each with
    the epochs start … stop−1 that are final (descending), so that the caller can copy them out and
    release them.  Returns (xs, Ps).
    """
    N, n = xs.shape
    pair_of = np.asarray(pair_of)
    if N < 2:
        if on_done is not None and N == 1:
            on_done(0, 1)
        return xs, Ps
    change = np.flatnonzero(pair_of[2:] != pair_of[1:-1])
    starts = np.r_[0, 1 + change]                              # transition k → k+1 uses pair_of[k+1]
    ends = np.r_[starts[1:], N - 1]
    step = N if chunk is None else max(int(chunk), 1)
    B, U = np.zeros((n, 0)), np.zeros((N, 0))
    for k_lo, k_hi in zip(starts[::-1], ends[::-1]):
        A, Q = pairs[pair_of[k_lo + 1]]
        for b in range(k_hi, k_lo, -step):
            a = max(b - step, k_lo)
            _rts_pass(A, Q, B, U[a:b + 1], xs[a:b + 1], Ps[a:b + 1], {}, None)
            if on_done is not None:
                on_done(a, b + 1)
    return xs, Ps
