"""States and covariances over INIT's batch window, for STATES.mcap (``cdgps estimate``).

``cdgps init`` solves the batch problem of Teague, How & Parkinson (1998) Eq. 9–15 over a window
and writes only the state at the window end (where the filter starts) and the biases, so that
INIT.json stays small whatever the window length.  :func:`window_states` recomputes, from the RUN
and INIT, the batch solution at every epoch of the window with its covariance: the same cost
(no prior on the first state, the batch's process noise, INIT's σ), the fixed integers' biases
known, the biases INIT left float estimated again as constant unknowns with no prior.  That is an
iterated extended Kalman smoother (Gauss–Newton on the batch cost), O(N) per iteration:

* forward, an information filter from zero information (the batch's diffuse start; no inverse of a
  singular matrix is ever needed): for z_k = [x_k; b_free],
  prior  Ȳ = M − M G (I + GᵀMG)⁻¹ GᵀM,  M = A⁻ᵀ Y A⁻¹  (ȳ likewise),
  update Y = Ȳ + H̃ᵀH̃/σ²,  y = ȳ + H̃ᵀỹ/σ²  with ỹ = Δφ − b_fixed − h(x̂) + H x̂ (linearized about x̂);
* backward, the Rauch–Tung–Striebel recursion written with the prior information only
  (G_k = P_k Aᵀ P̄⁻¹ = A⁻¹(I − QȲ_{k+1}), since A P_k Aᵀ = P̄_{k+1} − Q):
  x_k|N = A⁻¹(x_{k+1}|N − Q(Ȳ_{k+1} x_{k+1}|N − ȳ_{k+1})),
  P_k|N = A⁻¹[(I − QȲ)P_{k+1}|N(I − ȲQ) + Q − QȲQ]A⁻ᵀ,
  valid also where the filtered covariance does not exist yet (first epochs: no velocity information).

Why this pass is in information form and not the engine's forward filter + RTS smoother
(:class:`cdgps_cli.estimation.kalman.StepFilter`, :mod:`cdgps_cli.estimation.smoother`): the batch has
no prior on the first state nor on the float biases (a diffuse start), which the covariance form
cannot represent, and its RTS smoother needs a filtered covariance at every epoch, which does not
exist before the velocities and biases are observed.  With a broad prior P₀ = s² I instead, the
engine misses the batch by ≈ 7·10⁻³/s² (relative: the prior's weight) until cancellation
(cond ~ s²/σ²) takes over: on the linear case of tests/estimation/test_window_smoother.py its best,
s = 10³, is 7e-9 off in x and 5e-8 in P, and s = 10⁸ fails its Cholesky, where this pass is within
2e-13 and 1.5e-15 (benchmarks/window_information_form.py, docs/benchmarks/window-information-form.json).

The first linearization is a backward EKF from INIT's state at the window end (the engine's step,
:class:`cdgps_cli.estimation.kalman.StepFilter`, on the pseudolite SD model; with the compiled kernel
its filter span, the same step to rounding).  With the kernel the forward and backward loops run in
C too (``_ekfcore.window_forward`` / ``window_backward``; their numpy twins :func:`_forward_numpy`
and the loop of :func:`_backward` stay the reference, equal to ~1e-15 relative).  The iteration stops
when the largest step of a modal position (h depends on nothing else) is below 1e-3 of its σ, so
the solution is within ~1e-6 σ of the batch's (quadratic convergence from a trajectory that is
already at the filter's accuracy: 2–3 iterations; exact after 2 on a linear model).  Like the batch, the window
ignores thruster commands (the batch's dynamics have none).

:func:`extend_smoothing` carries a later smoothing pass (RTS over the filter after the window) into
the window: x_k|all = x_k|N + G_k (x_{k+1}|all − x_{k+1}|N), P_k|all = P_k|N + G_k (P_{k+1}|all −
P_{k+1}|N) G_kᵀ — the exact RTS recursion over the whole record, since the window's forward pass is
the filter up to the window end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.kalman import StepFilter
from cdgps_cli.measurement.model import PseudoliteSD
from cdgps_cli.measurement.phase import phase_model
from cdgps_cli.measurement import multipath
from cdgps_cli.core.records import Run
from cdgps_cli.measurement.noise import init_channel_sigma_m

_CHUNK = 1024                       # epochs per vectorized call of the measurement model
MAX_ITERATIONS = 10
STEP_SIGMA = 1e-3            # converged: largest modal-position step / its σ


@dataclass
class WindowStates:
    """The batch solution at every epoch of INIT's window (see the module docstring).

    Shapes: N window epochs, n structure states, p = n + free biases, C window channels.
    """

    time_s: np.ndarray          # (N,)
    x: np.ndarray               # (N, n) smoothed state (batch solution)
    P: np.ndarray               # (N, n, n) its covariance (marginal over the free biases)
    z: np.ndarray               # (N, p) smoothed augmented state [x; b_free]
    Pz: np.ndarray              # (N, p, p)
    Ybar: np.ndarray            # (N, p, p) prior information Ȳ_k of the forward pass (k ≥ 1)
    A: np.ndarray               # (p, p) augmented transition
    Q: np.ndarray               # (p, p) augmented process noise (batch's)
    channels: list              # [(antenna, transmitter)] of the window
    residual_m: np.ndarray      # (N, C) post-fit residual Δφ − h(x) − b (NaN where absent)
    iterations: int
    n_free_biases: int
    segments_without_bias: list     # window lock segments INIT has no bias for (their data left out)


def batch_window(init: dict, t0: float, source: str = "INIT.json") -> tuple[float, float] | None:
    """(start_s, end_s) of INIT's batch window when INIT's state is the batch solution at its end
    (INIT.json from ``cdgps init``), else None (a hand-made INIT: its state is a prior at t0).
    ``source`` names the INIT file in the messages."""
    w = init.get("window")
    if not isinstance(w, dict):
        return None
    try:
        a, b = float(w["start_s"]), float(w["end_s"])
    except (KeyError, TypeError, ValueError):
        raise CdgpsError(f"{source}: window: expected start_s and end_s in seconds") from None
    if not (np.isfinite(a) and np.isfinite(b) and a <= b):
        raise CdgpsError(f"{source}: window.start_s {a!r} and window.end_s {b!r}: expected finite times in seconds, "
                         f"start_s <= end_s")
    if abs(b - t0) > 1e-6:
        return None
    return a, b


def _segment_biases(init: dict, wd) -> tuple[np.ndarray, np.ndarray]:
    """Per window bias segment: INIT's bias (m) and whether its integer is fixed."""
    table = {}
    for b in init.get("biases", []):
        try:
            key = (str(b["antenna"]), str(b["transmitter"]), round(float(b["segment_start_s"]), 6))
            table[key] = (float(b["bias_m"]), bool(b.get("fixed", False)))
        except (KeyError, TypeError, ValueError):
            raise CdgpsError("INIT.json: biases: expected antenna, transmitter, bias_m, segment_start_s "
                             "for a window from 'cdgps init'") from None
    vals, fixed, missing = [], [], []
    for s in wd.segments:
        key = (s["antenna"], s["transmitter"], round(float(s["start_s"]), 6))
        if key not in table:
            missing.append(f"{s['antenna']}/{s['transmitter']} from {s['start_s']:g} s")
            vals.append(np.nan)            # data of a segment INIT has no bias for are left out
            fixed.append(True)
            continue
        vals.append(table[key][0])
        fixed.append(table[key][1])
    if len(missing) > len(wd.segments) // 2:
        raise CdgpsError("INIT.json does not match this RUN's window data: no INIT bias for the lock segment(s) "
                         + ", ".join(missing[:5]) + (f" (+{len(missing) - 5} more)" if len(missing) > 5 else "")
                         + "; was INIT made from this RUN?")
    return np.asarray(vals, dtype=float), np.asarray(fixed, dtype=bool), missing


def _measurements(cfg, wd, x_lin, seg_bias, seg_free):
    """Linearized rows of every epoch: H (N, C, n), ỹ − known bias (N, C), free-bias column (N, C)."""
    N, C = wd.y_m.shape
    n = x_lin.shape[1]
    H = np.empty((N, C, n))
    ytil = np.empty((N, C))
    model = _phase_model(cfg, wd)
    for k0 in range(0, N, _CHUNK):
        h, Hk = model(x_lin[k0:k0 + _CHUNK], True)
        H[k0:k0 + _CHUNK] = Hk
        ytil[k0:k0 + _CHUNK] = wd.y_m[k0:k0 + _CHUNK] - h + np.einsum("kci,ki->kc", Hk, x_lin[k0:k0 + _CHUNK])
    seg = np.maximum(wd.segment, 0)
    known = np.where(seg_free[seg], 0.0, seg_bias[seg])
    ytil -= known
    col = np.where((wd.segment >= 0) & seg_free[seg], np.cumsum(seg_free)[seg] - 1, -1)
    return H, ytil, col


def _phase_model(cfg, wd):
    """h (and H) of the window's channels on N states at once: the compiled model when available
    (:func:`cdgps_cli.estimation.kernel.phase_model_batch`), else :func:`cdgps_cli.measurement.phase.phase_model`
    (equal to rounding)."""
    if _compiled():
        from cdgps_cli.estimation import kernel

        geometry = kernel.pack_geometry(cfg, wd.ant, wd.tx)
        return lambda x, jacobian=False: kernel.phase_model_batch(geometry, x, jacobian=jacobian)
    return lambda x, jacobian=False: phase_model(cfg, x, wd.ant, wd.tx, jacobian=jacobian)


def _information_rows(H, ytil, col, sigma, n, p, n_mp=0):
    """Per epoch the measurement information H̃ᵀR⁻¹H̃ (N, p, p) and H̃ᵀR⁻¹ỹ (N, p), vectorized;
    R = diag(σ_c²), ``sigma`` (C,) per channel (m).

    z = [x (n); multipath (n_mp = 0 or C, one per channel); free biases]."""
    N, C, _ = H.shape
    present = ~np.isnan(ytil)
    Ht = np.zeros((N, C, p))
    Ht[:, :, :n] = np.where(present[..., None], H, 0.0)
    if n_mp:
        Ht[:, np.arange(C), n + np.arange(C)] = present
    kk, cc = np.nonzero((col >= 0) & present)
    Ht[kk, cc, n + n_mp + col[kk, cc]] = 1.0
    yv = np.where(present, ytil, 0.0)
    w = 1.0 / np.broadcast_to(np.asarray(sigma, dtype=float), (C,))**2
    Hw = Ht * w[:, None]
    return np.matmul(Ht.transpose(0, 2, 1), Hw), np.einsum("kci,kc->ki", Hw, yv)


def _forward(A_inv, G, H, ytil, col, sigma, n, p, mp=None):
    """Information filter from zero information (but the multipath states' stationary prior);
    returns the priors (Ȳ, ȳ) and the last posterior.  The epoch loop runs in the compiled kernel
    when it is available (``_ekfcore.window_forward``), else in :func:`_forward_numpy`."""
    N, C = H.shape[:2]
    n_mp = C if mp is not None else 0
    info, infv = _information_rows(H, ytil, col, sigma, n, p, n_mp)
    Y = np.zeros((p, p))
    if n_mp:
        Y[n:n + n_mp, n:n + n_mp] = np.eye(n_mp) / mp.sigma_m**2
    if not _compiled():
        return _forward_numpy(A_inv, G, info, infv, Y)
    from cdgps_cli.estimation import kernel

    Ybar = np.zeros((N, p, p))
    ybar = np.zeros((N, p))
    yv = np.zeros(p)
    bad = kernel._ekfcore.window_forward(*kernel.csr(A_inv.T), kernel._f64(G), info, infv, Y, yv, Ybar, ybar,
                                        N, p, G.shape[1])
    if bad >= 0:
        raise np.linalg.LinAlgError(f"INIT's window: I + GᵀMG not positive definite at epoch {bad}")
    return Ybar, ybar, Y, yv


def _compiled() -> bool:
    """The window's loops in C: the kernel is available and has them (an older build has not)."""
    from cdgps_cli.estimation import kernel

    return kernel.available() and hasattr(kernel._ekfcore, "window_forward")


def _forward_numpy(A_inv, G, info, infv, Y):
    """:func:`_forward`'s epoch loop in numpy (the reference of the compiled one)."""
    N, p = infv.shape
    Ybar = np.zeros((N, p, p))
    ybar = np.zeros((N, p))
    r = G.shape[1]
    I_r = np.eye(r)
    yv = np.zeros(p)
    for k in range(N):
        if k:
            M = A_inv.T @ Y @ A_inv
            m = A_inv.T @ yv
            if r:
                MG = M @ G
                K = cho_solve(cho_factor(I_r + G.T @ MG, check_finite=False), MG.T, check_finite=False).T
                M = M - K @ MG.T
                m = m - K @ (G.T @ m)
            Y, yv = 0.5 * (M + M.T), m
            Ybar[k], ybar[k] = Y, yv
        Y = Y + info[k]
        yv = yv + infv[k]
    return Ybar, ybar, Y, yv


def _backward(A_inv, Q, Ybar, ybar, Y_end, y_end):
    """The RTS pass from the prior information (module docstring): smoothed z (N, p), Pz (N, p, p);
    its epoch loop in the compiled kernel when available (``_ekfcore.window_backward``)."""
    N, p = ybar.shape
    z = np.empty((N, p))
    Pz = np.empty((N, p, p))
    try:
        L = np.linalg.cholesky(Y_end)
    except np.linalg.LinAlgError:
        raise CdgpsError("INIT's window: the batch information at the window end is singular "
                         "(states or biases not observable)") from None
    Li = np.linalg.inv(L)
    Pz[-1] = Li.T @ Li
    z[-1] = Pz[-1] @ y_end
    if _compiled():
        from cdgps_cli.estimation import kernel

        kernel._ekfcore.window_backward(*kernel.csr(A_inv), kernel._f64(Q), Ybar, ybar, z, Pz, N, p)
        return z, Pz
    I = np.eye(p)
    for k in range(N - 2, -1, -1):
        QY = Q @ Ybar[k + 1]
        z[k] = A_inv @ (z[k + 1] - Q @ (Ybar[k + 1] @ z[k + 1] - ybar[k + 1]))
        F = I - QY
        Pk = A_inv @ (F @ Pz[k + 1] @ F.T + Q - QY @ Q) @ A_inv.T
        Pz[k] = 0.5 * (Pk + Pk.T)
    return z, Pz


def _backward_ekf(cfg, wd, A_inv, Q, x_end, P_end, seg_bias, sigma):
    """First linearization: the engine's step (:class:`~cdgps_cli.estimation.kalman.StepFilter`, the
    pseudolite SD model, one EKF update an epoch) run backward in time from INIT's end state, all
    biases as INIT's: x_k = A⁻¹ x_{k+1}, P_k = A⁻¹ P_{k+1} A⁻ᵀ + A⁻¹ Q A⁻ᵀ."""
    N = wd.y_m.shape[0]
    n = len(x_end)
    b = np.where(wd.segment >= 0, seg_bias[np.maximum(wd.segment, 0)], np.nan)
    Q_back = A_inv @ Q[:n, :n] @ A_inv.T
    if _compiled():
        xs = _backward_ekf_compiled(cfg, wd, A_inv, Q_back, x_end, P_end, wd.y_m - b, sigma)
        if xs is not None:
            return xs
    model = PseudoliteSD(cfg, wd.y_m - b, wd.ant, wd.tx, sigma)
    step = StepFilter(x_end, P_end)
    xs = np.empty((N, n))
    xs[-1] = step.x
    for k in range(N - 2, -1, -1):
        step.predict(A_inv, Q_back)
        rows = model.rows(k)
        if rows is not None:
            step.update(model, rows, max_iterations=1)
        xs[k] = step.x
    return xs


def _backward_ekf_compiled(cfg, wd, A_inv, Q_back, x_end, P_end, y_m, sigma):
    """:func:`_backward_ekf` in the compiled filter span (``kernel.ForwardKernel``, the same EKF step
    to rounding) over the window's epochs reversed, biases already subtracted; None when the span
    stops early (a covariance not positive definite: the numpy step then runs)."""
    from cdgps_cli.estimation import kernel

    N, C = y_m.shape
    n = len(x_end)
    Yr = np.ascontiguousarray(y_m[::-1])
    xs = np.empty((N, n))
    Ps = np.empty((N, n, n))
    kern = kernel.ForwardKernel(cfg, wd.ant, wd.tx, A_inv, Q_back, np.zeros((n, 0)), sigma, np.inf, 0.99, N + 1,
                                Yr, np.zeros((N, C), dtype=np.int8), np.zeros((N, 0)), xs, Ps,
                                np.full((N, C), np.nan), np.full(N, np.nan), np.zeros(N, dtype=np.int64),
                                np.full((N, C), np.nan))
    k, _, _, _ = kern.run(1, np.asarray(x_end, float), np.asarray(P_end, float), np.zeros(C), {}, 0, -1)
    if k < N:
        return None
    xs[0] = x_end
    return xs[::-1].copy()


def window_states(run: Run, init: dict, window: tuple[float, float], x_end: np.ndarray,
                  P_end: np.ndarray) -> WindowStates:
    """The batch solution at every epoch of INIT's window (module docstring).

    Parameters
    ----------
    run : Run
        The RUN INIT was made from.
    init : dict
        INIT.json (``sigma_m_per_channel`` / ``sigma_m``, ``biases`` with ``segment_start_s`` and ``fixed``,
        ``options.process_noise``).
    window : (start_s, end_s)
        From :func:`batch_window`.
    x_end, P_end : (n,), (n, n)
        INIT's state and covariance at the window end (first linearization only).

    Raises CdgpsError when INIT does not match the RUN's window data.
    """
    from cdgps_cli.estimation.initializer import window_data

    cfg = run.cfg
    wd = window_data(run, window[0], window[1])
    if abs(float(wd.time_s[-1]) - window[1]) > 1e-6 or abs(float(wd.time_s[0]) - window[0]) > 1e-6:
        raise CdgpsError(f"INIT.json's window {window[0]:g}–{window[1]:g} s is not in this RUN's phase data "
                         f"({wd.time_s[0]:g}–{wd.time_s[-1]:g} s there); was INIT made from this RUN?")
    seg_bias, seg_fixed, missing = _segment_biases(init, wd)
    if missing:                            # (an INIT edited by hand): those segments' data are not used
        drop = np.isnan(seg_bias)[np.maximum(wd.segment, 0)] & (wd.segment >= 0)
        wd.y_m[drop] = np.nan
    seg_free = ~seg_fixed
    sigma, _ = init_channel_sigma_m(init, cfg, wd.channels)     # (C,) the batch's per-channel σ
    model = discrete_model(cfg)
    n = model.A.shape[0]
    mf = int(seg_free.sum())
    L = np.sqrt(np.diag(model.W))
    process_noise = bool((init.get("options") or {}).get("process_noise", True))
    Gx = (model.Bw * L)[:, L > 0] if process_noise else np.zeros((n, 0))
    mp = multipath.from_init(init)
    mp = mp if mp.active else None
    Ax = model.A
    if mp is not None:                     # INIT's Gauss–Markov state per channel, after the structure's
        Ax, Gx = multipath.augment(Ax, Gx, len(wd.channels), mp, cfg.sample_period_s)
    nz = Ax.shape[0]                       # structure (+ multipath) states
    p = nz + mf
    A = np.eye(p)
    A[:nz, :nz] = Ax
    A_inv = np.eye(p)
    A_inv[:nz, :nz] = np.linalg.inv(Ax)
    G = np.zeros((p, Gx.shape[1]))
    G[:nz] = Gx
    Q = G @ G.T

    x_lin = _backward_ekf(cfg, wd, A_inv[:n, :n], Q, np.asarray(x_end, float), np.asarray(P_end, float),
                          seg_bias, sigma)
    it = 0
    while True:
        it += 1
        H, ytil, col = _measurements(cfg, wd, x_lin, seg_bias, seg_free)
        Ybar, ybar, Y_end, y_end = _forward(A_inv, G, H, ytil, col, sigma, n, p, mp)
        z, Pz = _backward(A_inv, Q, Ybar, ybar, Y_end, y_end)
        # h depends on the modal positions only: converged when their step is a small fraction of σ
        nm = cfg.n_modes
        sig = np.sqrt(np.maximum(np.diagonal(Pz[:, :nm, :nm], axis1=1, axis2=2), 1e-300))
        step = float(np.max(np.abs(z[:, :nm] - x_lin[:, :nm]) / sig))
        x_lin = z[:, :n].copy()
        if step <= STEP_SIGMA or it >= MAX_ITERATIONS:
            break
    del H, ytil
    # post-fit residuals with every bias (fixed: INIT's; free: re-estimated)
    b = seg_bias.copy()
    b[seg_free] = z[-1, nz:]
    resid = np.empty(wd.y_m.shape)
    model = _phase_model(cfg, wd)
    for k0 in range(0, len(wd.time_s), _CHUNK):
        resid[k0:k0 + _CHUNK] = wd.y_m[k0:k0 + _CHUNK] - model(x_lin[k0:k0 + _CHUNK])
    resid -= np.where(wd.segment >= 0, b[np.maximum(wd.segment, 0)], np.nan)
    if mp is not None:
        resid -= z[:, n:nz]
    return WindowStates(wd.time_s, z[:, :n].copy(), Pz[:, :n, :n].copy(), z, Pz, Ybar, A, Q, list(wd.channels),
                        resid, it, mf, missing)


def extend_smoothing(ws: WindowStates, x_next: np.ndarray, P_next: np.ndarray,
                     x_ref: np.ndarray, P_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Carry a smoothing pass that ends at the window's last epoch into the window.

    ``x_next, P_next`` (n,), (n, n): the smoothed state at the window end given the whole record;
    ``x_ref, P_ref``: the same epoch's state given the window only (what the later filter started
    from).  The free biases are not observed after the window (the filter treats them as known),
    so their part of the difference is zero.  Returns (N−1, n) states and (N−1, n, n) covariances
    of the window's epochs before its end.
    """
    N, p = ws.z.shape
    n = ws.x.shape[1]
    dz = np.zeros(p)
    dz[:n] = x_next - x_ref
    dP = np.zeros((p, p))
    dP[:n, :n] = P_next - P_ref
    A_inv = np.linalg.inv(ws.A)
    I = np.eye(p)
    xs = np.empty((N - 1, n))
    Ps = np.empty((N - 1, n, n))
    for k in range(N - 2, -1, -1):
        Gk = A_inv @ (I - ws.Q @ ws.Ybar[k + 1])
        dz = Gk @ dz
        dP = Gk @ dP @ Gk.T
        dP = 0.5 * (dP + dP.T)
        xs[k] = ws.z[k, :n] + dz[:n]
        Ps[k] = ws.Pz[k, :n, :n] + dP[:n, :n]
    return xs, Ps
