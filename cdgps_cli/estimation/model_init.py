"""Batch dynamic initialization over the engine's interfaces: Gauss–Newton over [x₁, w, b] on a
window of any :class:`~cdgps_cli.measurement.model.MeasurementModel` (full or diagonal noise) with a
:class:`~cdgps_cli.model.dynamics_models.Dynamics`, then the one integer-fixing policy.

The engine is the one batch initializer (:mod:`cdgps_cli.estimation.batch_init`, Teague, How &
Parkinson 1998 Sec. IV.A), which the structure path (:mod:`cdgps_cli.estimation.initializer`) runs
too: :class:`ModelProblem` is its thin wrapper for a measurement model (the rows, their prediction,
the whitening), the linearized problem being whitened per epoch by the rows' noise (so a full
covariance such as D Σ Dᵀ of double differences is handled exactly: each whitened row then mixes
several ambiguities, :class:`~cdgps_cli.estimation.batch_solver.LinearProblem` ``E``).  Integers:
:func:`~cdgps_cli.estimation.ambiguity.resolve` (LAMBDA, ratio, partial fixing: the one policy of every initializer), then the fixed
solution and its validation (:func:`~cdgps_cli.estimation.batch_init.fix_validation`).

With the modal dynamics and the satellite-DD model this is the paper's model-aided initialization on
GNSS double differences (used by :mod:`cdgps_cli.pipeline.gnss_modal`), there with a prior on the
first state (the stationary covariance of the modal process noise plus a broad start spread): a mode
at or above the data's Nyquist frequency is not seen by the window, its normal matrix is near-singular
in that direction, and without the prior the solution there is arbitrary (a 5 Hz mode on 10 Hz GNSS
came out at tens of m/s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.ambiguity import AmbiguityError, resolve
from cdgps_cli.estimation.batch_init import BatchProblem, InitOptions, fix_note_text, full_set_ratio

__all__ = ["ModelProblem", "ModelInitResult", "model_batch_init", "stationary_covariance"]


def stationary_covariance(A: np.ndarray, Q: np.ndarray) -> np.ndarray | None:
    """The stationary covariance P = A P Aᵀ + Q of x_{k+1} = A x_k + w_k, cov w = Q: the spread of a
    state driven by the process noise long enough to forget its start (units of x², (n, n)); None
    when the dynamics are not strictly stable (spectral radius ≥ 1: an undamped or rigid mode has no
    stationary spread)."""
    from scipy.linalg import solve_discrete_lyapunov  # noqa: PLC0415

    if A.size == 0 or np.max(np.abs(np.linalg.eigvals(A))) >= 1.0 - 1e-12:
        return None
    P = solve_discrete_lyapunov(A, Q)
    return 0.5 * (P + P.T)


class ModelProblem(BatchProblem):
    """The nonlinear batch problem of ``model`` on the regular window ``epochs`` (model epoch indices):
    the measurement model and its per-epoch whitening over the engine
    (:class:`~cdgps_cli.estimation.batch_init.BatchProblem`).

    Parameters
    ----------
    model : MeasurementModel
    dyn : Dynamics
    epochs : sequence of int
        Consecutive model epochs, spaced ``dt_s``.
    dt_s : float
        Epoch spacing, s.
    known_bias : ndarray (n_seg,), optional
        Per window segment (see ``columns``): the known bias (m), NaN = estimated.
    rows : list of Rows, optional
        The window's rows (default: ``model.rows(k)`` for k in ``epochs``).
    prior_cov : ndarray (n, n), optional
        Prior covariance of the first state about 0 (e.g. the dynamics' stationary covariance,
        :func:`stationary_covariance`): the regulariser of the directions the window does not see
        (a mode at or above the data's Nyquist frequency), which are otherwise arbitrary.
    """

    square_root = True

    def __init__(self, model, dyn, epochs, dt_s: float, known_bias=None, rows=None, prior_cov=None):
        self.model = model
        self.prior_info = None if prior_cov is None else np.linalg.inv(np.asarray(prior_cov, float))
        self.rows = [model.rows(k) for k in epochs] if rows is None else rows
        self.A, _, _ = dyn.transition(dt_s)
        self.G = dyn.noise_factor(dt_s)
        self.n = self.n_dyn = self.A.shape[0]
        N = len(self.rows)
        C = max([r.z_m.size for r in self.rows if r is not None], default=0)
        if C == 0:
            raise CdgpsError("batch initialization: no measurements in the window")
        cols = sorted({int(c) for r in self.rows if r is not None for c in r.segment if c >= 0})
        self.columns = cols                                 # window segment i = model segment column cols[i]
        local = {c: i for i, c in enumerate(cols)}
        z = np.full((N, C), np.nan)
        self.Linv = np.zeros((N, C, C))
        seg = np.full((N, C), -1, dtype=np.int64)           # window segment of each row
        var = []
        for k, r in enumerate(self.rows):
            self.Linv[k] = np.eye(C)
            if r is None:
                continue
            m = r.z_m.size
            z[k, :m] = r.z_m
            self.Linv[k, :m, :m] = r.whiten(np.eye(m))
            seg[k, :m] = [local[int(c)] if c >= 0 else -1 for c in r.segment]
            v = np.diag(r.covariance())
            var.append(v[r.segment >= 0] if np.any(r.segment >= 0) else v)
        self.present = np.isfinite(z)
        # scale of the damping prior: the rows with an ambiguity (phase), not e.g. pseudorange rows
        self.sigma = float(np.sqrt(np.mean(np.concatenate(var))))
        # the free biases solved about their window means (raw DDs carry λ·N of 1e5–1e6 m)
        self._set_biases(z, seg, len(cols), None if known_bias is None else np.asarray(known_bias, float), center=True)
        self.E = np.zeros((N, C, self.free.size))
        k, c = np.nonzero(self.bias_index >= 0)
        self.E[k, c, self.bias_index[k, c]] = 1.0

    def x1_cost(self, x: np.ndarray) -> float:
        """The prior's cost x₁ᵀ P⁻¹ x₁ (0 without a prior)."""
        return 0.0 if self.prior_info is None else float(x[0] @ self.prior_info @ x[0])

    def x1_prior(self, damp: float, x1_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The damping (square-root weight ``damp`` about ``x1_ref``) and the prior (about 0) as one
        Gaussian: information Λ = damp² I + P⁻¹, mean Λ⁻¹ damp² x1_ref, square root chol(Λ)ᵀ."""
        if self.prior_info is None:
            return super().x1_prior(damp, x1_ref)
        info = damp**2 * np.eye(self.n) + self.prior_info
        mean = np.linalg.solve(info, damp**2 * np.asarray(x1_ref, float))
        return mean, np.linalg.cholesky(0.5 * (info + info.T)).T

    def predict(self, x: np.ndarray, jacobian: bool = False):
        """h (N, C) and with ``jacobian`` H (N, C, n), zero on absent rows."""
        N, C = self.y.shape
        h = np.zeros((N, C))
        H = np.zeros((N, C, self.n))
        for k, r in enumerate(self.rows):
            if r is not None:
                hk, Hk = self.model.predict(x[k], r)
                h[k, :hk.size], H[k, :hk.size] = hk, Hk
        return (h, H) if jacobian else h

    def _white(self, v: np.ndarray) -> np.ndarray:
        return np.einsum("kij,kj...->ki...", self.Linv, v)

    def data_cost(self, r: np.ndarray) -> float:
        return np.sum(self._white(np.where(self.present, r, 0.0)) ** 2)

    def whiten(self, H: np.ndarray, ytil: np.ndarray):
        """Each epoch's rows whitened by its noise (a full covariance mixes the rows, hence their biases: E)."""
        yw = np.where(self.present, self._white(np.where(self.present, ytil, 0.0)), np.nan)
        return self._white(H), yw, self._white(self.E)


@dataclass
class ModelInitResult:
    """Outcome of :func:`model_batch_init` (biases in metres, per window segment)."""

    columns: list              # model segment column of each window segment
    float_bias_m: np.ndarray   # (n_seg,)
    float_sigma_m: np.ndarray  # (n_seg,)
    bias_m: np.ndarray         # (n_seg,) final (fixed where fixed)
    fixed: np.ndarray          # (n_seg,) bool
    integers: np.ndarray       # (n_seg,) int64 (rounded float where not fixed)
    ratio: float | None
    note: str
    x: np.ndarray              # (N, n) trajectory of the final solution
    P_end: np.ndarray | None   # (n, n) state covariance at the window end (posterior with ``prior_cov``)
    cost: float
    cost_per_dof: float
    iterations: int


def model_batch_init(model, dyn, epochs, dt_s: float, wavelength_m, opt: InitOptions | None = None,
                     x1: np.ndarray | None = None, max_bias_sigma_cycles: float | None = None,
                     prior_cov: np.ndarray | None = None) -> ModelInitResult:
    """Batch initialization of ``model`` on ``epochs``: float solution, integers, fixed solution.

    The biases are λ·(integer) (no line biases: double differences); ``wavelength_m`` is one λ (m)
    for every segment, or a function of the model's segment column giving each segment's λ (DDs of
    several frequencies: the integers of all of them are fixed as one full set, in cycles, with
    their float covariance scaled by 1/(λᵢλⱼ)).  One start (``x1``, default 0)
    — the modal amplitudes of a structure on GNSS are centimetres, well inside the basin of the
    linearization.  Refuses (CdgpsError) when the float solution does not converge, its information
    is singular, or (``max_bias_sigma_cycles`` given) a float bias has a larger σ.  Without that
    limit a weak direction (e.g. a rigid yaw offset nearly constant over the window, which moves
    every DD like a bias pattern) is left to LAMBDA: its ratio test decides, and the fix validation
    checks the fixed solution.  ``prior_cov`` (n, n): the first state's prior covariance about 0
    (:class:`ModelProblem`), in the float and the fixed solutions; ``P_end`` is then the posterior
    with that prior.
    """
    opt = opt or InitOptions()
    prob = ModelProblem(model, dyn, epochs, dt_s, prior_cov=prior_cov)
    x = prob.propagate(np.zeros(prob.n) if x1 is None else np.asarray(x1, float))
    g = prob.gauss_newton(x, prob.initial_biases(x), opt.max_iterations, opt)
    m, n = prob.free.size, prob.n
    if not g.converged:
        raise CdgpsError(f"batch initialization did not converge in {opt.max_iterations} iterations (cost {g.cost:.4g})")
    P = g.lin.P_end
    if P is None:
        raise CdgpsError("batch initialization: the ambiguities are not observable in the window (singular information)")
    Pbb = P[n:, n:]
    sig = np.sqrt(np.diag(Pbb))
    lam = np.array([wavelength_m(c) for c in prob.columns], float) if callable(wavelength_m) \
        else np.full(m, float(wavelength_m))
    if max_bias_sigma_cycles is not None and np.max(sig / lam, initial=0.0) > max_bias_sigma_cycles:
        raise CdgpsError(f"batch initialization: float ambiguity σ up to {np.max(sig / lam):.2f} cycle "
                         f"(limit {max_bias_sigma_cycles:g}): not observable in the window")
    b_float = prob.full_bias(g.b)
    a = b_float / lam
    integers = np.rint(a).astype(np.int64)
    fixed = np.zeros(m, dtype=bool)
    ratio, note = None, "integer fixing off"
    if opt.fix_integers and m:
        try:
            fx = resolve(a, 0.5 * (Pbb + Pbb.T) / np.outer(lam, lam), opt.ratio_threshold, partial=opt.partial)
            fixed, ratio = np.asarray(fx["fixed_mask"], dtype=bool), full_set_ratio(fx)
            integers = np.where(fixed, fx["integers"], integers)
            note = fix_note_text(fx, m, opt.ratio_threshold)
        except AmbiguityError as exc:
            note = f"integer fixing failed: {exc}"
    n_obs = int(prob.present.sum())
    res = ModelInitResult(prob.columns, b_float, sig, b_float.copy(), fixed, integers, ratio, note, g.x,
                          P[:n, :n], g.cost, g.cost / max(n_obs - n - m, 1), g.iterations)
    if fixed.any():
        known = np.where(fixed, lam * integers, np.nan)
        pf = ModelProblem(model, dyn, epochs, dt_s, known_bias=known, rows=prob.rows, prior_cov=prior_cov)
        gf, dJ, limit = pf.refit_fixed(g, b_float[~fixed] - pf.b_offset, opt, n_obs - n - m, int(fixed.sum()))
        if gf.converged and dJ <= limit:
            Pf = gf.lin.P_end
            res.bias_m, res.x, res.cost = pf.full_bias(gf.b), gf.x, gf.cost
            res.P_end = None if Pf is None else Pf[:n, :n]
            res.cost_per_dof = gf.cost / max(n_obs - n - int((~fixed).sum()), 1)
            res.iterations += gf.iterations
        else:
            res.note = f"integer fix rejected by validation (cost increase {dJ:.1f} > {limit:.1f}); float biases kept"
            res.fixed = np.zeros(m, dtype=bool)
    return res
