"""The compiled inner loops of :mod:`cdgps_cli.estimation.filter` and of the batch initializer (C extension
``cdgps_cli.estimation._ekfcore``), and their inputs.

The forward filter with fixed biases spends its time in steady-state epochs: predict, evaluate the
measurement model, update, test the NIS.  :class:`ForwardKernel` runs stretches of such epochs in C and
hands back to ``ekf.estimate`` the first epoch that needs its Python logic (lock events, bias
re-estimation, innovation outliers, re-initialization); :func:`rts` is the smoother's pass.  Both
use the structure of the modal model: A (ZOH of 2×2 blocks per mode) as a sparse CSR matrix, and H
non-zero only in the n_m position columns.  The arithmetic is that of the numpy path (information
form with a diagonal R = diag(σ_c²) per channel, Cholesky inverses, NIS by Woodbury), so both paths agree to rounding.

The extension is optional: :func:`available` is false when it was not compiled, when its API does
not match this module, or when the environment variable ``CDGPS_NO_KERNEL`` is set to anything but
``""`` / ``"0"`` (tests use it to force the numpy path).  Then ``ekf`` runs its pure-numpy loops.
"""

from __future__ import annotations

import numpy as np

# the extension, its API number and the availability rule live in compiled.py (imported by the
# batch solver, which must not import the model geometry this module packs)
from cdgps_cli.estimation.compiled import API, _ekfcore, _f64, available, srif_forward  # noqa: F401

STOP_REASONS = {0: "end", 1: "lock event", 2: "re-bias", 3: "outlier", 4: "re-initialization", 5: "cholesky"}


def path_name() -> str:
    """"c" or "numpy": which forward-filter path :func:`cdgps_cli.estimation.filter.estimate` takes (biases="fixed")."""
    return "c" if available() else "numpy"


def _i64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64)


def _inputs(B: np.ndarray, U_in: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """B (p, n_u) and U_in (N, n_u) for C; inputs that are zero throughout (e.g. a broadcast row of
    zeros: no thruster logged) become n_u = 0 — the C prediction skips a zero u anyway, so the
    numbers are the same — and no (N, n_u) copy is made."""
    U = np.asarray(U_in)
    if U.ndim == 2 and (U.strides[0] == 0 or U.size == 0) and not U[:1].any():
        return np.zeros((B.shape[0], 0)), np.zeros((U.shape[0], 0))
    return _f64(B), U_in


def csr(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row pointer, column indices and values of the exact non-zeros of a square matrix."""
    A = np.asarray(A, dtype=float)
    rows, cols = np.nonzero(A)
    row = np.zeros(A.shape[0] + 1, dtype=np.int64)
    np.add.at(row, rows + 1, 1)
    return _i64(np.cumsum(row)), _i64(cols), _f64(A[rows, cols])


def pack_geometry(cfg, ant, tx) -> tuple[np.ndarray, np.ndarray]:
    """Pack the antenna kinematics and the channels (antenna, transmitter) for the C model.

    Layout (see _ekfcore.c): gi = [n_q, n_m, n_a, n_c, n_s, master, far, rigid, has_D, n_tr,
    section[n_a], rot_idx[n_s·3], channel antenna[n_c], translations[n_tr·3]];
    gf = [origin 3, pivot n_a·3, rel n_a·3, D n_a·3·n_q, U n_q·n_m, transmitter n_c·3].
    """
    from cdgps_cli.model.kinematics import EpochGeometry

    geo = EpochGeometry(cfg)
    ant = np.asarray(ant, dtype=np.int64)
    tx = np.asarray(tx, dtype=np.int64)
    U = np.asarray(cfg.mode_shapes, dtype=float)
    nq, nm = U.shape
    sec = np.asarray(cfg.antenna_section, dtype=np.int64)
    ns = len(cfg.sections)
    trans = np.array(geo.trans, dtype=np.int64).reshape(-1, 3)
    head = [nq, nm, len(sec), len(ant), ns, cfg.master_index, int(bool(cfg.transmitter_far_field)),
            -1 if cfg.rigid_index is None else int(cfg.rigid_index), int(geo.has_D), len(trans)]
    gi = np.concatenate([np.array(head, dtype=np.int64), sec, geo.rot_idx.reshape(-1).astype(np.int64),
                         ant, trans.reshape(-1)])
    tpos = np.asarray(cfg.transmitter_position_m, dtype=float)[tx].reshape(-1, 3)
    na = len(sec)
    pivot = np.broadcast_to(np.asarray(geo.pivot, dtype=float), (na, 3))     # (na, 1) zeros without sections
    rel = np.broadcast_to(np.asarray(geo.rel, dtype=float), (na, 3))
    gf = np.concatenate([np.asarray(cfg.body_origin_m, dtype=float).reshape(3), pivot.reshape(-1), rel.reshape(-1),
                         np.asarray(geo.D, dtype=float).reshape(-1), U.reshape(-1), tpos.reshape(-1)])
    return _i64(gi), _f64(gf)


class PhaseModel:
    """The C measurement model, called like :class:`cdgps_cli.measurement.phase.EpochPhaseModel`:
    ``h, H = model(x)`` with H of shape (C, 2·n_m)."""

    def __init__(self, cfg, ant, tx):
        if _ekfcore is None:
            raise ImportError("cdgps_cli.estimation._ekfcore is not compiled")
        self.gi, self.gf = pack_geometry(cfg, ant, tx)
        self.nm = cfg.n_modes
        self.C = len(ant)

    def __call__(self, x):
        x = _f64(x)
        h = np.empty(self.C)
        Hm = np.empty((self.C, self.nm))
        _ekfcore.phase_model(self.gi, self.gf, x, h, Hm)
        H = np.zeros((self.C, 2 * self.nm))
        H[:, :self.nm] = Hm
        return h, H


class ForwardKernel:
    """Forward EKF with fixed biases over steady-state epochs, writing into estimate's arrays.

    Parameters are those of the filter (A, Q, B: state transition, process noise, input matrix;
    sigma: the measurement σ (m) of each channel, shape (C,) (a scalar is broadcast); outlier
    threshold, NIS probability, re-initialization count) and its per-epoch arrays:
    Y (N, C) phases in metres (NaN absent), EVENT (N, C) int8 from ``lock_events``, U_in (N, n_u),
    and the outputs xs (N, n), Ps (N, n, n), resid (N, C), nis (N,), nis_dof (N,) int64 and
    hph (N, C): H_c(x_k) P_k H_c(x_k)ᵀ (m²) of each used channel c at each epoch k run here, with the
    Jacobian at the filtered state x_k and the filtered covariance P_k (the term of the residual noise
    estimate, :func:`cdgps_cli.measurement.noise.filter_sigma_estimate`); untouched elsewhere.
    """

    def __init__(self, cfg, ant, tx, A, Q, B, sigma, outlier_sigma, nis_probability, reinit_after,
                 Y, EVENT, U_in, xs, Ps, resid, nis, nis_dof, hph):
        from cdgps_cli.estimation.chi2 import chi2_quantile

        self.gi, self.gf = pack_geometry(cfg, ant, tx)
        self.n = A.shape[0]
        self.A = csr(A)
        self.Q = _f64(Q)
        self.B, U_in = _inputs(B, U_in)
        self.nu = self.B.shape[1]
        C = len(ant)
        # the NIS bound per number of channels used (index 0 unused)
        self.chi2 = _f64(np.r_[np.nan, chi2_quantile(nis_probability, np.arange(1, C + 1))])
        sig = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (C,))
        if not np.all(np.isfinite(sig) & (sig > 0)):
            raise ValueError("ForwardKernel: sigma must be positive and finite for every channel")
        self.r_var = _f64(sig**2)                # R = diag(σ_c²)
        self.outlier_sigma = float(outlier_sigma)
        self.reinit_after = int(reinit_after)
        self.Y = _f64(Y)
        self.EVENT = np.ascontiguousarray(EVENT, dtype=np.int8)
        self.U_in = _f64(U_in)
        for name, arr, dt in (("xs", xs, np.float64), ("Ps", Ps, np.float64), ("resid", resid, np.float64),
                              ("nis", nis, np.float64), ("nis_dof", nis_dof, np.int64), ("hph", hph, np.float64)):
            if arr.dtype != dt or not arr.flags.c_contiguous or not arr.flags.writeable:
                raise ValueError(f"ForwardKernel: {name} must be a writable C-contiguous {np.dtype(dt)} array")
        self.xs, self.Ps, self.resid, self.nis, self.nis_dof, self.hph = xs, Ps, resid, nis, nis_dof, hph
        self.N = len(self.Y)
        self.C = C
        self.epochs = 0                  # epochs run in C (statistics)
        self.stops: dict = {}            # stop reason → count

    def run(self, k0, x, P, bias, rebias, fail_run, k_reinit_block, k1=None, Q=None, stop_on_nis_failure=False):
        """Run epochs k0, k0+1, … (up to k1, excluded) from the state (x, P) entering k0 until an
        epoch needs Python.

        ``bias`` (C,) current biases (NaN: unknown), ``rebias``: channels being re-estimated;
        ``Q``: the process noise of this span (default: the constructor's); ``stop_on_nis_failure``:
        hand back the first epoch whose NIS fails its bound (instead of counting failures towards a
        re-initialization; ``fail_run`` is then returned as given, or 0 once an epoch with data passed).
        Returns (k_stop, fail_run, x, P): epochs k0 … k_stop−1 are done (outputs written) and
        (x, P) are the state entering k_stop; fail_run is the NIS failure count after k_stop−1.
        """
        if stop_on_nis_failure:
            k, _, x, P = self._span(k0, x, P, bias, rebias, 0, 1, -1, k1, Q)
            passed = bool((self.nis_dof[k0:k] > 0).any())
            return k, (0 if passed else int(fail_run)), x, P
        return self._span(k0, x, P, bias, rebias, fail_run, self.reinit_after, k_reinit_block, k1, Q)

    def _span(self, k0, x, P, bias, rebias, fail_run, reinit_after, k_reinit_block, k1, Q):
        x = np.array(x, dtype=np.float64)              # copies: the kernel updates them in place
        P = np.array(P, dtype=np.float64)
        mask = np.zeros(self.C, dtype=np.uint8)
        if rebias:
            mask[list(rebias)] = 1
        k_stop, fail_run, reason = _ekfcore.filter_span(
            self.gi, self.gf, *self.A, self.Q if Q is None else _f64(Q), self.B, self.chi2, self.Y, self.EVENT,
            _f64(bias), mask, self.U_in,
            x, P, self.xs, self.Ps, self.resid, self.nis, self.nis_dof, self.r_var, self.hph,
            self.N, self.n, self.nu, int(k0), self.N if k1 is None else int(k1), int(fail_run),
            int(reinit_after), int(k_reinit_block), self.outlier_sigma)
        self.epochs += k_stop - k0
        key = STOP_REASONS.get(reason, str(reason))
        self.stops[key] = self.stops.get(key, 0) + 1
        return k_stop, fail_run, x, P


def rts(A, Q, B, U_in, xf, Pf, xs, Ps, extra_q=None, no_link=None) -> None:
    """RTS pass in C: smoothed states into xs (N, p) and Ps (N, p, p), which may be xf and Pf
    themselves; same arguments and semantics as :func:`cdgps_cli.estimation.filter.rts_smooth`.

    Raises numpy.linalg.LinAlgError when a predicted covariance is not positive definite.
    """
    N, p = xf.shape
    B, U_in = _inputs(_f64(B).reshape(p, -1), U_in)
    nu = B.shape[1]
    for name, arr in (("xf", xf), ("Pf", Pf), ("xs", xs), ("Ps", Ps)):
        if arr.dtype != np.float64 or not arr.flags.c_contiguous:
            raise ValueError(f"rts: {name} must be a C-contiguous float64 array")
    if not (xs.flags.writeable and Ps.flags.writeable):
        raise ValueError("rts: xs and Ps must be writable")
    items = sorted((int(k), int(i), float(q)) for k, lst in (extra_q or {}).items() for i, q in lst)
    eq_k = np.array([t[0] for t in items], dtype=np.int64)
    eq_i = np.array([t[1] for t in items], dtype=np.int64)
    eq_q = np.array([t[2] for t in items], dtype=np.float64)
    nl = np.zeros(0, dtype=np.uint8) if no_link is None else np.ascontiguousarray(no_link, dtype=np.uint8)
    fail = _ekfcore.rts(*csr(A), _f64(Q), B, _f64(U_in).reshape(N, nu), xf, Pf, xs, Ps, eq_k, eq_i, eq_q, nl,
                        N, p, nu)
    if fail >= 0:
        raise np.linalg.LinAlgError(f"smoother: predicted covariance after epoch {fail} is not positive definite")


def phase_model_batch(geometry: tuple[np.ndarray, np.ndarray], x: np.ndarray, jacobian: bool = False):
    """The C measurement model on N states at once, as :func:`cdgps_cli.measurement.phase.phase_model`.

    Parameters
    ----------
    geometry : (gi, gf)
        :func:`pack_geometry` of the config and the channels (C of them).
    x : ndarray (N, n_x)
        Modal states [ξ, ξ̇] in their first 2·n_m columns (n_x ≥ 2·n_m; further columns ignored).
    jacobian : bool
        Also return H = ∂h/∂x, shape (N, C, 2·n_m) (zero in the rate columns).

    Returns
    -------
    h : ndarray (N, C), metres, and H with ``jacobian``.
    """
    gi, gf = geometry
    nm, C = int(gi[1]), int(gi[3])
    x = _f64(x)
    N = x.shape[0]
    h = np.empty((N, C))
    if not jacobian:
        _ekfcore.phase_model_batch(gi, gf, x, h, np.empty(0), N, x.shape[1], False)
        return h
    Hm = np.empty((N, C, nm))
    _ekfcore.phase_model_batch(gi, gf, x, h, Hm, N, x.shape[1], True)
    H = np.zeros((N, C, 2 * nm))
    H[:, :, :nm] = Hm
    return h, H

