"""The engine's Kalman step: prediction through a transition and an iterated information-form
update through the measurement-model interface (../shared/design/architecture.md "Filter").

:class:`StepFilter` holds (x, P) and steps it one epoch at a time: :meth:`StepFilter.predict`
(x̄ = A x + u, P̄ = A P Aᵀ + Q) and :meth:`StepFilter.update` on the rows of one epoch given by a
:class:`~cdgps_cli.measurement.model.MeasurementModel` (:func:`iterated_update`).  It is the loop
body of the forward filter :func:`cdgps_cli.estimation.model_filter.filter_numpy` and of the
Python epochs of :func:`~cdgps_cli.estimation.model_filter.filter_dd_kernel`, the closed loop's
in-loop filter (:class:`cdgps_cli.estimation.loop_filter.LoopFilter`) and the first linearization
of the INIT window (:mod:`cdgps_cli.estimation.window_smoother`).

The update whitens the rows by their noise (ρ_w = L⁻¹ρ, H_w = L⁻¹H for C = L Lᵀ, or ρ/σ, H/σ)
and applies, relinearizing h at the iterate x_i (Gauss–Newton),

    P⁺ = (P̄⁻¹ + H_wᵀ H_w)⁻¹,   x_{i+1} = x̄ + P⁺ H_wᵀ (z_w − h_w(x_i) − H_w (x̄ − x_i)),
    NIS = ν_wᵀ ν_w − (H_wᵀν_w)ᵀ P⁺ (H_wᵀν_w)  at the prior linearization

(the last is νᵀ(H P̄ Hᵀ + C)⁻¹ν by the matrix inversion lemma).  1998 paper Eq. (16)–(23) in
information form; both noise kinds of the architecture's filter.  :func:`update` is the same step
for rows already linearized at x̄ (residual ρ = z − h(x̄) and H).

The static engine's rows (:class:`~cdgps_cli.measurement.dd_signals.RunDDModel`, ≈ 10 DD rows on ≈ 90 states
an epoch, 86 400 epochs a day at 1 Hz) take :func:`iterated_update_covariance`'s sparse path in C
(``_ekfcore.sd_update``): the model's h, H and whitening and the update's products, with the very BLAS / LAPACK
calls numpy's matmul and scipy's wrappers make for them (numpy's bundled CBLAS, scipy's cython_lapack) and
numpy's elementwise order, so x, P and NIS are the numpy path's bit for bit (tests/estimation/
test_kalman_compiled.py); a case it does not cover, or CDGPS_NO_KERNEL, runs the numpy path.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.estimation import compiled

__all__ = ["StepFilter", "iterated_update", "iterated_update_covariance", "predict", "update", "positive_definite",
           "LAPACK_CHOLESKY", "NUMPY_INVERSE"]

#: LAPACK potrf / potrs and scipy's solve_triangular, imported on first use: scipy's import
#: (≈ 0.13 s) stays off the start-up of `cdgps rtk`, whose filter runs on this step too
_SCIPY: list = []


def _scipy() -> list:
    """[dpotrf, dpotrs, solve_triangular, dtrtrs], imported once."""
    if not _SCIPY:
        from scipy.linalg import solve_triangular
        from scipy.linalg.lapack import dpotrf, dpotrs, dtrtrs
        _SCIPY.extend((dpotrf, dpotrs, solve_triangular, dtrtrs))
    return _SCIPY


class StepFilter:
    """The forward filter's state (x, P) and its step, one epoch at a time.

    Parameters
    ----------
    x : array_like, shape (n,)
        Initial state (copied).
    P : array_like, shape (n, n)
        Its covariance (copied).

    Attributes
    ----------
    x : ndarray, shape (n,)
        The current estimate: predicted after :meth:`predict`, updated after :meth:`update`.
    P : ndarray, shape (n, n)
        Its covariance.
    linalg : (factor, solve, inverse), optional
        The update's linear algebra (:func:`iterated_update`); default :data:`LAPACK_CHOLESKY`.
    form : {"information", "covariance"}
        The update: :func:`iterated_update` (default; O(n³) an epoch) or
        :func:`iterated_update_covariance` (O(n² m): for large states with few rows an epoch).
    """

    def __init__(self, x, P, linalg=None, form: str = "information"):
        if form not in ("information", "covariance"):
            raise ValueError(f"form must be 'information' or 'covariance', got {form!r}")
        self.x = np.array(x, dtype=float)
        self.P = np.array(P, dtype=float)
        self.linalg = linalg
        self.form = form
        self.kernel = None      # the compiled covariance update, looked up at the first update (CDGPS_NO_KERNEL then)

    def predict(self, A: np.ndarray, Q: np.ndarray, known_input=None) -> None:
        """x̄ = A x (+ known input), P̄ = A P Aᵀ + Q.

        Parameters
        ----------
        A, Q : ndarray, shape (n, n)
            Transition and process-noise covariance over the step; A None for the identity, Q None
            (with A None) for no process noise.
        known_input : ndarray, shape (n,), optional
            The state change due to known inputs over the step (e.g. B u, or the exact response
            to fired thruster pulses).
        """
        if A is None:                   # the identity: A x and A P Aᵀ are x and P, exactly
            x = self.x
            if Q is not None:           # None: no process noise (P̄ = P, as P + 0 would give)
                self.P = self.P + Q
        else:
            x = A @ self.x
            self.P = A @ self.P @ A.T + Q
        self.x = x if known_input is None else x + known_input

    def update(self, model, rows, max_iterations: int = 5) -> float:
        """The iterated update with one epoch's ``rows`` (:class:`~cdgps_cli.measurement.model.Rows`)
        of ``model`` (a :class:`~cdgps_cli.measurement.model.MeasurementModel`), :func:`iterated_update`;
        returns the epoch's NIS (dof ``rows.z_m.size``)."""
        if self.form == "covariance":
            if self.kernel is None:
                self.kernel = _sd_kernel()
            self.x, self.P, nis = iterated_update_covariance(model, rows, self.x, self.P, max_iterations,
                                                             kernel=self.kernel)
        else:
            self.x, self.P, nis = iterated_update(model, rows, self.x, self.P, max_iterations, self.linalg)
        return nis


def iterated_update(model, mk, xbar: np.ndarray, Pbar: np.ndarray, max_iterations: int = 5, linalg=None):
    """(x, P, NIS) of one iterated information-form update on the whitened rows ``mk``.

    Iterates (Gauss–Newton) while the correction exceeds 1e-9 of the state, at most
    ``max_iterations`` times.  NIS uses the prior linearization:
    νᵀ(HPHᵀ + I)⁻¹ν = νᵀν − νᵀH(P⁻¹ + HᵀH)⁻¹Hᵀν (whitened ν, H).

    Parameters
    ----------
    model : MeasurementModel
        Gives h(x) (m,) and H (m, n) for the rows (``model.predict(x, mk)``).
    mk : Rows
        The epoch's rows: values ``z_m`` (m,), m, and ``whiten`` (their noise).
    xbar, Pbar : ndarray, shapes (n,), (n, n)
        Predicted state and covariance.
    max_iterations : int
        1: the extended Kalman update.
    linalg : (factor, solve, inverse), optional
        ``factor(M)`` of an SPD matrix, ``solve(factor, b)`` = M⁻¹ b and ``inverse(factor, eye)`` = M⁻¹:
        :data:`LAPACK_CHOLESKY` (default) or :data:`NUMPY_INVERSE` (numpy only: no scipy import, for
        start-up-bound one-shot commands such as `cdgps rtk`).

    Returns
    -------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    nis : float
    """
    factor, solve, inverse = linalg if linalg is not None else LAPACK_CHOLESKY
    eye = np.eye(len(xbar))
    Pinv = inverse(factor(Pbar), eye)

    def correction(H, v, first, _a):                # (P⁻¹ + HᵀH)⁻¹ Hᵀ ν, its NIS at x̄, the factor
        cf = factor(Pinv + H.T @ H)
        hv = H.T @ v
        dx = solve(cf, hv)
        return dx, (float(v @ v - hv @ dx) if first else None), cf

    xi, nis, cf = _gauss_newton(model, mk, xbar, max_iterations, correction)
    P = inverse(cf, eye)
    return xi, 0.5 * (P + P.T), nis


def _gauss_newton(model, mk, xbar: np.ndarray, max_iterations: int, correction, sparse: bool = False):
    """The iteration both update forms share: at each iterate x_i the whitened innovation
    ν = z_w − h_w(x_i) − H (x̄ − x_i) (at x̄: z_w − h_w(x̄)), x_{i+1} = x̄ + Δx from
    ``correction(H, ν, first, a) → (Δx, NIS at x̄ or None, what the covariance needs)``, until the step is
    ≤ 1e-9 of the state, or the model says the step leaves its linearization good (``model.linear_within(Δ)``, when
    it has one: relinearizing would not move the state), or ``max_iterations`` (the rule: a second iteration only
    when the first step is not negligible).  ``sparse``: H is cut to its non-zero columns ``a`` (:func:`_active_columns`) before
    it is whitened, and ``correction`` gets H[:, a] and a (else H whole and a None); Δx is of the whole
    state either way.  Returns (x, NIS, the last correction's third item)."""
    zw = mk.whiten(mk.z_m)
    linear = getattr(model, "linear_within", None)          # a model that can tell its step is linear enough
    xi = xbar.copy()
    nis = np.nan
    last = max(int(max_iterations), 1) - 1
    for it in range(last + 1):
        h, H = model.predict(xi, mk)
        a = None
        if sparse:
            a = _active_columns(H)
            if a is not None:
                H = H[:, a]
        H = mk.whiten(H)
        hw = mk.whiten(h)
        if it == 0:
            v = zw - hw
        else:
            v = zw - hw - H @ ((xbar - xi) if a is None else (xbar[a] - xi[a]))
        dx, nis_it, keep = correction(H, v, it == 0, a)
        if it == 0:
            nis = nis_it
        x_new = xbar + dx
        if it == last:                              # no convergence test after the last allowed step
            xi = x_new
            break
        step = abs(x_new - xi).max()
        done = step <= 1e-9 * max(1.0, float(abs(x_new).max())) or (linear is not None and linear(x_new - xi))
        xi = x_new
        if done:
            break
    return xi, nis, keep


def iterated_update_covariance(model, mk, xbar: np.ndarray, Pbar: np.ndarray, max_iterations: int = 5,
                               sparse: bool = True, kernel=None):
    """(x, P, NIS) of :func:`iterated_update` in covariance form: O(n² m) an epoch, no n × n factor.

    With whitened rows (noise I) linearized at the iterate x_i: S = H P̄ Hᵀ + I (m × m, Cholesky),
    K = P̄ Hᵀ S⁻¹, x_{i+1} = x̄ + K (z_w − h_w(x_i) − H (x̄ − x_i)); NIS = νᵀ S⁻¹ ν at x̄;
    P⁺ = P̄ − P̄ Hᵀ S⁻¹ H P̄ (the symmetric form of (I − K H) P̄) at the last linearization.
    Algebraically equal to :func:`iterated_update` (matrix inversion lemma); same iteration rule.

    The fast path (``sparse``, taken when H has columns that are zero in every row, e.g. the static
    engine's ≈ 90 states of which an epoch's rows touch the position and their own ≈ 10 arcs): only
    H's non-zero columns a enter, U = P̄[:, a] H_aᵀ (n × m, O(n |a| m)), S = H_a U[a] + I = Rᵀ R,
    [V | w] = R⁻ᵀ [Uᵀ | ν] (one triangular solve), x_{i+1} = x̄ + Vᵀ w, NIS = wᵀ w and P⁺ = P̄ − Vᵀ V
    (one rank-m correction, formed symmetric: exactly symmetric when P̄ is, so it is not symmetrized
    again).  The same values as the dense form to rounding (tests/estimation/test_kalman.py);
    ``sparse=False`` or H without a zero column: the dense form.

    Parameters
    ----------
    model, mk, xbar, Pbar, max_iterations
        As :func:`iterated_update`.
    sparse : bool
        Work on H's non-zero columns when it has zero ones.
    kernel : callable or False, optional
        The compiled twin of the sparse path for a model with ``range_terms`` (the static engine's
        :class:`~cdgps_cli.measurement.dd_signals.RunDDModel`; ``_ekfcore.sd_update``, the same bits), as
        :func:`_sd_kernel` gives it (False: numpy only; None: looked up, which reads CDGPS_NO_KERNEL).

    Returns
    -------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    nis : float
    """
    if sparse:
        terms = getattr(model, "range_terms", None)
        if terms is not None:                       # the static engine's rows: the compiled twin of this path
            out = _compiled_range_update(terms(mk), mk, xbar, Pbar, max_iterations, kernel)
            if out is not None:
                return out

    def correction(H, v, first, a):                 # P̄ Hᵀ S⁻¹ ν, its NIS at x̄, what P⁺ needs
        if a is None:                               # dense: (P̄ Hᵀ, factor of S)
            U = Pbar @ H.T                          # P̄ Hᵀ (n, m)
            S = H @ U
            S.ravel()[::S.shape[0] + 1] += 1.0      # (S is a new C-contiguous array: its diagonal)
            c = _chol_factor(S)                     # S = H P̄ Hᵀ + I (m, m)
            sv = _chol_solve(c, v)                  # S⁻¹ ν
            return U @ sv, (float(v @ sv) if first else None), (U, c)
        U = Pbar[:, a] @ H.T                        # P̄ Hᵀ (n, m) from H's non-zero columns
        S = H @ U[a]
        S.ravel()[::S.shape[0] + 1] += 1.0
        c = _chol_factor(S)                         # S = Rᵀ R
        m, n = U.T.shape
        B = np.empty((m, n + 1), order="F")
        B[:, :n], B[:, n] = U.T, v
        W = _tri_solve_upper_t(c, B)                # R⁻ᵀ [Uᵀ | ν] in one solve: [V | w]
        V, w = W[:, :n], W[:, n]                    # K ν = Vᵀ w, νᵀ S⁻¹ ν = wᵀ w, U S⁻¹ Uᵀ = Vᵀ V
        return V.T @ w, (float(w @ w) if first else None), (V, None)

    xi, nis, (U, c) = _gauss_newton(model, mk, xbar, max_iterations, correction, sparse)
    if c is not None:
        P = Pbar - U @ _chol_solve(c, U.T)          # P̄ − P̄ Hᵀ S⁻¹ H P̄
        return xi, 0.5 * (P + P.T), nis
    G = U.T @ U                                     # Vᵀ V (numpy's syrk for a product with its own transpose)
    np.subtract(Pbar, G, out=G)
    return xi, G, nis


#: the compiled update (``_ekfcore.sd_update``) with its BLAS / LAPACK routines set, or False; None: not looked up
_SD_KERNEL: list = [None]


def _sd_kernel():
    """``_ekfcore.sd_update`` once its routines are set: numpy's own CBLAS dgemm / dgemv / dsyrk / ddot (the ones
    its matmul calls, from the OpenBLAS numpy bundles) and scipy's LAPACK dpotrf / dtrtrs (those of
    :func:`_chol_factor` and :func:`_tri_solve_upper_t`, through ``scipy.linalg.cython_lapack``); False when the
    extension, the library or a symbol is not found, or CDGPS_NO_KERNEL is set (then the numpy path runs)."""
    if not compiled.available():
        return False
    if _SD_KERNEL[0] is None:
        _SD_KERNEL[0] = False
        fn = getattr(compiled._ekfcore, "sd_update", None)
        addresses = _blas_lapack_addresses() if fn is not None else None
        if addresses is not None:
            compiled._ekfcore.sd_set_routines(*addresses)
            _SD_KERNEL[0] = fn
    return _SD_KERNEL[0]


def _blas_lapack_addresses():
    """(dgemm, dgemv, dsyrk, ddot, dpotrf, dtrtrs) addresses, or None: the CBLAS of numpy's bundled ILP64
    OpenBLAS (``scipy_cblas_*64_``, the library numpy's matmul calls) and scipy's cython_lapack routines."""
    import ctypes
    import glob
    import os
    libs = sorted(glob.glob(os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs",
                                         "libscipy_openblas64_*.so")))
    cfg = np.show_config(mode="dicts").get("Build Dependencies", {}).get("blas", {})
    if len(libs) != 1 or cfg.get("name") != "scipy-openblas" or "USE64BITINT" not in cfg.get("openblas configuration", ""):
        return None
    try:
        lib = ctypes.CDLL(libs[0])
        blas = [ctypes.cast(getattr(lib, f"scipy_cblas_{f}64_"), ctypes.c_void_p).value
                for f in ("dgemm", "dgemv", "dsyrk", "ddot")]
        from scipy.linalg import cython_lapack
        get_name, get_pointer = ctypes.pythonapi.PyCapsule_GetName, ctypes.pythonapi.PyCapsule_GetPointer
        get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
        get_pointer.restype, get_pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
        caps = [cython_lapack.__pyx_capi__[f] for f in ("dpotrf", "dtrtrs")]
        lapack = [get_pointer(c, get_name(c)) for c in caps]
    except (OSError, AttributeError, KeyError, ImportError):
        return None
    out = blas + lapack
    return out if all(out) else None


def _compiled_range_update(terms, mk, xbar, Pbar, max_iterations, kernel=None):
    """:func:`iterated_update_covariance`'s sparse path in C for rows whose model gives ``range_terms``
    (:meth:`cdgps_cli.measurement.dd_signals.RunDDModel.range_terms`: the satellite positions as seen by rover
    and base, the base position, λ, the ambiguity columns, the origin and the whitening's u, Σ^{-1/2} and blocks;
    rows ``z_m`` (2M,)); (x, P, NIS), the same bits, or None when the kernel is off or does not cover the case
    (the numpy path then runs).  ``kernel``: :func:`_sd_kernel`'s answer when the caller has it (None: asked)."""
    fn = _sd_kernel() if kernel is None else kernel
    if not fn or terms is None:
        return None
    sat_xyz, sat_base_xyz, base_xyz, lam, amb, origin, u, inv_sigma, block = terms
    n = xbar.size
    x, P = np.empty(n), np.empty((n, n))
    nis = fn(Pbar, xbar, mk.z_m, u, inv_sigma, block, sat_xyz, sat_base_xyz, base_xyz, lam, amb, origin,
             int(max_iterations), x, P)
    return None if nis is None else (x, P, nis)


def _active_columns(H: np.ndarray):
    """Indices of H's columns with a non-zero entry, or None when every column has one (nothing to skip)."""
    a = H.any(axis=0).nonzero()[0]
    return None if a.size == H.shape[1] else a


def _tri_solve_upper_t(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """R⁻ᵀ b for the upper Cholesky factor R in ``c`` (:func:`_chol_factor`; LAPACK trtrs, its lower
    triangle not read); ``b`` (a Fortran-ordered temporary) may be overwritten."""
    x, info = (_SCIPY or _scipy())[3](c, b, lower=0, trans=1, overwrite_b=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"trtrs: info {info}")
    return x


def _chol_factor(M: np.ndarray) -> np.ndarray:
    """Upper Cholesky factor of an SPD matrix: LAPACK potrf as ``scipy.linalg.cho_factor`` calls it,
    without its wrapper's per-call cost (the filter calls it twice an epoch)."""
    c, info = (_SCIPY or _scipy())[0](M, lower=0, clean=0)
    if info > 0:
        raise np.linalg.LinAlgError(f"{info}-th leading minor of the array is not positive definite")
    if info < 0:
        raise ValueError(f"potrf: illegal value in argument {-info}")
    return c


def _chol_solve(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """M⁻¹ b from the factor of :func:`_cho_factor` (LAPACK potrs, as ``scipy.linalg.cho_solve``)."""
    x, info = (_SCIPY or _scipy())[1](c, b, lower=0)
    if info != 0:
        raise ValueError(f"potrs: illegal value in argument {-info}")
    return x


#: :func:`iterated_update`'s linear algebra: LAPACK Cholesky factor, solves with it, M⁻¹ as its solve of I
LAPACK_CHOLESKY = (_chol_factor, _chol_solve, _chol_solve)
#: the same in numpy only: the factor is the inverse itself, a solve its product
NUMPY_INVERSE = (np.linalg.inv, lambda inv, b: inv @ b, lambda inv, eye: inv)


class _Whitened:
    """Rows already whitened (noise I) and linearized at x̄, as both the model and its rows of
    :func:`iterated_update`: z_w = ρ_w, h_w(x) = H_w (x − x̄)."""

    def __init__(self, rw: np.ndarray, Hw: np.ndarray, xbar: np.ndarray):
        self.z_m, self.Hw, self.xbar = rw, Hw, xbar

    def whiten(self, v):
        return v

    def predict(self, x, rows):
        return self.Hw @ (x - self.xbar), self.Hw


def _whiten(residual_m, H, sigma_m=None, noise_chol=None):
    """Whitened rows: (ρ/σ, H/σ) for a diagonal noise, (L⁻¹ρ, L⁻¹H) for R = L Lᵀ."""
    r = np.asarray(residual_m, dtype=float)
    H = np.asarray(H, dtype=float)
    if noise_chol is not None:
        L = np.asarray(noise_chol, dtype=float)
        solve_triangular = _scipy()[2]
        return solve_triangular(L, r, lower=True), solve_triangular(L, H, lower=True)
    s = np.broadcast_to(np.asarray(sigma_m, dtype=float), r.shape)
    return r / s, H / s[:, None]


def predict(x: np.ndarray, P: np.ndarray, A: np.ndarray, Q: np.ndarray, known_input=None):
    """x̄ = A x (+ known input), P̄ = A P Aᵀ + Q: :meth:`StepFilter.predict` as a function.

    Parameters
    ----------
    x : ndarray, shape (n,)
    P : ndarray, shape (n, n)
    A, Q : ndarray, shape (n, n)
        Transition and process-noise covariance over the step.
    known_input : ndarray, shape (n,), optional
        The state change due to known inputs over the step.
    """
    step = StepFilter(x, P)
    step.predict(A, Q, known_input)
    return step.x, step.P


def update(xb: np.ndarray, Pb: np.ndarray, residual_m, H, sigma_m=None, noise_chol=None):
    """The update of one epoch from rows linearized at x̄ (one step of :func:`iterated_update`).

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
    xb = np.asarray(xb, dtype=float)
    w = _Whitened(*_whiten(residual_m, H, sigma_m, noise_chol), xb)
    return iterated_update(w, w, xb, np.asarray(Pb, dtype=float), 1)


def positive_definite(P: np.ndarray) -> bool:
    """Whether ``P`` is finite and its symmetric part positive definite (its Cholesky factor exists): what a
    covariance must be, and what the covariance-form update can lose to rounding over a long record."""
    P = np.asarray(P, dtype=np.float64)
    if not np.all(np.isfinite(P)):
        return False
    try:
        np.linalg.cholesky(0.5 * (P + P.T))
    except np.linalg.LinAlgError:
        return False
    return True
