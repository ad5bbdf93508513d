"""Bias initialization (``cdgps init``): iterated batch dynamic least squares + integer fixing.

Flow (Teague, How & Parkinson 1998 Sec. IV.A; Teague et al. 1995 batch estimator):

1. Pick a window of epochs recorded while the structure moves (automatic by default: the first
   window whose phase motion is well above the noise).
2. Give every channel one bias parameter per lock segment (a slip or re-lock inside the window
   starts a new segment, so the window is split at the slip rather than corrupted by it).  A slip
   the receiver did not flag is found after the cold start as a step in the channel's residuals
   (:func:`_split_slips`): split there too in an automatic window, refused in a given one.
3. For several initial guesses of the large rigid-body angle (cold start), iterate Gauss–Newton:
   linearize h about the current trajectory, solve the linear batch problem of Eq. (13)–(15) in
   O(N) with :func:`cdgps_cli.estimation.batch_solver.srif_solve`, accept the step if the nonlinear cost decreases
   (Levenberg–Marquardt damping on x₁ and b otherwise).  The starts are compared after a few
   iterations on the first part of the window; the best few (finalists) are continued on the whole
   window, one iteration each in turn, and the lowest cost wins.  A finalist that has settled in a
   minimum far worse than the best cost so far, or in the same minimum as another finalist, is
   abandoned (:func:`_race`).  On a window more than STAGE_GROWTH times longer than the first part,
   the finalists first converge on intermediate windows (each at most STAGE_GROWTH times longer
   than the previous one) so that they reach the long window nearly converged.
4. If line biases are calibrated, fix b = line bias + λ·n with LAMBDA and the ratio test (partial
   fixing of a subset if the whole set fails), then re-solve the states with the integers fixed.
5. Report the biases, the filter's initial state and covariance at the window end, residuals.

The batch problem and Gauss–Newton are the one engine of :mod:`cdgps_cli.estimation.batch_init`
(shared with the GNSS modal initialization); :class:`_Problem` is its wrapper here (the phase
model, per-channel σ, multipath states).
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np

from cdgps_cli.estimation import kernel
from cdgps_cli.estimation.batch_init import (  # noqa: F401  (the engine's names, re-exported)
    BatchProblem, GaussNewton, GNResult, InitOptions, fix_validation, full_set_ratio)
from cdgps_cli.estimation.batch_solver import LinearProblem, srif_solve
from cdgps_cli.config.structure import StructureConfig, channel_sigma_m, scalar_sigma_m
from cdgps_cli.model.dynamics import discrete_model
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.measurement.channels import lock_segments
from cdgps_cli.measurement.phase import channel_indices, phase_model, row_channel_indices
from cdgps_cli.core import progress
from cdgps_cli.estimation.ambiguity import resolve
from cdgps_cli.measurement.multipath import MultipathModel, augment, fit_autocovariance, model_from
from cdgps_cli.measurement.slips import residual_steps
from cdgps_cli.measurement.noise import leverage_per_channel, prior_sigma_m, snr_sigma_factor, variance_factors
from cdgps_cli.core.records import INIT_FORMAT, Run


@dataclass
class WindowData:
    time_s: np.ndarray          # (N,) regular grid
    y_m: np.ndarray             # (N, C) λ·phase, NaN where absent
    channels: list              # [(antenna, transmitter)]
    ant: np.ndarray
    tx: np.ndarray
    segment: np.ndarray         # (N, C) bias parameter index, -1 where absent
    segments: list              # per parameter: dict(antenna, transmitter, start_s, end_s, channel)
    # the last linearization of the phase model on this window (x, h, H), shared by every problem
    # built on it: the noise estimate and the fixed solution re-linearize where the float one ended
    model_cache: dict = field(default_factory=dict, repr=False, compare=False)


def _say(opt: InitOptions, msg: str) -> None:
    if opt.progress:
        opt.progress(msg)


def phase_matrix(run: Run, t0: float, t1: float):
    """Epoch grid and (N, C) matrices of phase (metres) and lock over [t0, t1]."""
    cfg = run.cfg
    T = cfg.sample_period_s
    ph = run.phase
    t_all = ph["time_s"]
    keep = (t_all >= t0 - 1e-9) & (t_all <= t1 + 1e-9)
    if not keep.any():
        raise CdgpsError(f"{run.path}: no phase data between {t0:g} s and {t1:g} s")
    t = t_all[keep]
    tmin, tmax = t.min(), t.max()
    n = int(round((tmax - tmin) / T)) + 1
    grid = tmin + np.arange(n) * T
    k = np.rint((t - tmin) / T).astype(int)
    # channels in config order (antenna, then transmitter)
    ai, ti = row_channel_indices(cfg, ph, run.path, rows=keep)
    key = ai * len(cfg.transmitter_names) + ti
    ukey, ci = np.unique(key, return_inverse=True)
    chans = [(cfg.antenna_names[u // len(cfg.transmitter_names)], cfg.transmitter_names[u % len(cfg.transmitter_names)])
             for u in ukey.tolist()]
    y = np.full((n, len(chans)), np.nan)
    lock = np.full((n, len(chans)), -1, dtype=np.int64)
    y[k, ci] = ph["phase_cycles"][keep] * cfg.wavelength_m
    lock[k, ci] = ph["lock"][keep]
    return grid, y, lock, chans


def window_snr_dbhz(run: Run, wd: WindowData) -> np.ndarray:
    """Each window channel's mean C/N₀ (dB-Hz) over the window, (C,); NaN where none is reported."""
    ph = run.phase
    t = ph["time_s"]
    keep = (t >= wd.time_s[0] - 1e-9) & (t <= wd.time_s[-1] + 1e-9)
    snr = np.asarray(ph["snr_dbhz"][keep], dtype=float)        # (the window's rows only: a table on disk)
    ai, ti = row_channel_indices(run.cfg, ph, run.path, rows=keep)
    key = ai * len(run.cfg.transmitter_names) + ti               # each row's channel, by config index
    c_ant, c_tx = channel_indices(run.cfg, [c[0] for c in wd.channels], [c[1] for c in wd.channels])
    out = np.full(len(wd.channels), np.nan)
    for c, k in enumerate((c_ant * len(run.cfg.transmitter_names) + c_tx).tolist()):
        v = snr[key == k]
        v = v[np.isfinite(v)]
        if v.size:
            out[c] = float(v.mean())
    return out


def window_data(run: Run, t0: float, t1: float, cuts=()) -> WindowData:
    """The window [t0, t1] of a run: phase matrix, channels and one bias parameter per lock segment
    (:func:`cdgps_cli.measurement.channels.lock_segments` on the lock counts; a segment is cut at
    the window's edges).  Segments are numbered by channel, then time.

    ``cuts``: (channel, epoch) pairs (column and row of the window's phase matrix) where a segment
    starts although the lock indicator continues (unflagged slips found by :func:`_split_slips`)."""
    grid, y, lock, chans = phase_matrix(run, t0, t1)
    n, C = y.shape
    cc, kk = np.nonzero(~np.isnan(y.T))          # channel-major: the rule's (channel, step) order
    slip = np.zeros(cc.size, dtype=bool)
    for c, k in cuts:
        slip |= (cc == c) & (kk == k)
    ls = lock_segments(cc, kk, lock=lock[kk, cc], slip=slip if len(cuts) else None)
    seg = np.full((n, C), -1, dtype=np.int64)
    seg[kk, cc] = ls.segment
    segments = [{"antenna": chans[c][0], "transmitter": chans[c][1], "channel": c,
                 "start_s": float(grid[kk[i0]]), "end_s": float(grid[kk[i1]])}
                for c, i0, i1 in zip(ls.channel.tolist(), ls.first.tolist(), ls.last.tolist())]
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
    ph_t = run.phase["time_s"]
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


_MODEL_CHUNK = 1024             # epochs per call of the measurement model


class _Problem(BatchProblem):
    """The pseudolite / far-field batch problem on a window: the structure's phase model (compiled),
    one bias parameter per lock segment, per-channel σ and, optionally, a Gauss–Markov multipath
    state per channel; the engine is :class:`~cdgps_cli.estimation.batch_init.BatchProblem`."""

    def __init__(self, cfg: StructureConfig, wd: WindowData, sigma_m: float, process_noise: bool,
                 known_bias: np.ndarray | None = None, mp: MultipathModel | None = None):
        self.cfg = cfg
        self.wd = wd
        self._geometry = None                     # the compiled model's packed geometry (on first use)
        self.mp = mp if mp is not None and mp.active else None
        # per-channel σ (m); self.sigma (a scalar) only scales the damping prior
        self.sig_c = np.broadcast_to(np.asarray(sigma_m, dtype=float), (len(wd.channels),)).copy()
        self.sigma = float(np.sqrt(np.mean(self.sig_c**2)))
        model = discrete_model(cfg)
        self.A = model.A
        L = np.sqrt(np.diag(model.W))
        G = model.Bw * L
        keep = L > 0
        self.G = G[:, keep] if process_noise else np.zeros((model.A.shape[0], 0))
        self.n_dyn = self.n = model.A.shape[0]     # structure states; n with the multipath states
        if self.mp is not None:                    # one Gauss–Markov state per channel (cdgps_cli.measurement.multipath)
            self.A, self.G = augment(self.A, self.G, len(wd.channels), self.mp, cfg.sample_period_s)
            self.n = self.A.shape[0]
        # with multipath the Gram form of the bias-only rows is mostly too ill-conditioned (measured:
        # 30 of 74 solves redone), so the square-root form is used directly
        self.square_root = True if self.mp is not None else None
        # bias parametrization: fixed values (known_bias[s] finite) are moved into y
        self._set_biases(wd.y_m, wd.segment, len(wd.segments), known_bias)
        chan_of_seg = np.array([sg["channel"] for sg in wd.segments], dtype=np.int64)
        # each free bias solved in units of its channel's σ (the rows are divided by it)
        self.free_sig = self.bias_scale = self.sig_c[chan_of_seg[self.free]] if self.free.size else np.zeros(0)


    def predict(self, x: np.ndarray, jacobian: bool = False):
        """h(x) (N, C) and with ``jacobian`` H (N, C, n): the structure's phase model on x[:, :n_dyn]
        plus, with multipath, each channel's Gauss–Markov state."""
        if self.mp is None:
            return self._predict(x, jacobian)
        nd, C = self.n_dyn, len(self.wd.channels)
        out = self._predict(np.ascontiguousarray(x[:, :nd]), jacobian)
        h = (out[0] if jacobian else out) + x[:, nd:]
        if not jacobian:
            return h
        H = np.zeros((len(x), C, self.n))
        H[:, :, :nd] = out[1]
        H[:, np.arange(C), nd + np.arange(C)] = 1.0
        return h, H

    def _predict(self, x: np.ndarray, jacobian: bool = False):
        c = self.wd.model_cache
        if "x" in c and c["x"].shape == x.shape and np.array_equal(c["x"], x):
            return (c["h"], c["H"]) if jacobian else c["h"]
        out = self._evaluate(x, jacobian)
        if jacobian:
            c.update(x=x.copy(), h=out[0], H=out[1])
        return out

    def _evaluate(self, x: np.ndarray, jacobian: bool):
        if kernel.available():                    # the compiled model (tested equal to phase_model)
            if self._geometry is None:
                self._geometry = kernel.pack_geometry(self.cfg, self.wd.ant, self.wd.tx)
            return kernel.phase_model_batch(self._geometry, x, jacobian)
        N = len(x)
        if N <= _MODEL_CHUNK:
            return phase_model(self.cfg, x, self.wd.ant, self.wd.tx, jacobian=jacobian)
        # in blocks of epochs: the Jacobian's temporaries (epochs × channels × 3 × coordinates)
        # then stay cache-sized and the cost per epoch does not grow with the window
        C = len(self.wd.ant)
        h = np.empty((N, C))
        H = np.empty((N, C, x.shape[1])) if jacobian else None
        for k0 in range(0, N, _MODEL_CHUNK):
            part = phase_model(self.cfg, x[k0:k0 + _MODEL_CHUNK], self.wd.ant, self.wd.tx, jacobian=jacobian)
            if jacobian:
                h[k0:k0 + _MODEL_CHUNK], H[k0:k0 + _MODEL_CHUNK] = part
            else:
                h[k0:k0 + _MODEL_CHUNK] = part
        return (h, H) if jacobian else h

    def data_cost(self, r: np.ndarray) -> float:
        return np.nansum((r / self.sig_c) ** 2)

    def x1_cost(self, x: np.ndarray) -> float:
        return 0.0 if self.mp is None else float(np.sum((x[0, self.n_dyn:] / self.mp.sigma_m) ** 2))

    def whiten(self, H: np.ndarray, ytil: np.ndarray):
        """Rows divided by their channel's σ; each row touches one bias (no E)."""
        w = 1.0 / self.sig_c
        return H * w[None, :, None], ytil * w, None

    def x1_prior(self, damp: float, x1_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Prior on the first state: the damping (square-root weight ``damp`` about ``x1_ref``) and,
        with multipath, the stationary N(0, σ_mp²) of each Gauss–Markov state combined with it."""
        info = np.full(self.n, damp)
        mean = np.array(x1_ref, dtype=float)
        if self.mp is not None:
            nd, s2 = self.n_dyn, self.mp.sigma_m**-2
            tot = damp**2 + s2
            mean[nd:] = damp**2 * mean[nd:] / tot
            info[nd:] = np.sqrt(tot)
        return mean, np.diag(info)


    def leverage(self, x: np.ndarray) -> np.ndarray:
        """Σ_k h_kc per channel of the linearization about x (no damping; Hutchinson probes, all
        solved at once as one SRIF pass with a right-hand side per probe)."""
        lp0 = self.linear_problem(x, 0.0, x[0], 0.0, np.zeros(self.free.size))
        H = lp0.H
        present = np.isfinite(self.y)

        def fitted(eps):                        # eps (N, C, K) → whitened fitted values (N, C, K)
            K = eps.shape[2]
            lp = LinearProblem(A=lp0.A, Bw_L=lp0.Bw_L, H=H, y=eps, bias_index=lp0.bias_index, n_bias=lp0.n_bias,
                               sigma_m=1.0, x1_mean=np.zeros((self.n, K)), x1_sqrt_info=lp0.x1_sqrt_info,
                               b_mean=np.zeros((lp0.n_bias, K)), b_sqrt_info=lp0.b_sqrt_info)
            sol = srif_solve(lp, square_root=self.square_root)
            f = np.einsum("nci,nik->nck", H, sol.x)
            if sol.b.size:
                f = f + np.where((self.bias_index >= 0)[..., None], sol.b[np.maximum(self.bias_index, 0)], 0.0)
            return f

        return leverage_per_channel(fitted, present, batched=True)


# a finalist is abandoned when it has settled in a basin whose cost exceeds the best current cost by
# more than this many standard deviations of the chi-square cost (after allowing ABANDON_TAIL × its
# last cost decrease for the iterations it would still make)
ABANDON_SIGMAS = 10.0
ABANDON_TAIL = 100.0
SAME_SOLUTION_M = 1e-3          # two finalists whose biases agree to 1 mm have found the same minimum
STAGE_GROWTH = 8                # longest window growth from the start window to the next one


def _race(runs: list, prob: _Problem, results: list, opt: InitOptions) -> dict:
    """Advance the finalists' Gauss–Newton runs in turn, one iteration each per round.

    Every run's cost only decreases, so the lowest current cost J_ref bounds the winner's final
    cost from above.  A run that has *settled* (:meth:`GaussNewton.settled`: a full step that did
    what the linearized model predicted) in a worse basin — its cost minus ABANDON_TAIL × its last
    decrease still above J_ref by ABANDON_SIGMAS standard deviations of the cost — cannot win and
    is abandoned; so is a settled run whose biases agree within SAME_SOLUTION_M with a settled or
    converged run of lower cost (the same minimum, reached twice).  Runs still approaching their
    minimum (backtracking, damping, or a model that mispredicts the decrease) are never abandoned,
    whatever their cost: a run far above the others can still end in the best basin.

    Returns {start index: "converged" | "not converged" | "abandoned: …"}.
    """
    n_obs = int(np.isfinite(prob.y).sum())
    dof = max(n_obs - prob.n_dyn - prob.free.size, 1)
    outcome = {}
    active = list(runs)
    while active:
        for _, gn in active:
            gn.step()
        J_ref = min(gn.J for i, gn in runs if not outcome.get(i, "").startswith("abandoned"))
        margin = ABANDON_SIGMAS * math.sqrt(2.0 * dof) * J_ref / dof
        still = []
        for i, gn in active:
            if gn.done:
                outcome[i] = "converged" if gn.converged else "not converged"
                continue
            if gn.settled():
                if gn.J - ABANDON_TAIL * gn.last[0] > J_ref + margin:
                    outcome[i] = "abandoned: worse minimum"
                    continue
                twin = next((j for j, o in runs if j != i and not outcome.get(j, "").startswith("abandoned")
                             and (o.settled() or o.converged) and (o.J, j) < (gn.J, i)
                             and np.max(np.abs(o.b - gn.b), initial=0.0) < SAME_SOLUTION_M), None)
                if twin is not None:
                    outcome[i] = f"abandoned: same minimum as {results[twin][0]}"
                    continue
            still.append((i, gn))
        active = still
    return outcome


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


@dataclass
class _Window:
    """The initialization window of a run and its nonlinear problem at the options' σ."""

    t0: float
    t1: float
    how: str
    wd: WindowData
    motion_m: float
    mp: MultipathModel
    prob: _Problem
    cuts: tuple = ()            # (channel, epoch) of the unflagged slips found (:func:`_split_slips`)


@dataclass
class _Race:
    """Outcome of the multi-start stage (:func:`_multi_start`)."""

    results: list               # [(label, GNResult on the start window)]
    best_i: int
    best: GaussNewton
    outcome: dict               # start index → full-window outcome
    final_costs: dict           # start index → full-window cost
    iterations: int


@dataclass
class _Fit:
    """The float solution with its noise model (:func:`_noise_fit`)."""

    prob: _Problem
    g: GNResult
    noise: dict
    mp: MultipathModel
    auto_mp: dict | None


@dataclass
class _Fix:
    """Integer fixing of the float biases (:func:`_fix_integers`), per bias segment."""

    line: np.ndarray            # line bias (m)
    a_float: np.ndarray         # float ambiguity (cycles)
    fixed: np.ndarray           # bool
    integers: np.ndarray        # int64
    ratio: float | None
    note: str


@dataclass
class _Final:
    """The reported solution: fixed when the fix passed validation, else the float one."""

    x: np.ndarray
    lin: object
    prob: _Problem
    cost: float
    bias_m: np.ndarray
    iterations: int


def initialize(run: Run, opt: InitOptions | None = None, return_trajectory: bool = False):
    """Estimate channel biases and the filter's initial state from a window of a RUN.

    Returns the INIT.json dictionary (see the README); with ``return_trajectory`` also
    ``{"time_s", "x"}``, the smoothed batch trajectory over the window.  Raises :class:`CdgpsError` when the window
    does not make the biases observable or Gauss–Newton does not converge.
    """
    opt = opt or InitOptions()
    t_start = _time.perf_counter()
    sigma = _checked_sigma(run.cfg, opt)
    win = _window(run, opt, sigma)
    race = _multi_start(run, win, opt, sigma)
    win, race, slips = _split_slips(run, win, race, opt, sigma)
    fit = _noise_fit(run, win, race.best.result(), opt, sigma)
    _check_float(run.cfg, win, fit, opt)
    keep_float = _slip_sizes(run.cfg, win.wd, fit, slips)
    fix = _fix_integers(run.cfg, win.wd, fit, opt, keep_float)
    final = _fixed_solution(run.cfg, win, fit, fix, opt)
    out = _init_record(run, win, race, fit, fix, final, opt)
    if slips:
        out["unflagged_slips"] = slips
    out["iterations"] = int(race.iterations + final.iterations)
    out["elapsed_s"] = _time.perf_counter() - t_start
    if return_trajectory:
        return out, {"time_s": win.wd.time_s, "x": final.x[:, :fit.prob.n_dyn]}
    return out


def _checked_sigma(cfg: StructureConfig, opt: InitOptions) -> float:
    """The options checked; the scalar σ (m) of the start stage (``--sigma-m`` or the config's)."""
    if opt.sigma_m is not None and not (np.isfinite(opt.sigma_m) and opt.sigma_m > 0):
        raise CdgpsError(f"--sigma-m must be a positive number of metres, got {opt.sigma_m!r}")
    if opt.ratio_threshold <= 1.0:
        raise CdgpsError(f"--ratio must be greater than 1, got {opt.ratio_threshold:g}")
    if opt.starts < 1 or opt.max_iterations < 1:
        raise CdgpsError("--starts and --max-iterations must be at least 1")
    return opt.sigma_m if opt.sigma_m is not None else scalar_sigma_m(channel_sigma_m(cfg, cfg.channels))


def _window(run: Run, opt: InitOptions, sigma: float) -> _Window:
    """The window (:func:`choose_window`), refused when too short or without enough motion."""
    cfg = run.cfg
    t0, t1, how = choose_window(run, opt, sigma)
    wd = window_data(run, t0, t1)
    N = len(wd.time_s)
    motion = motion_rms_m(wd.y_m, wd.segment)
    _say(opt, f"window {t0:g}–{t1:g} s ({how}): {N} epochs, {len(wd.channels)} channels, "
              f"{len(wd.segments)} bias segments, phase motion RMS {motion * 100:.2f} cm")
    if N < 3:
        given = [f"{flag} {v:g} s" for flag, v in (("--start", opt.start_s), ("--duration", opt.duration_s)) if v is not None]
        raise CdgpsError(f"{' and '.join(given) + ': the ' if given else ''}window {t0:g}–{t1:g} s has only {N} "
                         f"epoch{'s' if N != 1 else ''}; need at least 3"
                         + (" (give a longer --duration)" if opt.duration_s is not None else ""))
    if motion < opt.min_motion_ratio * sigma:
        raise CdgpsError(_unobservable_msg(t0, t1, motion, sigma, None, cfg.wavelength_m, opt, motion_only=True))
    mp = model_from(cfg, opt.multipath_sigma_m, opt.multipath_time_constant_s)
    if mp.active:
        _say(opt, f"  multipath: a Gauss–Markov state per channel (σ {mp.sigma_m * 1000:.2f} mm, "
                  f"τ {mp.time_constant_s:g} s)")
    return _Window(t0, t1, how, wd, motion, mp, _Problem(cfg, wd, sigma, opt.process_noise, mp=mp))


def _multi_start(run: Run, win: _Window, opt: InitOptions, sigma: float) -> _Race:
    """Cold start: every initial guess a few iterations on the first part of the window; the most
    promising (lowest short-window cost) continue through the growing windows (:func:`_race`); the
    lowest full-window cost wins (a short window can prefer a mirror solution ~180° away)."""
    cfg, wd, N = run.cfg, win.wd, len(win.wd.time_s)
    n_sub = min(N, max(int(round(opt.start_window_s / cfg.sample_period_s)) + 1, 3))
    sub = _Problem(cfg, window_data(run, float(wd.time_s[0]), float(wd.time_s[n_sub - 1]), win.cuts), sigma,
                   opt.process_noise, mp=win.mp)
    results = []
    for label, x1 in _start_guesses(cfg, opt.starts):
        xs = sub.propagate(x1)
        g = sub.gauss_newton(xs, sub.initial_biases(xs), opt.start_iterations, opt, max_retries=3, information=False)
        results.append((label, g))
        _say(opt, f"  start {label}: cost {g.cost:.4g} after {g.iterations} iterations on the first {n_sub} epochs")
    order = list(np.argsort([g.cost for _, g in results]))[: max(1, min(opt.finalists, len(results)))]
    # on a long window the finalists first go through intermediate windows, each at most
    # STAGE_GROWTH times longer than the previous one (from a converged shorter solution the
    # extrapolation to the next window is good, and the long window needs few iterations)
    stages = [n_sub]
    while stages[-1] < N:
        stages.append(min(N, STAGE_GROWTH * (stages[-1] - 1) + 1))
    survivors = [(int(i), results[i][1]) for i in order]
    outcome, final_costs, total_iter = {}, {}, sum(r.iterations for _, r in results)
    for n_stage in stages[1:] or [N]:
        runs, stage_outcome = _race_stage(run, win, n_stage, survivors, results, opt, sigma)
        total_iter += sum(gn.it for _, gn in runs)
        last = n_stage == N
        where = "the whole window" if last else f"the first {n_stage} epochs"
        for i, gn in runs:
            _say(opt, f"  continued {results[i][0]} on {where}: cost {gn.J:.6g} after {gn.it} iterations, "
                      f"{stage_outcome[i]}")
            if last:
                outcome[i], final_costs[i] = stage_outcome[i], gn.J
            elif stage_outcome[i].startswith("abandoned"):
                outcome[i] = stage_outcome[i].replace("abandoned", f"abandoned on the first {n_stage} epochs", 1)
        survivors = [(i, gn) for i, gn in runs if not stage_outcome[i].startswith("abandoned")]
    best_i, best = min(((i, gn) for i, gn in runs if not outcome[i].startswith("abandoned")), key=lambda t: t[1].J)
    return _Race(results, best_i, best, outcome, final_costs, total_iter)


def _race_stage(run: Run, win: _Window, n_stage: int, survivors: list, results: list, opt: InitOptions,
                sigma: float) -> tuple[list, dict]:
    """The survivors' runs continued on the first ``n_stage`` epochs (their trajectories propagated
    over the new epochs), raced (:func:`_race`).  Returns ([(start index, GaussNewton)], outcome)."""
    wd = win.wd
    sp = win.prob if n_stage == len(wd.time_s) else _Problem(
        run.cfg, window_data(run, float(wd.time_s[0]), float(wd.time_s[n_stage - 1]), win.cuts), sigma,
        opt.process_noise, mp=win.mp)
    runs = []
    for i, g0 in survivors:
        x_init = np.empty((n_stage, sp.n))
        x_init[:len(g0.x)] = g0.x
        for k in range(len(g0.x), n_stage):
            x_init[k] = sp.A @ x_init[k - 1]
        w_init = np.zeros((n_stage - 1, sp.G.shape[1]))
        w_init[:len(g0.w)] = g0.w
        runs.append((i, GaussNewton(sp, x_init, sp.initial_biases(x_init), opt.max_iterations, opt, w_init=w_init)))
    return runs, _race(runs, sp, results, opt)


SLIP_ROUNDS = 6                 # search – split – refit rounds for unflagged slips (one split each)


def _split_slips(run: Run, win: _Window, race: _Race, opt: InitOptions, sigma: float):
    """Unflagged cycle slips in the window: steps in a channel's residuals of the winning fit
    (:func:`~cdgps_cli.measurement.slips.residual_steps`).  In a window the user gave
    (--start/--duration) a slip is refused, naming the channel and the time; in an automatic
    window the channel's lock segment is split at the largest step (a new bias parameter from there
    on), the cold start redone on the split window (:func:`_multi_start`: the unmodelled slip may
    have drawn the first fit into a wrong basin) and its residuals searched again, up to
    SLIP_ROUNDS times.

    Returns (window, race, [slip records for INIT.json's ``unflagged_slips``])."""
    cfg, found, cuts = run.cfg, [], []
    for rnd in range(SLIP_ROUNDS + 1):
        wd, g = win.wd, race.best.result()
        steps = residual_steps(win.prob.residual(g.x, g.b), wd.segment, cfg.wavelength_m, cfg.sample_period_s)
        if not steps:
            break
        recs = [{"antenna": wd.channels[st.channel][0], "transmitter": wd.channels[st.channel][1],
                 "time_s": float(wd.time_s[st.epoch]), "residual_step_m": st.step_m,
                 "residual_step_cycles": st.step_m / cfg.wavelength_m, "z": st.z} for st in steps]
        if win.how == "given":
            raise CdgpsError(_slip_refusal(win, recs, cfg.wavelength_m))
        if rnd == SLIP_ROUNDS:
            raise CdgpsError(_slip_refusal(win, recs, cfg.wavelength_m, found))
        # one split per round, the largest step: a large slip bends the fitted trajectory and so
        # leaves smaller steps in other channels, which vanish once the slip has its own bias
        j = int(np.argmax([abs(st.step_m) for st in steps]))
        steps, recs = [steps[j]], [recs[j]]
        for r in recs:
            _say(opt, f"  unflagged cycle slip on {r['antenna']}/{r['transmitter']} at {r['time_s']:g} s (residual step "
                      f"{r['residual_step_m'] * 100:.1f} cm, z {r['z']:.0f}): a new bias from there on")
        found += recs
        cuts += [(st.channel, st.epoch) for st in steps]
        wd = window_data(run, win.t0, win.t1, cuts)
        prob = _Problem(cfg, wd, sigma, opt.process_noise, mp=win.mp)
        win = _Window(win.t0, win.t1, win.how, wd, win.motion_m, win.mp, prob, tuple(cuts))
        iterations = race.iterations
        race = _multi_start(run, win, opt, sigma)
        race.iterations += iterations
    return win, race, found


def _slip_refusal(win: _Window, recs: list, lam: float, split: list | None = None) -> str:
    what = "; ".join(f"{r['antenna']}/{r['transmitter']} at {r['time_s']:g} s (residual step "
                     f"{r['residual_step_m'] * 100:.1f} cm ≈ {r['residual_step_cycles']:+.2f} cycle)" for r in recs)
    first = min(r["time_s"] for r in recs)
    if split is not None:
        return (f"unflagged cycle slips in the automatic window {win.t0:g}–{win.t1:g} s: still {what} after "
                f"{len(split)} segments were split at slips ({', '.join(r['antenna'] + '/' + r['transmitter'] for r in split)}); "
                f"too many to trust the window: initialize on another one (--start/--duration)")
    return (f"--start/--duration: unflagged cycle slip in the window {win.t0:g}–{win.t1:g} s (the phase jumps "
            f"but the lock indicator continues): {what}. Initialize on a window without it (e.g. --start "
            f"{first:g}), or leave --start/--duration out: the automatic window starts a new bias at the slip")


#: a split segment whose bias differs from the one before by more than this distance (cycles) from
#: a whole number of cycles came after a half-cycle slip: its bias is not an integer, kept float
HALF_CYCLE_TOLERANCE = 0.25


def _slip_sizes(cfg: StructureConfig, wd: WindowData, fit: _Fit, slips: list) -> np.ndarray:
    """(segments,) bool: segments to keep float.  Each slip's size in cycles is the float bias
    after it minus the one before (recorded in ``slips``); after a slip of a half number of
    cycles the channel's later segments are not whole cycles from the line bias and are not fixed."""
    keep = np.zeros(len(wd.segments), dtype=bool)
    lam = cfg.wavelength_m
    for r in slips:
        idx = [i for i, sg in enumerate(wd.segments) if (sg["antenna"], sg["transmitter"]) == (r["antenna"], r["transmitter"])]
        post = next(i for i in idx if abs(wd.segments[i]["start_s"] - r["time_s"]) < 1e-9)
        pre = max(i for i in idx if wd.segments[i]["start_s"] < r["time_s"])
        k = float((fit.g.b[post] - fit.g.b[pre]) / lam)
        half = abs(k - round(k)) > HALF_CYCLE_TOLERANCE
        r["slip_cycles"] = k
        r["handling"] = ("segment split; a half-cycle slip: the biases from here on are kept float" if half
                         else "segment split: a new bias from here on")
        if half:
            keep[[i for i in idx if wd.segments[i]["start_s"] >= r["time_s"] - 1e-9]] = True
    if slips:
        fit.noise["warnings"].insert(0, "unflagged cycle slips (the lock indicator continued) found in the window and "
                                        "given a new bias: " + ", ".join(
                                            f"{r['antenna']}/{r['transmitter']} at {r['time_s']:g} s "
                                            f"({r['slip_cycles']:+.2f} cycles)" for r in slips))
    return keep


def _noise_fit(run: Run, win: _Window, g: GNResult, opt: InitOptions, sigma: float) -> _Fit:
    """The winner refitted with the per-channel prior σ (config, SNR weighting), checked for
    time-correlated residuals (:func:`_auto_multipath`), and its σ per channel estimated
    (:func:`_estimate_noise`)."""
    cfg, wd, prob, mp = run.cfg, win.wd, win.prob, win.mp
    snr = window_snr_dbhz(run, wd)
    prior = prior_sigma_m(cfg, wd.channels, opt.sigma_m, snr_dbhz=snr)
    snr_f = snr_sigma_factor(snr) if opt.sigma_m is None else None
    if snr_f is not None:
        _say(opt, f"  SNR weighting: channel mean C/N₀ {np.nanmin(snr):.1f}–{np.nanmax(snr):.1f} dB-Hz, prior σ × "
                  f"{snr_f.min():.2f}–{snr_f.max():.2f}")
    if opt.sigma_m is None and not np.allclose(prior, sigma):
        prob = _Problem(cfg, wd, prior, opt.process_noise, mp=mp)   # per-channel prior σ from the config
        g = prob.gauss_newton(g.x, g.b, opt.max_iterations, opt, w_init=g.w)
    noise = {"source": "--sigma-m" if opt.sigma_m is not None else "config", "warnings": []}
    auto_mp = None
    if not mp.active and opt.multipath_sigma_m is None:
        # (before the white σ estimation: when the residuals are time-correlated that is redone
        # with the multipath model anyway, so it is skipped)
        prob, g, noise, mp, auto_mp = _auto_multipath(cfg, wd, prob, g, prior, noise, opt)
    if opt.estimate_sigma and opt.sigma_m is None and auto_mp is None:
        prob, g, noise = _estimate_noise(cfg, wd, prob, g, prior, opt)
    if snr_f is not None:
        noise["snr_weighting"] = {"model": "sigma^2 = sigma_config^2 * 10^((snr_ref - snr)/10) per channel (mean C/N0)",
                                  "snr_ref_dbhz": float(np.nanmedian(snr)),
                                  "snr_dbhz": {f"{a}/{t}": (float(v) if np.isfinite(v) else None)
                                               for (a, t), v in zip(wd.channels, snr)}}
    return _Fit(prob, g, noise, mp, auto_mp)


def _check_float(cfg: StructureConfig, win: _Window, fit: _Fit, opt: InitOptions) -> None:
    """Refuse a float solution whose biases are not observable (singular, or σ above the limit)
    or that did not converge."""
    sigma = float(np.sqrt(np.mean(fit.prob.sig_c**2)))
    lin, n = fit.g.lin, fit.prob.n
    if lin.P_end is None:
        raise CdgpsError(_unobservable_msg(win.t0, win.t1, win.motion_m, sigma, None, cfg.wavelength_m, opt))
    bias_sigma = np.sqrt(np.diag(lin.P_end[n:, n:]))
    if bias_sigma.max() > opt.max_bias_sigma_cycles * cfg.wavelength_m:
        raise CdgpsError(_unobservable_msg(win.t0, win.t1, win.motion_m, sigma, bias_sigma.max(), cfg.wavelength_m, opt))
    if not fit.g.converged:
        raise CdgpsError(f"batch initialization did not converge in {opt.max_iterations} iterations "
                         f"(window {win.t0:g}–{win.t1:g} s, cost {fit.g.cost:.4g}); try another window "
                         f"(--start/--duration) or more iterations (--max-iterations)")


def _fix_integers(cfg: StructureConfig, wd: WindowData, fit: _Fit, opt: InitOptions,
                  keep_float: np.ndarray | None = None) -> _Fix:
    """b = line bias + λ·n: LAMBDA, ratio test and partial fixing (:func:`~cdgps_cli.estimation.ambiguity.resolve`)
    when the line biases are calibrated; segments marked in ``keep_float`` (after a half-cycle
    slip) are left out of the integer set (fixed on the marginal of the others)."""
    lam, m, n = cfg.wavelength_m, len(wd.segments), fit.prob.n
    line = np.array([cfg.antenna_line_bias_m[cfg.antenna_names.index(s["antenna"])]
                     - cfg.antenna_line_bias_m[cfg.master_index] for s in wd.segments])
    a_float = (fit.g.b - line) / lam
    fixed = np.zeros(m, dtype=bool)
    integers = np.rint(a_float).astype(np.int64)
    ratio, note = None, "integer fixing off"
    if opt.fix_integers and cfg.line_bias_calibrated:
        Pbb = fit.g.lin.P_end[n:, n:]
        Qa = Pbb / lam**2
        Qa = 0.5 * (Qa + Qa.T)
        sub = np.flatnonzero(~keep_float) if keep_float is not None and keep_float.any() else None
        with progress.bar(m if opt.partial else 1, "integer fixing (LAMBDA)", unit="subset") as bar:
            if sub is None:
                pf = resolve(a_float, Qa, opt.ratio_threshold, partial=opt.partial,
                             progress=lambda done, total: bar.update_to(done))
            else:
                pf = _resolve_subset(a_float, Qa, sub, opt, bar)
        ratio = full_set_ratio(pf)
        full_txt = pf["limit_message"] or f"ratio {ratio:.2f} < {opt.ratio_threshold:g}"
        if pf["n_fixed"] == m:
            fixed[:] = True
            integers = pf["integers"]
            note = f"all {m} integers fixed (ratio {ratio:.2f} ≥ {opt.ratio_threshold:g})"
        elif pf["n_fixed"]:
            fixed = np.asarray(pf["fixed_mask"], dtype=bool)
            integers = np.where(fixed, pf["integers"], integers)
            note = (f"{int(fixed.sum())} of {m} integers fixed by partial fixing (full set: "
                    f"{'ratio ' + format(ratio, '.2f') if ratio is not None else full_txt})")
        else:
            note = f"integers not fixed: {full_txt}"
        if keep_float is not None and keep_float.any():
            note = (note.replace("full set", "the set without them")
                    + f"; {int(keep_float.sum())} bias(es) after a half-cycle slip kept float")
    elif not cfg.line_bias_calibrated:
        note = "line biases not calibrated: float biases only"
    _say(opt, f"  {note}")
    return _Fix(line, a_float, fixed, integers, ratio, note)


def _resolve_subset(a_float: np.ndarray, Qa: np.ndarray, sub: np.ndarray, opt: InitOptions, bar) -> dict:
    """:func:`resolve` on the ambiguities ``sub`` (their marginal), mapped back to the full set
    (the others never fixed; the full set then counts as not fixed as a whole)."""
    m = a_float.size
    if sub.size == 0:
        return {"n_fixed": 0, "fixed_mask": np.zeros(m, dtype=bool), "integers": np.rint(a_float).astype(np.int64),
                "ratio_full_set": float("nan"), "limit_message": "every bias follows a half-cycle slip: none fixed"}
    pf = resolve(a_float[sub], Qa[np.ix_(sub, sub)], opt.ratio_threshold, partial=opt.partial,
                 progress=lambda done, total: bar.update_to(done))
    mask = np.zeros(m, dtype=bool)
    mask[sub] = np.asarray(pf["fixed_mask"], dtype=bool)
    ints = np.rint(a_float).astype(np.int64)
    ints[sub] = pf["integers"]
    return dict(pf, fixed_mask=mask, integers=ints, n_fixed=int(mask.sum()))


def _fixed_solution(cfg: StructureConfig, win: _Window, fit: _Fit, fix: _Fix, opt: InitOptions) -> _Final:
    """The states re-solved with the fixed integers, kept when the cost increase passes the fix
    validation (:func:`fix_validation`); otherwise (or with nothing fixed) the float solution."""
    g, prob, m = fit.g, fit.prob, len(win.wd.segments)
    float_final = _Final(g.x, g.lin, prob, g.cost, g.b.copy(), 0)
    if not fix.fixed.any():
        return float_final
    known = np.full(m, np.nan)
    known[fix.fixed] = fix.line[fix.fixed] + cfg.wavelength_m * fix.integers[fix.fixed]
    prob_f = _Problem(cfg, win.wd, prob.sig_c, opt.process_noise, known_bias=known, mp=fit.mp)
    n_obs = int(np.isfinite(prob.y).sum())
    dof_f = max(n_obs - prob.n_dyn - m, 1)     # (the multipath states have their own prior)
    n_fixed = int(fix.fixed.sum())
    gf, dJ, limit = prob_f.refit_fixed(g, g.b[~fix.fixed], opt, dof_f, n_fixed)
    if dJ > limit:
        _say(opt, f"  integer fix rejected by validation: cost increase {dJ:.1f} > {limit:.1f} "
                  f"(chi-square {opt.fix_validation_probability:g}, {n_fixed} dof, margin {opt.fix_validation_margin:g})")
        fix.note = f"integer fix rejected by validation (cost increase {dJ:.1f} > {limit:.1f}); float biases kept"
        fix.fixed[:] = False
        fix.integers = np.rint(fix.a_float).astype(np.int64)
        float_final.iterations = gf.iterations
        return float_final
    return _Final(gf.x, gf.lin, prob_f, gf.cost, prob_f.full_bias(gf.b), gf.iterations)


def _bias_records(wd: WindowData, fit: _Fit, fix: _Fix, final: _Final) -> list:
    """INIT.json's ``biases``: one entry per lock segment (``current``: the channel's last segment)."""
    m, n = len(wd.segments), fit.prob.n
    P = final.lin.P_end
    free_sigma = np.full(m, 0.0)
    if P is not None and final.prob.free.size:
        free_sigma[final.prob.free] = np.sqrt(np.diag(P[n:, n:]))
    bias_sigma = np.sqrt(np.diag(fit.g.lin.P_end[n:, n:]))
    last_seg = {(s["antenna"], s["transmitter"]): s_i for s_i, s in enumerate(wd.segments)}
    return [{"antenna": s["antenna"], "transmitter": s["transmitter"],
             "bias_m": float(final.bias_m[s_i]),
             "sigma_m": float(free_sigma[s_i] if not fix.fixed[s_i] else 0.0),
             "float_bias_m": float(fit.g.b[s_i]), "float_sigma_m": float(bias_sigma[s_i]),
             "integer_cycles": int(fix.integers[s_i]), "float_cycles": float(fix.a_float[s_i]),
             "line_bias_m": float(fix.line[s_i]), "fixed": bool(fix.fixed[s_i]),
             "segment_start_s": s["start_s"], "segment_end_s": s["end_s"],
             "current": last_seg[(s["antenna"], s["transmitter"])] == s_i}
            for s_i, s in enumerate(wd.segments)]


def _init_record(run: Run, win: _Window, race: _Race, fit: _Fit, fix: _Fix, final: _Final, opt: InitOptions) -> dict:
    """The INIT.json dictionary (``iterations`` and ``elapsed_s`` filled in by :func:`initialize`)."""
    cfg, wd = run.cfg, win.wd
    N, nd, sig_c = len(wd.time_s), fit.prob.n_dyn, fit.prob.sig_c
    resid = final.prob.residual(final.x, final.bias_m[final.prob.free] if final.prob.free.size else np.zeros(0))
    res_rms = {f"{a}/{t}": float(np.sqrt(np.nanmean(resid[:, c] ** 2))) if np.isfinite(resid[:, c]).any() else None
               for c, (a, t) in enumerate(wd.channels)}
    P = final.lin.P_end
    Pxx = P[:nd, :nd] if P is not None else None
    x_end = final.x[-1][:nd]
    mp_out = _multipath_record(fit.mp, wd, final.x[-1], P, nd)
    if fit.auto_mp is not None:
        mp_out["source"] = "estimated from the white-noise fit's residual autocovariance (no multipath option given)"
        mp_out["evidence"] = fit.auto_mp
    q_end = np.asarray(cfg.mode_shapes) @ x_end[:cfg.n_modes]
    dof = max(int(np.isfinite(resid).sum()) - nd - int(final.prob.free.size), 1)
    return {
        "format": INIT_FORMAT, "kind": "structure", "config": cfg.name, "config_sha256": cfg.sha256, "run": run.path,
        "window": {"start_s": float(wd.time_s[0]), "end_s": float(wd.time_s[-1]), "epochs": N, "selection": win.how,
                   "motion_rms_m": win.motion_m, "channels": len(wd.channels), "bias_segments": len(wd.segments)},
        "biases": _bias_records(wd, fit, fix, final),
        "state": {
            "time_s": float(wd.time_s[-1]),
            "state_names": [f"xi_{k}" for k in cfg.mode_names] + [f"xidot_{k}" for k in cfg.mode_names],
            "x": [float(v) for v in x_end],
            "P": [[float(v) for v in row] for row in Pxx] if Pxx is not None else None,
            "q": {name: float(v) for name, v in zip(cfg.coord_names, q_end)},
        },
        "iterations": None,
        "converged": True,
        "starts": [{"label": lab, "cost": float(r.cost), "iterations": r.iterations, "won": i == race.best_i,
                    "full_window_cost": (float(race.final_costs[i]) if i in race.final_costs else None),
                    "full_window": race.outcome.get(i)}
                   for i, (lab, r) in enumerate(race.results)],
        "cost": float(final.cost),
        "cost_per_dof": float(final.cost / dof),
        "ratio": None if fix.ratio is None else (float(fix.ratio) if np.isfinite(fix.ratio) else "inf"),
        "integer_fixing": fix.note,
        "n_fixed": int(fix.fixed.sum()),
        "residual_rms_m": res_rms,
        "sigma_m": float(np.sqrt(np.mean(sig_c**2))),
        "sigma_m_per_channel": {f"{a}/{t}": float(v) for (a, t), v in zip(wd.channels, sig_c)},
        "noise": fit.noise,
        **({"multipath": mp_out} if mp_out is not None else {}),
        "options": opt.echo(),
        "elapsed_s": None,
    }


def _auto_multipath(cfg, wd, prob, g, prior, noise, opt):
    """With no multipath option (and none in the config), test the white-noise fit's residuals (at the
    prior σ) for
    time correlation (:func:`~cdgps_cli.measurement.multipath.fit_autocovariance`: pooled Ljung–Box
    and a Gauss–Markov + white autocovariance fit).  When detected, refit the whole window with the
    fitted Gauss–Markov state per channel, from the white solution (no new cold start), and
    re-estimate the white σ per channel with it.  Returns (problem, solution, noise report, model,
    evidence for INIT.json or None)."""
    off = MultipathModel(0.0)
    fit = fit_autocovariance(prob.residual(g.x, g.b), wd.segment, cfg.sample_period_s)
    if fit is None:
        return prob, g, noise, off, None
    _say(opt, f"  multipath check: Ljung–Box Q {fit['ljung_box_q']:.0f} (limit {fit['ljung_box_limit']:.0f}, "
              f"{fit['ljung_box_dof']} dof), fitted Gauss–Markov σ {fit['raw_sigma_m'] * 1000:.2f} mm τ "
              f"{fit['raw_time_constant_s']:.3g} s, white σ {fit['white_sigma_m'] * 1000:.2f} mm: "
              f"{'time-correlated' if fit['detected'] else 'no multipath model'}")
    if not fit["detected"]:
        return prob, g, noise, off, None
    mp = MultipathModel(fit["sigma_m"], fit["time_constant_s"])
    N, C = g.x.shape[0], len(wd.channels)
    p2 = _Problem(cfg, wd, prior, opt.process_noise, mp=mp)
    x0 = np.hstack([g.x, np.zeros((N, C))])
    w0 = np.hstack([g.w, np.zeros((N - 1, C))])
    g2 = p2.gauss_newton(x0, g.b, opt.max_iterations, opt, w_init=w0)
    if opt.estimate_sigma and opt.sigma_m is None:
        p2, g2, noise = _estimate_noise(cfg, wd, p2, g2, prior, opt)
    else:
        noise = dict(noise, warnings=list(noise["warnings"]))
    noise["warnings"].insert(0, (
        f"time-correlated phase residuals (multipath?): pooled Ljung–Box Q = {fit['ljung_box_q']:.0f} > "
        f"{fit['ljung_box_limit']:.0f} ({fit['ljung_box_dof']} dof, lags {', '.join(f'{v:g}' for v in fit['lags_s'])} s); "
        f"modelled as a Gauss–Markov state per channel with σ {mp.sigma_m * 1000:.2f} mm, τ "
        f"{mp.time_constant_s:.3g} s estimated from the residual autocovariance "
        f"(--multipath-sigma-m 0 to switch it off, or give the values)"))
    return p2, g2, noise, mp, fit


def _multipath_record(mp: MultipathModel, wd: WindowData, z_end: np.ndarray, P, nd: int) -> dict | None:
    """INIT.json's ``multipath`` object: the model and, at the window end, each channel's
    Gauss–Markov state (m), its covariance (m²) and its cross-covariance with the structure state."""
    if not mp.active:
        return None
    C = len(wd.channels)
    rec = dict(mp.echo(), model="first-order Gauss–Markov per channel",
               channels=[f"{a}/{t}" for a, t in wd.channels], x_m=[float(v) for v in z_end[nd:nd + C]])
    if P is not None:
        rec["P_m2"] = [[float(v) for v in row] for row in P[nd:nd + C, nd:nd + C]]
        rec["cross_P"] = [[float(v) for v in row] for row in P[:nd, nd:nd + C]]
    return rec


NOISE_ITERATIONS = 2            # re-weightings of the batch with the estimated per-channel σ
SIGMA_WARN_FACTOR = 1.5         # estimated σ this much above/below the prior → warning
CHANNEL_WARN_RATIO = 2.0        # a channel's σ̂ this much above the median of all → warning


def _estimate_noise(cfg, wd, prob, g, prior, opt):
    """Per-channel σ from the batch's variance factors (redundancy numbers), re-weighted
    NOISE_ITERATIONS times; a channel far beyond the others (an unflagged slip, a broken
    channel) is refused.  Returns (problem, solution, noise report for INIT.json)."""
    sig = prior.copy()
    for _ in range(NOISE_ITERATIONS):
        lev = prob.leverage(g.x)
        resid = prob.residual(g.x, g.b)
        vf = variance_factors(resid, prob.sig_c, lev)
        new = np.where(vf["n_obs"] > 0, vf["sigma_m"], sig)
        sig = np.maximum(new, 1e-5)
        prob = _Problem(cfg, wd, sig, opt.process_noise, mp=prob.mp)
        g = prob.gauss_newton(g.x, g.b, opt.max_iterations, opt, w_init=g.w)
    names = [f"{a}/{t}" for a, t in wd.channels]
    med = float(np.median(sig))
    rms_est, rms_prior = float(np.sqrt(np.mean(sig**2))), float(np.sqrt(np.mean(prior**2)))
    warnings = []
    f = rms_est / rms_prior
    if f > SIGMA_WARN_FACTOR or f < 1 / SIGMA_WARN_FACTOR:
        warnings.append(f"measurement noise estimated from the data is {rms_est * 1000:.2f} mm, {f:.2f} × the "
                        f"config's {rms_prior * 1000:.2f} mm: the estimate is used (--sigma-m to override)")
    ratio = sig / med
    bad = np.flatnonzero(ratio > CHANNEL_WARN_RATIO)
    resid = prob.residual(g.x, g.b)
    if bad.size and len(sig) >= 3:
        worst = bad[np.argsort(-ratio[bad])]
        own = _unshared_ratio(wd.channels, sig)
        detail = ", ".join(f"{names[c]} {sig[c] * 1000:.1f} mm ({ratio[c]:.1f}×"
                           f"{'' if own[c] > CHANNEL_WARN_RATIO else ', shared by its antenna or transmitter'})"
                           f"{_step_note(wd, resid, c)}" for c in worst[:6])
        if own[worst].max() > opt.sigma_refuse_ratio:
            raise CdgpsError(
                f"batch fit inconsistent in the window {wd.time_s[0]:g}–{wd.time_s[-1]:g} s: channel residuals far "
                f"beyond the others' noise (median {med * 1000:.2f} mm): {detail}. This is not measurement "
                f"noise (an unflagged cycle slip or a broken channel?); initialize on another window "
                f"(--start/--duration) or give --sigma-m to accept it")
        warnings.append(f"channels with noise well above the others (median {med * 1000:.2f} mm): {detail}")
    per = [{"channel": names[c], "sigma_m": float(sig[c]), "prior_sigma_m": float(prior[c]),
            "variance_factor": float(vf["variance_factor"][c]), "redundancy": float(vf["redundancy"][c]),
            "observations": int(vf["n_obs"][c]), "residual_rms_m": float(vf["rms_m"][c])}
           for c in range(len(sig))]
    # the warnings travel in the result (INIT.json "noise"); the CLI prints them once
    return prob, g, {"source": "estimated (batch variance factors with redundancy numbers)",
                     "sigma_m": rms_est, "prior_sigma_m": rms_prior, "median_sigma_m": med,
                     "iterations": NOISE_ITERATIONS, "per_channel": per, "warnings": warnings}


def _unshared_ratio(channels, sig: np.ndarray) -> np.ndarray:
    """(C,) each channel's σ̂ over the larger of the medians of the other channels of its antenna and of
    its transmitter (and never above its ratio to the median of all channels).

    Noise that a whole antenna (or transmitter) shares is noise — an antenna 5× noisier than the
    others has all its channels high, so each is ≈ 1× its antenna's others.  A single channel far
    above both of its groups is not explained by per-antenna or per-transmitter noise (an
    unflagged slip, a broken channel): that is what init refuses."""
    sig = np.asarray(sig, dtype=float)
    ant = np.array([a for a, _ in channels], dtype=object)
    tx = np.array([t for _, t in channels], dtype=object)
    med = float(np.median(sig))
    out = sig / med
    for c in range(len(sig)):
        ref = med
        for same in (ant == ant[c], tx == tx[c]):
            others = same.copy()
            others[c] = False
            if others.sum() >= 2:
                ref = max(ref, float(np.median(sig[others])))
        out[c] = sig[c] / ref
    return out


def _step_note(wd, resid, c) -> str:
    """' step 4.1 cm at 23.4 s' when the channel's residuals have a step larger than their spread."""
    e = resid[:, c]
    ok = np.flatnonzero(np.isfinite(e))
    if ok.size < 20:
        return ""
    v = e[ok]
    cs = np.cumsum(v)
    k = np.arange(5, v.size - 5)
    d = cs[-1] / v.size
    diff = cs[k - 1] / k - (cs[-1] - cs[k - 1]) / (v.size - k)
    j = int(np.argmax(np.abs(diff)))
    step = float(diff[j])
    if abs(step) < 3 * float(np.std(v - d)) * 0.5:
        return ""
    return f", residual step {abs(step) * 100:.1f} cm at {wd.time_s[ok[k[j]]]:g} s"


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
