"""Bias initialization (``cdgps init``): iterated batch dynamic least squares + integer fixing.

Flow (Teague, How & Parkinson 1998 Sec. IV.A; Teague et al. 1995 batch estimator):

1. Pick a window of epochs recorded while the structure moves (automatic by default: the first
   window whose phase motion is well above the noise).
2. Give every channel one bias parameter per lock segment (a slip or re-lock inside the window
   starts a new segment, so the window is split at the slip rather than corrupted by it).
3. For several initial guesses of the large rigid-body angle (cold start), iterate Gauss–Newton:
   linearize h about the current trajectory, solve the linear batch problem of Eq. (13)–(15) in
   O(N) with :func:`cdgps_cli.batch.srif_solve`, accept the step if the nonlinear cost decreases
   (Levenberg–Marquardt damping on x₁ and b otherwise).  The start with the lowest cost wins.
4. If line biases are calibrated, fix b = line bias + λ·n with LAMBDA and the ratio test (partial
   fixing of a subset if the whole set fails), then re-solve the states with the integers fixed.
5. Report the biases, the filter's initial state and covariance at the window end, residuals.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np

from scipy.stats import chi2

from .ambiguity import lambda_search, partial_fix, ratio_test
from .batch import LinearProblem, srif_solve
from .config import StructureConfig
from .dynamics import discrete_model
from .errors import CdgpsError
from .measurement import channel_indices, phase_model
from .run import Run


@dataclass
class InitOptions:
    """Options of :func:`initialize` (all echoed in INIT.json)."""

    start_s: float | None = None        # window start (default: automatic)
    duration_s: float | None = None     # window length (default: automatic, up to 60 s)
    process_noise: bool = True          # False: the 1995 variant (no process noise)
    fix_integers: bool = True           # LAMBDA + ratio test when line biases are calibrated
    ratio_threshold: float = 3.0
    partial: bool = True                # partial fixing when the full set fails
    starts: int = 8                     # initial guesses of the rigid angle (or lowest mode)
    start_iterations: int = 3           # Gauss–Newton iterations per start before choosing
    start_window_s: float = 10.0        # starts are compared on this first part of the window
    finalists: int = 3                  # best starts continued on the whole window
    fix_validation_probability: float = 0.999  # chi-square test of the cost increase caused by fixing
    fix_validation_margin: float = 10.0  # … times this margin for model error (e.g. no process noise)
    max_iterations: int = 30
    step_tol_m: float = 1e-5            # convergence: max bias / position step (m)
    cost_rtol: float = 1e-9             # convergence: relative cost change
    sigma_m: float | None = None        # measurement noise (default: config)
    max_bias_sigma_cycles: float = 0.25  # observability limit on the float biases' sigma
    min_motion_ratio: float = 2.0       # automatic window: phase motion RMS / noise
    progress: object = None             # callable(str) for progress messages

    def echo(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "progress"}


@dataclass
class WindowData:
    time_s: np.ndarray          # (N,) regular grid
    y_m: np.ndarray             # (N, C) λ·phase, NaN where absent
    channels: list              # [(antenna, transmitter)]
    ant: np.ndarray
    tx: np.ndarray
    segment: np.ndarray         # (N, C) bias parameter index, -1 where absent
    segments: list              # per parameter: dict(antenna, transmitter, start_s, end_s, channel)


def _say(opt: InitOptions, msg: str) -> None:
    if opt.progress:
        opt.progress(msg)


def phase_matrix(run: Run, t0: float, t1: float):
    """Epoch grid and (N, C) matrices of phase (metres) and lock over [t0, t1]."""
    cfg = run.cfg
    T = cfg.sample_period_s
    ph = run.phase
    sel = ph[(ph["time_s"] >= t0 - 1e-9) & (ph["time_s"] <= t1 + 1e-9)]
    if len(sel) == 0:
        raise CdgpsError(f"{run.path}: no phase data between {t0:g} s and {t1:g} s")
    tmin, tmax = sel["time_s"].min(), sel["time_s"].max()
    n = int(round((tmax - tmin) / T)) + 1
    grid = tmin + np.arange(n) * T
    k = np.rint((sel["time_s"].to_numpy() - tmin) / T).astype(int)
    chans = sorted(set(zip(sel["antenna"], sel["transmitter"])),
                   key=lambda c: (cfg.antenna_names.index(c[0]), cfg.transmitter_names.index(c[1])))
    cidx = {c: i for i, c in enumerate(chans)}
    ci = np.array([cidx[c] for c in zip(sel["antenna"], sel["transmitter"])])
    y = np.full((n, len(chans)), np.nan)
    lock = np.full((n, len(chans)), -1, dtype=np.int64)
    y[k, ci] = sel["phase_cycles"].to_numpy() * cfg.wavelength_m
    lock[k, ci] = sel["lock"].to_numpy()
    return grid, y, lock, chans


def window_data(run: Run, t0: float, t1: float) -> WindowData:
    grid, y, lock, chans = phase_matrix(run, t0, t1)
    n, C = y.shape
    seg = np.full((n, C), -1, dtype=np.int64)
    segments = []
    for c in range(C):
        present = ~np.isnan(y[:, c])
        current = -1
        prev_present = False
        prev_lock = -1
        for k in np.flatnonzero(present):
            new = (current < 0) or (lock[k, c] == 0) or (lock[k, c] < prev_lock) or \
                (not present[k - 1] and lock[k, c] != prev_lock + (k - last_k))
            if new:
                current = len(segments)
                segments.append({"antenna": chans[c][0], "transmitter": chans[c][1], "channel": c,
                                 "start_s": float(grid[k]), "end_s": float(grid[k])})
            segments[current]["end_s"] = float(grid[k])
            seg[k, c] = current
            prev_lock = lock[k, c]
            last_k = k
            prev_present = True
        del prev_present
    ant, tx = channel_indices(run.cfg, [c[0] for c in chans], [c[1] for c in chans])
    return WindowData(grid, y, chans, ant, tx, seg, segments)


def motion_rms_m(y: np.ndarray, segment: np.ndarray) -> float:
    """RMS over channels of the standard deviation of the phase within each lock segment (m)."""
    vals = []
    for s in np.unique(segment[segment >= 0]):
        v = y[segment == s]
        if v.size > 2:
            vals.append(np.var(v))
    return float(np.sqrt(np.mean(vals))) if vals else 0.0


def choose_window(run: Run, opt: InitOptions, sigma_m: float) -> tuple[float, float, str]:
    """Window [t0, t1] for initialization; automatic: first 60 s span with enough motion."""
    ph_t = run.phase["time_s"].to_numpy()
    first, last = float(ph_t[0]), float(ph_t[-1])
    if opt.start_s is not None or opt.duration_s is not None:
        t0 = first if opt.start_s is None else float(opt.start_s)
        dur = 60.0 if opt.duration_s is None else float(opt.duration_s)
        if dur <= 0:
            raise CdgpsError(f"--duration must be positive, got {dur:g}")
        if t0 < first - 1e-9 or t0 > last:
            raise CdgpsError(f"--start {t0:g} s is outside the recording ({first:g}–{last:g} s)")
        return t0, min(t0 + dur, last), "given"
    dur = min(60.0, last - first)
    step = max(dur / 2, 10.0)
    t0 = first
    while t0 + dur <= last + 1e-9:
        wd = window_data(run, t0, t0 + dur)
        if motion_rms_m(wd.y_m, wd.segment) >= opt.min_motion_ratio * sigma_m:
            return t0, t0 + dur, "automatic"
        t0 += step
    return first, first + dur, "automatic (no window with enough motion found; using the first)"


@dataclass
class GNResult:
    x: np.ndarray
    b: np.ndarray
    w: np.ndarray
    cost: float
    iterations: int
    converged: bool
    lin: object = None
    history: list = field(default_factory=list)


class _Problem:
    """Nonlinear batch problem on a window (model, data, bias parametrization)."""

    def __init__(self, cfg: StructureConfig, wd: WindowData, sigma_m: float, process_noise: bool,
                 known_bias: np.ndarray | None = None):
        self.cfg = cfg
        self.wd = wd
        self.sigma = sigma_m
        model = discrete_model(cfg)
        self.A = model.A
        L = np.sqrt(np.diag(model.W))
        G = model.Bw * L
        keep = L > 0
        self.G = G[:, keep] if process_noise else np.zeros((model.A.shape[0], 0))
        self.n = model.A.shape[0]
        # bias parametrization: fixed values (known_bias[s] finite) are moved into y
        nseg = len(wd.segments)
        self.known = np.full(nseg, np.nan) if known_bias is None else known_bias
        free = np.flatnonzero(np.isnan(self.known))
        self.free = free
        remap = np.full(nseg + 1, -1, dtype=np.int64)
        remap[free] = np.arange(free.size)
        self.bias_index = np.where(wd.segment >= 0, remap[wd.segment], -1)
        kb = np.where(wd.segment >= 0, np.nan_to_num(self.known, nan=0.0)[np.maximum(wd.segment, 0)], 0.0)
        self.y = wd.y_m - kb                     # measurement minus known biases

    def full_bias(self, b_free: np.ndarray) -> np.ndarray:
        out = self.known.copy()
        out[self.free] = b_free
        return out

    def predict(self, x: np.ndarray, jacobian: bool = False):
        return phase_model(self.cfg, x, self.wd.ant, self.wd.tx, jacobian=jacobian)

    def residual(self, x: np.ndarray, b_free: np.ndarray) -> np.ndarray:
        h = self.predict(x)
        bb = np.where(self.bias_index >= 0, b_free[np.maximum(self.bias_index, 0)] if b_free.size else 0.0, 0.0)
        return self.y - h - bb

    def cost(self, x, b_free, w) -> float:
        r = self.residual(x, b_free)
        return float(np.nansum(r**2) / self.sigma**2 + np.sum(w**2))

    def propagate(self, x1: np.ndarray) -> np.ndarray:
        N = len(self.wd.time_s)
        xs = np.empty((N, self.n))
        xs[0] = x1
        for k in range(1, N):
            xs[k] = self.A @ xs[k - 1]
        return xs

    def linear_problem(self, x: np.ndarray, damp_x1: float, x1_ref, damp_b: float, b_ref) -> LinearProblem:
        h, H = self.predict(x, jacobian=True)
        ytil = self.y - h + np.einsum("nci,ni->nc", H, x)
        m = self.free.size
        return LinearProblem(
            A=self.A, Bw_L=self.G, H=H, y=ytil, bias_index=self.bias_index, n_bias=m, sigma_m=self.sigma,
            x1_mean=x1_ref, x1_sqrt_info=np.eye(self.n) * damp_x1,
            b_mean=b_ref, b_sqrt_info=np.eye(m) * damp_b)

    def initial_biases(self, x: np.ndarray) -> np.ndarray:
        """Bias guess per free parameter: mean residual of its segment along trajectory x."""
        r = self.y - self.predict(x)
        out = np.zeros(self.free.size)
        for j in range(self.free.size):
            sel = self.bias_index == j
            out[j] = np.nanmean(r[sel]) if np.isfinite(r[sel]).any() else 0.0
        return out

    def gauss_newton(self, x_init: np.ndarray, b_init: np.ndarray, max_iter: int, opt: InitOptions,
                     w_init: np.ndarray | None = None, max_retries: int = 12) -> GNResult:
        """Gauss–Newton with Levenberg–Marquardt step control on x₁ and b.

        Each iteration first tries the step with the damping reduced tenfold (undamped once it is
        small); a step that raises the nonlinear cost is retried with ten times more damping.
        """
        x, b = x_init, b_init
        w = np.zeros((len(x) - 1, self.G.shape[1])) if w_init is None else w_init
        J = self.cost(x, b, w)
        lam = 0.0
        hist = [J]
        converged = False
        lin = None
        it = 0
        for it in range(1, max_iter + 1):
            accepted = False
            for _ in range(max_retries):
                sw = lam / self.sigma          # square-root weight of the damping prior
                lin = srif_solve(self.linear_problem(x, sw, x[0], sw, b))
                # backtracking along the Gauss–Newton step before adding damping
                for alpha in (1.0, 0.5, 0.25, 0.1):
                    xt = x + alpha * (lin.x - x)
                    bt = b + alpha * (lin.b - b)
                    wt = w + alpha * (lin.w - w)
                    Jn = self.cost(xt, bt, wt)
                    if np.isfinite(Jn) and Jn <= J * (1 + 1e-12):
                        accepted = True
                        break
                if accepted:
                    break
                lam = max(lam * 10.0, 1e-2)
            if not accepted:
                break
            if alpha != 1.0:
                lin = LinearSolutionView(xt, wt, bt, lin)
            step = max(np.max(np.abs(lin.b - b), initial=0.0), np.max(np.abs(lin.x - x), initial=0.0))
            rel = (J - Jn) / max(J, 1e-300)
            x, b, w, J = lin.x, lin.b, lin.w, Jn
            hist.append(J)
            lam = lam / 10.0 if lam > 1e-2 else 0.0
            if step < opt.step_tol_m or (rel < opt.cost_rtol and lam == 0.0):
                converged = True
                break
        if lin is None or lam != 0.0 or not converged:
            lin = srif_solve(self.linear_problem(x, 0.0, x[0], 0.0, b))
        return GNResult(x, b, w, J, it, converged, lin, hist)


class LinearSolutionView:
    """A partial (line-search) step: trajectory and biases replaced, information kept."""

    def __init__(self, x, w, b, base):
        self.x, self.w, self.b = x, w, b
        self.cost, self.R_end, self.P_end, self.rank_deficient = base.cost, base.R_end, base.P_end, base.rank_deficient


def _start_guesses(cfg: StructureConfig, n_starts: int) -> list[tuple[str, np.ndarray]]:
    """Initial modal states: rigid angle spread over the circle, or ± lowest-mode amplitudes."""
    nm = cfg.n_modes
    U = np.asarray(cfg.mode_shapes)
    rigid = np.flatnonzero(np.asarray(cfg.mode_frequency_hz) == 0.0)
    starts = []
    if rigid.size and cfg.rigid_index is not None and n_starts > 1:
        j = rigid[0]
        for a in np.linspace(-np.pi, np.pi, n_starts, endpoint=False):
            x = np.zeros(2 * nm)
            x[j] = a / U[cfg.rigid_index, j]
            starts.append((f"rigid angle {math.degrees(a):+.0f} deg", x))
        return starts
    starts.append(("zero state", np.zeros(2 * nm)))
    if n_starts > 1:
        amps = np.linspace(-0.6, 0.6, n_starts - 1 if (n_starts - 1) % 2 == 0 else n_starts)
        amps = amps[amps != 0][: n_starts - 1]
        for a in amps:
            x = np.zeros(2 * nm)
            qmax = np.max(np.abs(U[:, 0])) or 1.0
            x[0] = a / qmax
            starts.append((f"mode {cfg.mode_names[0]} amplitude {a:+.2f}", x))
    return starts


def initialize(run: Run, opt: InitOptions | None = None, return_trajectory: bool = False):
    """Estimate channel biases and the filter's initial state from a window of a RUN.

    Returns the INIT.json dictionary (see the README); with ``return_trajectory`` also
    ``{"time_s", "x"}``, the smoothed batch trajectory over the window.  Raises :class:`CdgpsError` when the window
    does not make the biases observable or Gauss–Newton does not converge.
    """
    opt = opt or InitOptions()
    cfg = run.cfg
    t_start = _time.perf_counter()
    if opt.sigma_m is not None and not (np.isfinite(opt.sigma_m) and opt.sigma_m > 0):
        raise CdgpsError(f"--sigma-m must be a positive number of metres, got {opt.sigma_m!r}")
    sigma = opt.sigma_m if opt.sigma_m is not None else cfg.measurement_sigma_m
    if opt.ratio_threshold <= 1.0:
        raise CdgpsError(f"--ratio must be greater than 1, got {opt.ratio_threshold:g}")
    if opt.starts < 1 or opt.max_iterations < 1:
        raise CdgpsError("--starts and --max-iterations must be at least 1")
    t0, t1, how = choose_window(run, opt, sigma)
    wd = window_data(run, t0, t1)
    N = len(wd.time_s)
    motion = motion_rms_m(wd.y_m, wd.segment)
    _say(opt, f"window {t0:g}–{t1:g} s ({how}): {N} epochs, {len(wd.channels)} channels, "
              f"{len(wd.segments)} bias segments, phase motion RMS {motion * 100:.2f} cm")
    if N < 3:
        raise CdgpsError(f"window {t0:g}–{t1:g} s has only {N} epochs; need at least 3")
    if motion < opt.min_motion_ratio * sigma:
        raise CdgpsError(_unobservable_msg(t0, t1, motion, sigma, None, cfg.wavelength_m, opt, motion_only=True))
    prob = _Problem(cfg, wd, sigma, opt.process_noise)

    # --- cold start: several initial guesses, each tried on the first part of the window
    n_sub = min(N, max(int(round(opt.start_window_s / cfg.sample_period_s)) + 1, 3))
    sub = _Problem(cfg, window_data(run, float(wd.time_s[0]), float(wd.time_s[n_sub - 1])), sigma, opt.process_noise)
    results = []
    for label, x1 in _start_guesses(cfg, opt.starts):
        xs = sub.propagate(x1)
        g = sub.gauss_newton(xs, sub.initial_biases(xs), opt.start_iterations, opt, max_retries=3)
        results.append((label, g))
        _say(opt, f"  start {label}: cost {g.cost:.4g} after {g.iterations} iterations on the first {n_sub} epochs")
    # the most promising starts (lowest short-window cost) are continued on the whole window; the
    # lowest full-window cost wins (a short window can prefer a mirror solution ~180° away)
    order = list(np.argsort([g.cost for _, g in results]))[: max(1, min(opt.finalists, len(results)))]
    finals = []
    for i in order:
        _, g0 = results[i]
        x_init = np.empty((N, prob.n))
        x_init[:len(g0.x)] = g0.x
        for k in range(len(g0.x), N):
            x_init[k] = prob.A @ x_init[k - 1]
        w_init = np.zeros((N - 1, prob.G.shape[1]))
        w_init[:len(g0.w)] = g0.w
        gi = prob.gauss_newton(x_init, prob.initial_biases(x_init), opt.max_iterations, opt, w_init=w_init)
        finals.append((i, gi))
        _say(opt, f"  continued {results[i][0]} on the whole window: cost {gi.cost:.6g} after {gi.iterations} iterations")
    best_i, g = min(finals, key=lambda t: t[1].cost)
    best_i = int(best_i)
    label = results[best_i][0]
    final_costs = {i: gi.cost for i, gi in finals}
    total_iter = sum(r.iterations for _, r in results) + sum(gi.iterations for _, gi in finals)
    lin = g.lin
    m = len(wd.segments)
    n = prob.n
    if lin.P_end is None:
        raise CdgpsError(_unobservable_msg(t0, t1, motion, sigma, None, cfg.wavelength_m, opt))
    Pbb = lin.P_end[n:, n:]
    bias_sigma = np.sqrt(np.diag(Pbb))
    if bias_sigma.max() > opt.max_bias_sigma_cycles * cfg.wavelength_m:
        raise CdgpsError(_unobservable_msg(t0, t1, motion, sigma, bias_sigma.max(), cfg.wavelength_m, opt))
    if not g.converged:
        raise CdgpsError(f"batch initialization did not converge in {opt.max_iterations} iterations "
                         f"(window {t0:g}–{t1:g} s, cost {g.cost:.4g}); try another window (--start/--duration) "
                         f"or more iterations (--max-iterations)")
    b_float = g.b.copy()

    # --- integers
    lam = cfg.wavelength_m
    line = np.array([cfg.antenna_line_bias_m[cfg.antenna_names.index(s["antenna"])]
                     - cfg.antenna_line_bias_m[cfg.master_index] for s in wd.segments])
    a_float = (b_float - line) / lam
    fixed = np.zeros(m, dtype=bool)
    integers = np.rint(a_float).astype(np.int64)
    ratio = None
    fix_note = "integer fixing off"
    if opt.fix_integers and cfg.line_bias_calibrated:
        Qa = Pbb / lam**2
        Qa = 0.5 * (Qa + Qa.T)
        cands, norms = lambda_search(a_float, Qa, candidates=2)
        ok, ratio = ratio_test(norms, opt.ratio_threshold)
        if ok:
            fixed[:] = True
            integers = cands[0]
            fix_note = f"all {m} integers fixed (ratio {ratio:.2f} ≥ {opt.ratio_threshold:g})"
        elif opt.partial:
            pf = partial_fix(a_float, Qa, threshold=opt.ratio_threshold)
            fixed = np.asarray(pf["fixed_mask"], dtype=bool)
            if fixed.any():
                integers = np.where(fixed, pf["integers"], integers)
                fix_note = f"{int(fixed.sum())} of {m} integers fixed by partial fixing (full-set ratio {ratio:.2f})"
            else:
                fix_note = f"integers not fixed: ratio {ratio:.2f} < {opt.ratio_threshold:g}"
        else:
            fix_note = f"integers not fixed: ratio {ratio:.2f} < {opt.ratio_threshold:g}"
    elif not cfg.line_bias_calibrated:
        fix_note = "line biases not calibrated: float biases only"
    _say(opt, f"  {fix_note}")

    final_b = b_float.copy()
    if fixed.any():
        known = np.full(m, np.nan)
        known[fixed] = line[fixed] + lam * integers[fixed]
        prob_f = _Problem(cfg, wd, sigma, opt.process_noise, known_bias=known)
        gf = prob_f.gauss_newton(g.x, g.b[~fixed], opt.max_iterations, opt, w_init=g.w)
        total_iter += gf.iterations
        final_b = prob_f.full_bias(gf.b)
        x_traj, lin_final, prob_final, J_final = gf.x, gf.lin, prob_f, gf.cost
        # validation: with the right integers the cost rises by about a chi-square(n_fixed) amount
        # (scaled by the float solution's cost per degree of freedom)
        n_obs = int(np.isfinite(prob.y).sum())
        dof_f = max(n_obs - n - m, 1)
        scale = max(g.cost / dof_f, 1e-12)
        dJ = (J_final - g.cost) / scale
        limit = opt.fix_validation_margin * float(chi2.ppf(opt.fix_validation_probability, int(fixed.sum())))
        if dJ > limit:
            _say(opt, f"  integer fix rejected by validation: cost increase {dJ:.1f} > {limit:.1f} "
                      f"(chi-square {opt.fix_validation_probability:g}, {int(fixed.sum())} dof, margin {opt.fix_validation_margin:g})")
            fix_note = (f"integer fix rejected by validation (cost increase {dJ:.1f} > {limit:.1f}); "
                        f"float biases kept")
            fixed[:] = False
            integers = np.rint(a_float).astype(np.int64)
            final_b = b_float.copy()
            x_traj, lin_final, prob_final, J_final = g.x, lin, prob, g.cost
    else:
        x_traj, lin_final, prob_final, J_final = g.x, lin, prob, g.cost

    # --- outputs
    resid = prob_final.residual(x_traj, final_b[prob_final.free] if prob_final.free.size else np.zeros(0))
    res_rms = {f"{a}/{t}": float(np.sqrt(np.nanmean(resid[:, c] ** 2))) if np.isfinite(resid[:, c]).any() else None
               for c, (a, t) in enumerate(wd.channels)}
    P = lin_final.P_end
    Pxx = P[:n, :n] if P is not None else None
    free_sigma = np.full(m, 0.0)
    if P is not None and prob_final.free.size:
        free_sigma[prob_final.free] = np.sqrt(np.diag(P[n:, n:]))
    biases = []
    last_seg = {}
    for s_i, s in enumerate(wd.segments):
        last_seg[(s["antenna"], s["transmitter"])] = s_i
    for s_i, s in enumerate(wd.segments):
        biases.append({
            "antenna": s["antenna"], "transmitter": s["transmitter"],
            "bias_m": float(final_b[s_i]),
            "sigma_m": float(free_sigma[s_i] if not fixed[s_i] else 0.0),
            "float_bias_m": float(b_float[s_i]), "float_sigma_m": float(bias_sigma[s_i]),
            "integer_cycles": int(integers[s_i]), "float_cycles": float(a_float[s_i]),
            "line_bias_m": float(line[s_i]), "fixed": bool(fixed[s_i]),
            "segment_start_s": s["start_s"], "segment_end_s": s["end_s"],
            "current": last_seg[(s["antenna"], s["transmitter"])] == s_i,
        })
    nm = cfg.n_modes
    U = np.asarray(cfg.mode_shapes)
    x_end = x_traj[-1]
    q_end = U @ x_end[:nm]
    elapsed = _time.perf_counter() - t_start
    dof = max(int(np.isfinite(resid).sum()) - n - int(prob_final.free.size), 1)
    out = {
        "format": "cdgps.init/1",
        "config": cfg.name,
        "config_sha256": cfg.sha256,
        "run": run.path,
        "window": {"start_s": float(wd.time_s[0]), "end_s": float(wd.time_s[-1]), "epochs": N, "selection": how,
                   "motion_rms_m": motion, "channels": len(wd.channels), "bias_segments": m},
        "biases": biases,
        "state": {
            "time_s": float(wd.time_s[-1]),
            "state_names": [f"xi_{k}" for k in cfg.mode_names] + [f"xidot_{k}" for k in cfg.mode_names],
            "x": [float(v) for v in x_end],
            "P": [[float(v) for v in row] for row in Pxx] if Pxx is not None else None,
            "q": {name: float(v) for name, v in zip(cfg.coord_names, q_end)},
        },
        "iterations": int(total_iter),
        "converged": True,
        "starts": [{"label": lab, "cost": float(r.cost), "iterations": r.iterations, "won": i == best_i,
                    "full_window_cost": (float(final_costs[i]) if i in final_costs else None)}
                   for i, (lab, r) in enumerate(results)],
        "cost": float(J_final),
        "cost_per_dof": float(J_final / dof),
        "ratio": None if ratio is None else (float(ratio) if np.isfinite(ratio) else "inf"),
        "integer_fixing": fix_note,
        "n_fixed": int(fixed.sum()),
        "residual_rms_m": res_rms,
        "sigma_m": sigma,
        "options": opt.echo(),
        "elapsed_s": elapsed,
    }
    if return_trajectory:
        return out, {"time_s": wd.time_s, "x": x_traj}
    return out


def _unobservable_msg(t0, t1, motion, sigma, bias_sigma, lam, opt, motion_only=False) -> str:
    if motion_only:
        detail = (f"phase motion RMS {motion * 100:.2f} cm is below {opt.min_motion_ratio:g} × the "
                  f"{sigma * 100:.2f} cm measurement noise")
    else:
        s = "singular (some bias has no information)" if bias_sigma is None else f"{bias_sigma * 100:.1f} cm"
        detail = (f"phase motion RMS {motion * 100:.2f} cm against {sigma * 100:.2f} cm noise, largest "
                  f"float-bias sigma {s} (limit {opt.max_bias_sigma_cycles:g} cycle = "
                  f"{opt.max_bias_sigma_cycles * lam * 100:.1f} cm)")
    return (f"biases not observable in the window {t0:g}–{t1:g} s: {detail}. "
            f"Initialize on a window where the structure moves (--start/--duration).")
