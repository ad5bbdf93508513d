"""The one batch initializer engine (Teague, How & Parkinson 1998 Sec. IV.A, Eq. 9–15): dynamic batch
least squares over a window — the state at the window start propagated by the dynamics, process
noise w, constant bias/ambiguity parameters b — by Gauss–Newton with Levenberg–Marquardt step
control, each step solved in O(N) by :func:`~cdgps_cli.estimation.batch_solver.srif_solve`; then the
fix validation of the integers.

:class:`BatchProblem` holds everything but the measurement model: the bias bookkeeping (one
parameter per window segment, known ones moved into the data, free ones optionally solved about
their window mean), the residual, cost, trajectory propagation, linearized problem and its solve.
A thin problem-specific wrapper supplies the measurement model and its whitening:

* :class:`cdgps_cli.estimation.initializer._Problem` — the pseudolite testbed and the far-field
  structure (the compiled phase model, per-channel σ, Gauss–Markov multipath states);
* :class:`cdgps_cli.estimation.model_init.ModelProblem` — any
  :class:`~cdgps_cli.measurement.model.MeasurementModel` (full per-epoch noise, e.g. GNSS double
  differences on the modal state).

:class:`GaussNewton` runs on either, one iteration per call (the cold start races several runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cdgps_cli.config.options import INIT_MAX_ITERATIONS, INIT_STARTS, RATIO_THRESHOLD
from cdgps_cli.estimation.batch_solver import LinearProblem, LinearSolution, srif_solve
from cdgps_cli.estimation.chi2 import chi2_quantile

__all__ = ["InitOptions", "BatchProblem", "GaussNewton", "GNResult", "LinearSolutionView", "fix_validation",
           "fix_note_text", "full_set_ratio"]


@dataclass
class InitOptions:
    """Options of the batch initialization (all echoed in INIT.json): the engine's (iterations,
    convergence, integer fixing and its validation) and the pseudolite/far-field window's
    (:func:`cdgps_cli.estimation.initializer.initialize`: window, starts, noise, multipath)."""

    start_s: float | None = None        # window start (default: automatic)
    duration_s: float | None = None     # window length (default: automatic, up to 60 s)
    process_noise: bool = True          # False: the 1995 variant (no process noise)
    fix_integers: bool = True           # LAMBDA + ratio test when line biases are calibrated
    ratio_threshold: float = RATIO_THRESHOLD
    partial: bool = True                # partial fixing when the full set fails
    starts: int = INIT_STARTS                     # initial guesses of the rigid angle (or lowest mode)
    start_iterations: int = 3           # Gauss–Newton iterations per start before choosing
    start_window_s: float = 10.0        # starts are compared on this first part of the window
    finalists: int = 3                  # best starts continued on the whole window
    fix_validation_probability: float = 0.999  # chi-square test of the cost increase caused by fixing
    fix_validation_margin: float = 10.0  # … times this margin for model error (e.g. no process noise)
    max_iterations: int = INIT_MAX_ITERATIONS
    step_tol_m: float = 1e-5            # convergence: max bias / position step (m)
    cost_rtol: float = 1e-9             # convergence: relative cost change
    sigma_m: float | None = None        # measurement noise for every channel (default: config, then estimated)
    estimate_sigma: bool = True         # per-channel σ from the batch's variance factors (off with sigma_m)
    sigma_refuse_ratio: float = 4.0     # refuse when one channel's σ̂ exceeds the others' median this many times
    max_bias_sigma_cycles: float = 0.25  # observability limit on the float biases' sigma
    min_motion_ratio: float = 2.0       # automatic window: phase motion RMS / noise
    multipath_sigma_m: float | None = None        # Gauss–Markov multipath σ (default: config; 0 = off)
    multipath_time_constant_s: float | None = None  # … and its time constant (default: config)
    progress: object = None             # callable(str) for progress messages

    def echo(self) -> dict:
        # the multipath overrides are echoed only when given (INIT.json without them is unchanged)
        return {k: v for k, v in self.__dict__.items()
                if k != "progress" and not (k.startswith("multipath_") and v is None)}


@dataclass
class GNResult:
    """A Gauss–Newton run's outcome: trajectory x (N, n), free biases b (m,), process noise w (N−1, r),
    cost, iterations, convergence, the linear solution at the end (``lin``: information at the window
    end) and the cost history."""

    x: np.ndarray
    b: np.ndarray
    w: np.ndarray
    cost: float
    iterations: int
    converged: bool
    lin: object = None
    history: list = field(default_factory=list)


class BatchProblem:
    """The nonlinear batch problem on a window of N epochs and C measurement rows per epoch, less its
    measurement model.

    A subclass sets the dynamics ``A`` (n, n), ``G`` (n, r) (x_{k+1} = A x_k + G w_k, w white of unit
    variance), ``n`` and ``n_dyn`` (the states the measurement model sees first; extra states such
    as multipath follow), ``sigma`` (m, the scale of the damping prior), calls :meth:`_set_biases`
    and supplies

    * ``predict(x, jacobian=False)``: h (N, C), and with ``jacobian`` H (N, C, n), of the trajectory x (N, n);
    * ``data_cost(r)``: the whitened squared norm of the residuals r (N, C, NaN where absent);
    * ``whiten(H, ytil)``: the linearized rows whitened, (H_w, y_w (NaN where absent), E_w or None);
      E_w (N, C, m): the whitened bias incidence when whitening mixes rows, else None (each row
      then touches the one bias of ``bias_index``).

    Optional: ``bias_scale`` (m,) — the free biases solved in these units (b' = b / scale, e.g. the
    channel's σ when each row is divided by it), None for metres; ``square_root`` — srif_solve's form
    (None: automatic); ``x1_cost``/``x1_prior`` for states with a prior of their own.
    """

    bias_scale: np.ndarray | None = None
    square_root: bool | None = None
    b_offset: np.ndarray | None = None

    def predict(self, x: np.ndarray, jacobian: bool = False):  # pragma: no cover - interface
        raise NotImplementedError

    def data_cost(self, r: np.ndarray) -> float:  # pragma: no cover - interface
        raise NotImplementedError

    def whiten(self, H: np.ndarray, ytil: np.ndarray):  # pragma: no cover - interface
        raise NotImplementedError

    def _set_biases(self, z: np.ndarray, segment: np.ndarray, n_seg: int, known=None, center: bool = False) -> None:
        """The bias bookkeeping: ``z`` (N, C) data (m, NaN absent), ``segment`` (N, C) window bias
        segment of each row (−1: no bias), ``n_seg`` segments, ``known`` (n_seg,) the known biases
        (m, NaN: free) or None (all free).

        Sets ``known``, ``free`` (indices of the free segments), ``bias_index`` (N, C: the free
        parameter of each row, −1 none) and ``y`` = z − known biases.  With ``center`` each free bias is
        solved about the window mean of its rows (``b_offset``, m, removed from y): raw double
        differences carry λ·N of 1e5–1e6 m, whose cancellation in every cost evaluation would
        leave a rounding noise above Gauss–Newton's acceptance tolerance near the minimum."""
        self.known = np.full(n_seg, np.nan) if known is None else known
        self.free = np.flatnonzero(np.isnan(self.known))
        remap = np.full(n_seg + 1, -1, dtype=np.int64)
        remap[self.free] = np.arange(self.free.size)
        self.bias_index = np.where(segment >= 0, remap[segment], -1)
        kb = np.where(segment >= 0, np.nan_to_num(self.known, nan=0.0)[np.maximum(segment, 0)], 0.0)
        self.y = z - kb
        if center:
            ok = np.isfinite(z) & (self.bias_index >= 0)
            cnt = np.bincount(self.bias_index[ok], minlength=self.free.size)
            tot = np.bincount(self.bias_index[ok], weights=self.y[ok], minlength=self.free.size)
            self.b_offset = np.where(cnt > 0, tot / np.maximum(cnt, 1), 0.0)
            self.y = self.y - np.append(self.b_offset, 0.0)[self.bias_index]    # (index −1: no bias → 0)

    def full_bias(self, b_free: np.ndarray) -> np.ndarray:
        """Every window segment's bias, m: the known ones, and the free ``b_free`` (about ``b_offset``)."""
        out = self.known.copy()
        out[self.free] = b_free if self.b_offset is None else self.b_offset + b_free
        return out

    def residual(self, x: np.ndarray, b_free: np.ndarray) -> np.ndarray:
        """y − h(x) − b of each row's bias, m (N, C); NaN on absent rows."""
        h = self.predict(x)
        bb = np.where(self.bias_index >= 0, b_free[np.maximum(self.bias_index, 0)] if b_free.size else 0.0, 0.0)
        return self.y - h - bb

    def cost(self, x: np.ndarray, b_free: np.ndarray, w: np.ndarray) -> float:
        """The nonlinear cost: whitened residuals, process noise and the states' own prior."""
        return float(self.data_cost(self.residual(x, b_free)) + np.sum(w**2)) + self.x1_cost(x)

    def x1_cost(self, x: np.ndarray) -> float:
        return 0.0

    def x1_prior(self, damp: float, x1_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Prior on the first state: the damping (square-root weight ``damp`` about ``x1_ref``)."""
        return np.array(x1_ref, dtype=float), np.diag(np.full(self.n, damp))

    def propagate(self, x1: np.ndarray) -> np.ndarray:
        """The trajectory (N, n) from x1 without process noise (states beyond len(x1): 0 at the start)."""
        xs = np.empty((len(self.y), self.n))
        xs[0] = 0.0
        xs[0, :len(x1)] = x1
        for k in range(1, len(xs)):
            xs[k] = self.A @ xs[k - 1]
        return xs

    def initial_biases(self, x: np.ndarray) -> np.ndarray:
        """Bias guess per free parameter: mean residual of its rows along trajectory x."""
        r = self.y - self.predict(x)
        ok = np.isfinite(r) & (self.bias_index >= 0)
        m = self.free.size
        total = np.bincount(self.bias_index[ok], weights=r[ok], minlength=m)
        count = np.bincount(self.bias_index[ok], minlength=m)
        return np.where(count > 0, total / np.maximum(count, 1), 0.0)

    def linear_problem(self, x: np.ndarray, damp_x1: float, x1_ref, damp_b: float, b_ref) -> LinearProblem:
        """The problem linearized about trajectory x, whitened (σ = 1), with the damping priors
        (square-root weights ``damp_x1`` about ``x1_ref``, ``damp_b`` about ``b_ref``)."""
        h, H = self.predict(x, jacobian=True)
        ytil = self.y - h + np.einsum("nci,ni->nc", H, x)
        Hw, yw, Ew = self.whiten(H, ytil)
        m = self.free.size
        x1_mean, x1_info = self.x1_prior(damp_x1, x1_ref)
        if self.bias_scale is None:
            b_mean, b_info = np.asarray(b_ref, dtype=float), np.eye(m) * damp_b
        else:
            b_mean = np.asarray(b_ref, dtype=float) / self.bias_scale
            b_info = np.diag(np.full(m, damp_b) * self.bias_scale)
        return LinearProblem(A=self.A, Bw_L=self.G, H=Hw, y=yw, bias_index=self.bias_index, n_bias=m, sigma_m=1.0,
                             x1_mean=x1_mean, x1_sqrt_info=x1_info, b_mean=b_mean, b_sqrt_info=b_info, E=Ew)

    def solve(self, lp: LinearProblem) -> LinearSolution:
        """:func:`srif_solve` on the whitened problem, biases and their information back in metres."""
        sol = srif_solve(lp, square_root=self.square_root)
        fs = self.bias_scale
        if fs is None or not fs.size:
            return sol
        d = np.r_[np.ones(self.n), fs]
        P = None if sol.P_end is None else sol.P_end * d[:, None] * d[None, :]
        return LinearSolution(sol.x, sol.w, sol.b * fs, sol.cost, sol.R_end / d[None, :], P, sol.rank_deficient)

    def gauss_newton(self, x_init: np.ndarray, b_init: np.ndarray, max_iter: int, opt: InitOptions,
                     w_init: np.ndarray | None = None, max_retries: int = 12, information: bool = True) -> GNResult:
        """Gauss–Newton with Levenberg–Marquardt step control on x₁ and b (see :class:`GaussNewton`).

        ``information=False``: the result's ``lin`` (information at the window end) is not needed,
        so it is not recomputed at the last iterate (None unless the run converged undamped)."""
        gn = GaussNewton(self, x_init, b_init, max_iter, opt, w_init=w_init, max_retries=max_retries)
        while gn.step():
            pass
        return gn.result(information)

    def refit_fixed(self, g: GNResult, b_init: np.ndarray, opt: InitOptions, dof_float: int, n_fixed: int):
        """This problem (the fixed biases known) solved from the float solution ``g``, and its fix
        validation against it: (result, ΔJ, limit) (:func:`fix_validation`)."""
        gf = self.gauss_newton(g.x, b_init, opt.max_iterations, opt, w_init=g.w)
        dJ, limit = fix_validation(g.cost, gf.cost, dof_float, n_fixed, opt)
        return gf, dJ, limit


def _largest_change(lin, x: np.ndarray, b: np.ndarray) -> float:
    """Largest change of a bias or of a state (m) from (x, b) to the linear solution ``lin``."""
    return max(np.max(np.abs(lin.b - b), initial=0.0), np.max(np.abs(lin.x - x), initial=0.0))


class GaussNewton:
    """Gauss–Newton on a :class:`BatchProblem`, one iteration per :meth:`step` (so that several runs can
    be advanced in turn), with Levenberg–Marquardt step control on x₁ and b.

    Each iteration first tries the step with the damping reduced tenfold (undamped once it is
    small), backtracking along it (α = 1, ½, ¼, 1/10) before a step that raises the nonlinear cost
    is retried with ten times more damping.  Converged when the step (largest change of a bias or
    of a state) is below ``step_tol_m``, when the cost changes by less than ``cost_rtol`` without
    damping, or when two successive full undamped steps contract so fast (ratio r ≤ ½) that the
    steps still to come, about r/(1 − r) × the last one, are below ``step_tol_m``; also converged
    when every trial raises the cost but the first proposed step is already below ``step_tol_m``
    (the rise is then rounding in a cost at its minimum, not a failure).
    """

    def __init__(self, prob: "BatchProblem", x_init: np.ndarray, b_init: np.ndarray, max_iter: int, opt: InitOptions,
                 w_init: np.ndarray | None = None, max_retries: int = 12):
        self.prob, self.opt = prob, opt
        self.max_iter, self.max_retries = max_iter, max_retries
        self.x, self.b = x_init, b_init
        self.w = np.zeros((len(x_init) - 1, prob.G.shape[1])) if w_init is None else w_init
        self.J = prob.cost(self.x, self.b, self.w)
        self.lam = 0.0
        self.hist = [self.J]
        self.converged = False
        self.lin = None
        self.it = 0
        self.done = False
        self.last = None              # last iteration: (cost decrease, predicted decrease, full undamped step)
        self._prev_full_step = None

    def step(self) -> bool:
        """One iteration; False once finished (converged, failed, or out of iterations)."""
        if self.done or self.it >= self.max_iter:
            self.done = True
            return False
        prob, opt = self.prob, self.opt
        x, b, w, J = self.x, self.b, self.w, self.J
        self.it += 1
        accepted = False
        first_step = None
        for _ in range(self.max_retries):
            sw = self.lam / prob.sigma          # square-root weight of the damping prior
            lin = prob.solve(prob.linear_problem(x, sw, x[0], sw, b))
            self.lin = lin
            if first_step is None:
                first_step = _largest_change(lin, x, b)
            # backtracking along the Gauss–Newton step before adding damping
            for alpha in (1.0, 0.5, 0.25, 0.1):
                xt = x + alpha * (lin.x - x)
                bt = b + alpha * (lin.b - b)
                wt = w + alpha * (lin.w - w)
                Jn = prob.cost(xt, bt, wt)
                if np.isfinite(Jn) and Jn <= J * (1 + 1e-12):
                    accepted = True
                    break
            if accepted:
                break
            self.lam = max(self.lam * 10.0, 1e-2)
        if not accepted:
            # every trial raised the cost; if the first proposed step was already below the step
            # tolerance, that rise is rounding in the cost at its minimum: converged where we stand
            self.converged = bool(first_step is not None and first_step < opt.step_tol_m)
            self.done = True
            return False
        full = alpha == 1.0 and sw == 0.0
        self.last = (J - Jn, J - lin.cost, full)
        if alpha != 1.0:
            lin = self.lin = LinearSolutionView(xt, wt, bt, lin)
        step = _largest_change(lin, x, b)
        rel = (J - Jn) / max(J, 1e-300)
        self.x, self.b, self.w, self.J = lin.x, lin.b, lin.w, Jn
        self.hist.append(Jn)
        self.lam = self.lam / 10.0 if self.lam > 1e-2 else 0.0
        prev, self._prev_full_step = self._prev_full_step, (step if full else None)
        ratio = step / prev if (full and prev) else 1.0
        if step < opt.step_tol_m or (rel < opt.cost_rtol and self.lam == 0.0) or \
                (ratio <= 0.5 and step * ratio / (1.0 - ratio) < opt.step_tol_m):
            self.converged = True
            self.done = True
        elif self.it >= self.max_iter:
            self.done = True
        return not self.done

    def settled(self) -> bool:
        """The last iteration was a full undamped step whose cost decrease matched the linearized
        model's prediction (within a factor 2): the run is in the quadratic region of its minimum."""
        if self.last is None:
            return False
        dJ, pred, full = self.last
        return full and pred > 0 and 0.5 <= dJ / pred <= 2.0

    def result(self, information: bool = True) -> GNResult:
        prob = self.prob
        if self.lin is None or self.lam != 0.0 or not self.converged:
            self.lin = prob.solve(prob.linear_problem(self.x, 0.0, self.x[0], 0.0, self.b)) if information else None
        return GNResult(self.x, self.b, self.w, self.J, self.it, self.converged, self.lin, self.hist)


class LinearSolutionView:
    """A partial (line-search) step: trajectory and biases replaced, information kept."""

    def __init__(self, x, w, b, base):
        self.x, self.w, self.b = x, w, b
        self.cost, self.R_end, self.P_end, self.rank_deficient = base.cost, base.R_end, base.P_end, base.rank_deficient


def full_set_ratio(fx: dict) -> float | None:
    """The full set's ratio of a :func:`~cdgps_cli.estimation.ambiguity.resolve` result (None when not computed)."""
    r = fx["ratio_full_set"]
    return None if r is None or math.isnan(r) else float(r)


def fix_note_text(fx: dict, m: int, threshold: float) -> str:
    """INIT.json's ``integer_fixing`` sentence for a :func:`~cdgps_cli.estimation.ambiguity.resolve` result."""
    ratio, fixed = full_set_ratio(fx), np.asarray(fx["fixed_mask"], dtype=bool)
    rtxt = "n/a" if ratio is None else f"{ratio:.2f}"
    if fixed.all():
        return f"all {m} integers fixed (ratio {rtxt} ≥ {threshold:g})"
    if fixed.any():
        return f"{int(fixed.sum())} of {m} integers fixed by partial fixing (full-set ratio {rtxt})"
    return fx.get("limit_message") or f"integers not fixed: ratio {rtxt} < {threshold:g}"


def fix_validation(cost_float: float, cost_fixed: float, dof_float: int, n_fixed: int, opt) -> tuple[float, float]:
    """(ΔJ, limit) of the fix validation: with the right integers the cost rises by about a
    chi-square(n_fixed) amount, scaled by the float solution's cost per degree of freedom; the fix is
    rejected when ΔJ > limit = ``fix_validation_margin`` × χ²_p(n_fixed), p = ``fix_validation_probability``."""
    scale = max(cost_float / max(dof_float, 1), 1e-12)
    limit = opt.fix_validation_margin * float(chi2_quantile(opt.fix_validation_probability, n_fixed))
    return (cost_fixed - cost_float) / scale, limit

