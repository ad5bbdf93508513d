"""The pseudolite / far-field single-difference filter as :func:`cdgps_cli.estimation.driver.drive`
sees it: its measurement model (:class:`PhaseRows`, rows linearized at the prediction) and its
integrity hooks, in the order the driver calls them each epoch (Teague, How & Parkinson 1998; the
1995 paper's Fig. 7 for the re-initialization):

* :class:`LockRestart` (``before_rows``) — first sightings, lock restarts and re-acquisitions
  (precomputed lock events): the channel's bias is dropped and re-estimated, or its bias state's
  variance inflated;
* :class:`cdgps_cli.estimation.rest.StaticMode` (``before_rows``) — rest mode, the zero-velocity update;
* :class:`NewBiasStates` and :class:`Rebias` (``prepared``) — a bias state started from the
  prediction; the dropped biases re-estimated over ``rebias_epochs`` (integer re-fixed when
  unambiguous);
* :class:`OutlierGate` (``gate``) — the per-channel normalized-innovation test;
* :class:`PostFit` (``updated``) — post-fit residuals and the NIS test's failure count;
* :class:`Reinit` (``after``) — batch re-initialization after persistent NIS failures.

Every hook reads and changes the pass's shared state ``fp`` (a
:class:`cdgps_cli.estimation.filter._ForwardPass`: biases, the channels being re-biased, the event
log, the extra process noise the smoother must know).  The arithmetic is the one the filter had
before it was split (same operations in the same order: STATES are bit-identical,
tests/estimation/test_estimate_golden.py).
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.chi2 import chi2_quantile
from cdgps_cli.estimation.driver import Hook
from cdgps_cli.measurement.model import MeasurementModel, Rows

__all__ = ["PhaseRows", "EpochDynamics", "LockRestart", "NewBiasStates", "Rebias", "OutlierGate", "PostFit",
           "Reinit", "drop_bias", "bias_rows", "reinitialize"]


def bias_rows(Hx: np.ndarray, idx: np.ndarray, p: int, n: int, use_bias_states: bool, mp0: int | None) -> np.ndarray:
    """Measurement Jacobian (len(idx), p) of channels ``idx`` over the filter's state: the structure's
    Hx (C, n), a 1 on the channel's bias state (``use_bias_states``) and on its multipath state (at
    ``mp0`` + channel, when modelled).  Without either it is Hx[idx] itself (p = n)."""
    if not use_bias_states and mp0 is None:
        return Hx[idx]
    H = np.zeros((idx.size, p))
    H[:, :n] = Hx[idx]
    rows = np.arange(idx.size)
    if use_bias_states:
        H[rows, n + idx] = 1.0
    if mp0 is not None:
        H[rows, mp0 + idx] = 1.0
    return H


class EpochDynamics:
    """The modal ZOH transition of the pass (bias and multipath states appended): into epoch k, A, the
    process noise of k (the rest one inside a rest stretch, read live: the rest hook may end it) and
    the thruster input B u_{k−1}."""

    identity = False

    def __init__(self, fp):
        self.fp = fp

    def step_into(self, k: int):
        fp = self.fp
        return fp.A, (fp.Qd_rest if fp.at_rest[k] else fp.Qd), fp.Bu @ fp.U_in[k - 1]


class PhaseRows(MeasurementModel):
    """The single differences of the pass: ``prepare`` evaluates h(x̄), H at the prediction once per
    epoch (unless the rest checks did at the same state) and takes the usable channels (present, with
    a bias); ``rows`` gives the innovation ρ = Δφ − h(x̄) − bias (− multipath) of those channels with
    their σ, linearized at x̄ (``predict``: H (x − x̄), H), so the driver's update is the EKF's."""

    def __init__(self, fp):
        self.fp = fp
        self.n_epochs, self.n_state, self.segment_keys = fp.N, fp.p, []

    def prepare(self, k: int, ctx) -> None:
        fp = self.fp
        y = fp.Y[k]
        self.present = ~np.isnan(y)
        self.xq = xq = ctx.x[:fp.n]
        if fp.hx_at is None or not np.array_equal(fp.hx_at, xq):    # (the rest checks evaluated it already)
            fp.h, fp.Hx = fp.meas.predict(xq, fp.all_channels)
        fp.hx_at = None
        self.usable = self.present.copy() if fp.use_bias_states else self.present & ~np.isnan(fp.bias)

    def rows(self, k: int) -> Rows | None:
        fp = self.fp
        idx = np.flatnonzero(self.usable)
        if not idx.size:
            return None
        n, mp0, x = fp.n, fp.mp0, fp.x
        H = bias_rows(fp.Hx, idx, fp.p, n, fp.use_bias_states, mp0)
        b_used = x[n + idx] if fp.use_bias_states else fp.bias[idx]
        if mp0 is not None:
            b_used = b_used + x[mp0 + idx]
        rho = fp.Y[k][idx] - fp.h[idx] - b_used
        self.xbar = x
        return self.make_rows(idx, H, rho)

    def make_rows(self, idx, H, rho) -> Rows:
        fp = self.fp
        return Rows(rho, [fp.chans[c] for c in idx], np.full(idx.size, -1, dtype=np.int64),
                    sigma_m=fp.sig_c[idx], context=(idx, H))

    def predict(self, x, rows: Rows):
        H = rows.context[1]
        return H @ (x - self.xbar), H


def drop_bias(fp, k: int, c: int, kind: str) -> None:
    """A channel's bias is no longer trusted (restart, outlier): re-estimate it, or inflate its state."""
    opt = fp.opt
    if fp.use_bias_states:
        # the 1995 variant: the bias state absorbs the jump; its variance is inflated as extra
        # process noise at this epoch (recorded so that the smoother stays exact)
        q = opt.restart_sigma_cycles**2 * fp.lam**2
        fp.P[fp.n + c, fp.n + c] += q
        fp.extra_q.setdefault(k, []).append((fp.n + c, q))
        fp.log(k, c, kind, f"bias state variance inflated by ({opt.restart_sigma_cycles:g} cycles)²")
        return
    fp.bias[c] = np.nan
    fp.rebias[c] = []
    fp.log(k, c, kind, f"bias dropped; re-estimating over {opt.rebias_epochs} epochs")


class LockRestart(Hook):
    """Lock restarts (slips, re-acquisitions) and first sightings (precomputed, rare)."""

    def __init__(self, fp):
        self.fp = fp

    def before_rows(self, ctx, k: int) -> None:
        fp = self.fp
        for c in np.flatnonzero(fp.EVENT[k]):
            if fp.EVENT[k, c] == 1:
                if np.isnan(fp.bias[c]) and not fp.use_bias_states:
                    fp.rebias.setdefault(c, [])
                    fp.log(k, c, "new channel", "no INIT bias; estimating")
                elif np.isnan(fp.bias[c]) and fp.use_bias_states:
                    fp.new_states.append(c)
            else:
                drop_bias(fp, k, c, "lock restart" if fp.EVENT[k, c] == 2 else "re-acquisition")


class NewBiasStates(Hook):
    """A channel INIT did not know (biases="states"): its bias state starts from the prediction."""

    def __init__(self, fp):
        self.fp = fp

    def prepared(self, ctx, k: int) -> None:
        fp = self.fp
        opt, n, lam, y = fp.opt, fp.n, fp.lam, fp.Y[k]
        for c in fp.new_states:
            q_new = opt.restart_sigma_cycles**2 * lam**2
            fp.x[n + c] = y[c] - fp.h[c]
            q_was = float(fp.P[n + c, n + c])          # never measured: no cross terms to drop
            fp.P[n + c, :] = 0.0
            fp.P[:, n + c] = 0.0
            fp.P[n + c, n + c] = q_new
            fp.bias[c] = fp.x[n + c]
            fp.extra_q.setdefault(k, []).append((n + c, q_new - q_was))    # the smoother's prior = the filter's
            fp.log(k, c, "new channel", f"bias state initialized from the prediction (sigma {opt.restart_sigma_cycles:g} cycles)")
        fp.new_states = []


class Rebias(Hook):
    """Channels being re-biased: collect y − h(x̄); after ``rebias_epochs``, set the bias (re-fix the
    integer when the float is unambiguous)."""

    def __init__(self, fp):
        self.fp = fp

    def prepared(self, ctx, k: int) -> None:
        fp = self.fp
        n, mp0, P, x, y = fp.n, fp.mp0, fp.P, fp.x, fp.Y[k]
        for c in list(fp.rebias):
            if np.isnan(y[c]):
                continue
            var_h = float(fp.Hx[c] @ P[:n, :n] @ fp.Hx[c])
            m_c = 0.0
            if mp0 is not None:                # the channel's multipath state is predicted, not a bias
                m_c = float(x[mp0 + c])
                var_h += float(P[mp0 + c, mp0 + c] + 2.0 * fp.Hx[c] @ P[:n, mp0 + c])
            fp.rebias[c].append((y[c] - fp.h[c] - m_c, var_h))
            if len(fp.rebias[c]) >= fp.opt.rebias_epochs:
                self._set(k, c)

    def _set(self, k: int, c: int) -> None:
        fp = self.fp
        opt, cfg, lam, n = fp.opt, fp.cfg, fp.lam, fp.n
        vals = np.array([v for v, _ in fp.rebias[c]])
        est = float(vals.mean())
        s_b = float(np.sqrt(fp.r_var[c] / len(vals) + np.mean([v for _, v in fp.rebias[c]])))
        a = (est - fp.line[c]) / lam
        nint = int(np.rint(a))
        if (cfg.line_bias_calibrated and s_b / lam < opt.refix_max_sigma_cycles
                and abs(a - nint) < min(opt.refix_max_offset_cycles, 3.0 * s_b / lam)):
            est = fp.line[c] + lam * nint
            action = f"integer re-fixed: {nint} cycles (float {a:.3f}, sigma {s_b / lam:.3f} cycle)"
        else:
            action = f"float bias {est:.4f} m (sigma {s_b / lam:.3f} cycle)"
        fp.bias[c] = est
        if fp.use_bias_states:
            fp.x[n + c] = est
            fp.P[n + c, :] = 0.0
            fp.P[:, n + c] = 0.0
            fp.P[n + c, n + c] = s_b**2
        del fp.rebias[c]
        fp.log(k, c, "bias re-estimated", action)


class OutlierGate(Hook):
    """Per-channel test of the normalized innovation: outliers (fewer than half the rows) drop their
    bias (with fixed biases their rows leave this update; a bias state keeps them)."""

    def __init__(self, fp):
        self.fp = fp

    def gate(self, ctx, k: int, model, rows):
        fp = self.fp
        idx, H = rows.context
        rho = rows.z_m
        S_diag = np.sum((H @ fp.P) * H, axis=1) + fp.r_var[idx]
        z = rho / np.sqrt(S_diag)
        out = np.flatnonzero(np.abs(z) > fp.opt.outlier_sigma)
        if out.size and out.size < idx.size // 2 + 1:
            worst = out[np.argsort(-np.abs(z[out]))]
            for j in worst:
                drop_bias(fp, k, int(idx[j]), "innovation outlier")
                fp.events[-1]["normalized_innovation"] = float(z[j])
            if not fp.use_bias_states:
                keep = np.setdiff1d(np.arange(idx.size), worst)
                if not keep.size:
                    return None
                rows = model.make_rows(idx[keep], H[keep], rho[keep])
        trace = fp.trace
        if trace is not None:
            trace.setdefault("prior", {})[k] = fp.P.copy()
        return rows


class PostFit(Hook):
    """After the update: post-fit residuals (the filtered state, the Jacobian at x̄) and the NIS test
    (consecutive failures count towards a re-initialization)."""

    def __init__(self, fp, model: PhaseRows):
        self.fp, self.model = fp, model

    def updated(self, ctx, k: int, model, rows, nis: float) -> None:
        fp, m = self.fp, self.model
        idx = rows.context[0]
        n, mp0, x, h, Hx, y = fp.n, fp.mp0, fp.x, fp.h, fp.Hx, fp.Y[k]
        fp.resid[k, idx] = (y[idx] - (h[idx] + Hx[idx] @ (x[:n] - m.xq))
                            - (x[n + idx] if fp.use_bias_states else fp.bias[idx]))
        if mp0 is not None:
            fp.resid[k, idx] -= x[mp0 + idx]
        bound = fp.chi2_bound.get(idx.size)
        if bound is None:
            bound = fp.chi2_bound[idx.size] = chi2_quantile(fp.opt.nis_probability, idx.size)
        fp.fail_run = fp.fail_run + 1 if fp.nis[k] > bound else 0


class Reinit(Hook):
    """After ``reinit_after_epochs`` NIS failures in a row, a batch re-initialization on a window after k
    (1995 Fig. 7); the epochs of that window take the batch solution and the filter restarts at its end."""

    def __init__(self, fp):
        self.fp = fp

    def after(self, ctx, k: int, k_next: int) -> int:
        fp = self.fp
        opt = fp.opt
        if not (fp.fail_run >= opt.reinit_after_epochs and k > fp.k_reinit_block):
            return k_next
        k_new = reinitialize(fp.run_, fp.grid, k, opt, fp.sigma, fp.chans, fp.log, fp.mp)
        fp.fail_run = 0
        if k_new is None:
            fp.k_reinit_block = k + int(opt.reinit_window_s / fp.T)
            return k_next
        kk, xr, Pr, new_bias, traj_t, traj_x = k_new
        self._fill_window(k, kk, Pr, traj_t, traj_x)
        for c, b in new_bias.items():
            fp.bias[c] = b
            fp.rebias.pop(c, None)
        n, C, p, mp0 = fp.n, fp.C, fp.p, fp.mp0
        fp.x = np.zeros(p)
        fp.x[:n] = xr
        fp.P = np.zeros((p, p))
        fp.P[:n, :n] = Pr
        if fp.use_bias_states:
            fp.x[n:n + C] = np.nan_to_num(fp.bias)
            fp.P[n:n + C, n:n + C] = np.eye(C) * 1e-8
        if fp.mp.active:                  # the multipath states restart from their stationary prior
            fp.P[mp0:, mp0:] = np.eye(C) * fp.mp.sigma_m**2
        fp.k_reinit_block = kk + opt.reinit_after_epochs
        fp.rest_stretch_end, fp.rest_fail = -1, 0    # a rest stretch in progress is entered afresh
        fp.xs[kk] = fp.x
        fp.Ps[kk] = fp.P
        return kk + 1

    def _fill_window(self, k, kk, Pr, traj_t, traj_x) -> None:
        """Epochs k+1 … kk−1 take the batch solution (smoothed over the re-initialization window)."""
        fp = self.fp
        n, C, p, mp0 = fp.n, fp.C, fp.p, fp.mp0
        for j in range(k + 1, kk):
            xj = np.zeros(p)
            ti = int(np.argmin(np.abs(traj_t - fp.grid[j])))
            xj[:n] = traj_x[ti]
            if fp.use_bias_states:
                xj[n:n + C] = fp.xs[k, n:n + C]
            fp.xs[j] = xj
            fp.Ps[j] = np.zeros((p, p))
            fp.Ps[j][:n, :n] = Pr
            if fp.use_bias_states:
                fp.Ps[j][n:n + C, n:n + C] = fp.Ps[k][n:n + C, n:n + C]
            if fp.mp.active:
                fp.Ps[j][mp0:, mp0:] = np.eye(C) * fp.mp.sigma_m**2
        fp.no_link[k:kk] = True


def reinitialize(run, grid, k, opt, sigma, chans, log, mp=None):
    """Batch re-initialization on a window after epoch k (1995 paper, Fig. 7): (first epoch after the
    window, x, P, {channel: bias}, the window's times and states), or None (logged why)."""
    from cdgps_cli.estimation.initializer import InitOptions, initialize

    t0 = float(grid[k])
    t1 = min(t0 + opt.reinit_window_s, float(grid[-1]))
    log(k, None, "integrity failure", f"{opt.reinit_after_epochs} consecutive NIS failures; batch re-initialization on {t0:g}–{t1:g} s")
    if t1 - t0 < 5.0:
        log(k, None, "re-initialization", "skipped: not enough data left")
        return None
    try:
        mp_opt = {} if mp is None else {"multipath_sigma_m": mp.sigma_m, "multipath_time_constant_s": mp.time_constant_s}
        res, traj = initialize(run, InitOptions(start_s=t0, duration_s=t1 - t0, sigma_m=sigma, starts=8, **mp_opt),
                               return_trajectory=True)
    except CdgpsError as exc:
        log(k, None, "re-initialization", f"failed: {exc}")
        return None
    kk = int(round((res["state"]["time_s"] - grid[0]) / (grid[1] - grid[0]))) if len(grid) > 1 else k
    new_bias = {}
    cidx = {c: i for i, c in enumerate(chans)}
    for b in res["biases"]:
        if b["current"] and (b["antenna"], b["transmitter"]) in cidx:
            new_bias[cidx[(b["antenna"], b["transmitter"])]] = b["bias_m"]
    log(kk, None, "re-initialization", f"filter restarted at {grid[kk]:g} s from the batch solution "
        f"({res['n_fixed']} integers fixed)")
    return kk, np.asarray(res["state"]["x"]), np.asarray(res["state"]["P"]), new_bias, traj["time_s"], traj["x"]
