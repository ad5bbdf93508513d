"""Rest (static mode) of the structure filter: the zero-velocity hook of the driver, and the rest
segments found from the data (``cdgps estimate --rest auto``).

Static mode (:class:`StaticMode`, a hook of :func:`cdgps_cli.estimation.driver.drive` run by
:func:`cdgps_cli.estimation.filter.estimate`): inside a declared (or detected) rest segment the
prediction uses the rest process noise; entering a rest stretch the modal velocities are tested and,
when they are zero, observed as zero (:func:`zero_velocity_update`) after the modal position
variances are raised; the data may contradict rest (:func:`rest_motion`: two outlying channels,
or NIS failures in a row), which breaks the stretch (kinematic from the entry's kinematic prior,
retried ``rest_retry_s`` later).  Every change of the prior is recorded as extra process noise so
that the smoother stays exact.

Detection (``--rest auto``):

A zero-velocity test on the estimated modal velocities of a kinematic filter pass, with hysteresis,
gives the segments on which the static mode of :func:`cdgps_cli.estimation.filter.estimate` (entry test,
zero-velocity update, reduced process noise, breaks and retries) then runs.

The test, per epoch k (modal velocities v̂_k = x̂_k[nm:2nm] with the filter's covariance P_vv,k):

    d_k   = v̂_kᵀ P_vv,k⁻¹ v̂_k                         (chi-square, nm dof, if the velocities are zero)
    D_k   = Σ_{j = k−W+1 … k} d_j                      (sliding window of W epochs, W·nm dof)
    pass  : D_k ≤ χ²_{p_enter}(W·nm)       fail : D_k > χ²_{p_leave}(W·nm)      (p_leave > p_enter)

Hysteresis: rest is entered once the test has passed on every epoch of a dwell of ``dwell_s``
seconds; the segment is dated from the first epoch of that run of passes (``estimate`` is
post-processing: the detector may look back over its dwell).  Rest is left at the first epoch whose
window fails the (higher) leave bound; the segment ends on the epoch before.  A statistic that
chatters between the two bounds therefore never toggles the state, and one that chatters around the
entry bound in runs shorter than the dwell never enters.  Epochs without a full window (the record's
first W−1) neither pass nor fail; a non-finite d_k fails.

The kinematic pass weights the data with the measurement noise the data show (the batch's
a-posteriori σ = σ_INIT·√(cost/dof), or ``--sigma-m``), so the test's power does not depend on
a conservative σ in the config: with σ 10× too large every velocity looks small against P_vv.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from cdgps_cli.estimation.chi2 import chi2_quantile
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.estimation.driver import Hook
from cdgps_cli.estimation.integrity import bias_rows

REST_ENTER_PROBABILITY = 0.99        # window passes: D_k ≤ χ²_0.99(W·nm)
REST_LEAVE_PROBABILITY = 0.9999      # window fails (rest is left): D_k > χ²_0.9999(W·nm)


def velocity_nis_series(v: np.ndarray, P_vv: np.ndarray) -> np.ndarray:
    """Per-epoch zero-velocity statistic d_k = v_kᵀ P_k⁻¹ v_k.

    Parameters
    ----------
    v : (N, nm) modal velocities (sqrt(kg)·m/s)
    P_vv : (N, nm, nm) their covariance

    Returns
    -------
    (N,) float: chi-square with nm dof when the velocities are zero; inf where P_k is not positive
    definite or an entry is not finite.
    """
    v = np.asarray(v, dtype=float)
    P = np.asarray(P_vv, dtype=float)
    if v.ndim != 2 or P.shape != (v.shape[0], v.shape[1], v.shape[1]):
        raise CdgpsError(f"velocity_nis_series: expected v (N, nm) and P_vv (N, nm, nm), got {v.shape} and {P.shape}")
    d = np.full(len(v), np.inf)
    ok = np.isfinite(v).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
    if ok.any():
        try:
            L = np.linalg.cholesky(P[ok])
            w = np.linalg.solve(L, v[ok][..., None])[..., 0]
            d[ok] = np.einsum("ni,ni->n", w, w)
        except np.linalg.LinAlgError:                 # some P_k not PD: epoch by epoch
            for k in np.flatnonzero(ok):
                try:
                    w = np.linalg.solve(np.linalg.cholesky(P[k]), v[k])
                    d[k] = float(w @ w)
                except np.linalg.LinAlgError:
                    pass
    return d


def window_sums(d: np.ndarray, W: int) -> np.ndarray:
    """Trailing sums D_k = d_{k−W+1} + … + d_k, (N,); NaN for k < W−1, inf when a term is inf."""
    d = np.asarray(d, dtype=float)
    N = len(d)
    out = np.full(N, np.nan)
    if N < W:
        return out
    bad = ~np.isfinite(d)
    c = np.concatenate([[0.0], np.cumsum(np.where(bad, 0.0, d))])
    nb = np.concatenate([[0], np.cumsum(bad)])
    out[W - 1:] = c[W:] - c[:-W]
    out[W - 1:][(nb[W:] - nb[:-W]) > 0] = np.inf
    return out


def validate_detector(window_s, dwell_s, T: float) -> tuple[int, int]:
    """(W, dwell) in epochs from ``--rest-window-s`` / ``--rest-dwell-s``; CdgpsError when not valid."""
    for name, v in (("--rest-window-s", window_s), ("--rest-dwell-s", dwell_s)):
        if (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                or not (np.isfinite(v) and v > 0)):
            raise CdgpsError(f"{name} must be a positive number of seconds, got {v!r}")
    return max(int(round(window_s / T)), 1), max(int(round(dwell_s / T)), 1)


def detect_rest(time_s: np.ndarray, d: np.ndarray, nm: int, window: int, dwell: int,
                p_enter: float = REST_ENTER_PROBABILITY, p_leave: float = REST_LEAVE_PROBABILITY
                ) -> tuple[list[tuple[float, float]], list[dict]]:
    """Rest segments from a per-epoch zero-velocity statistic, with hysteresis.

    Parameters
    ----------
    time_s : (N,) epoch times, s
    d : (N,) per-epoch statistic (:func:`velocity_nis_series`), chi-square with ``nm`` dof at rest
    nm : dof of one epoch (number of modes)
    window : W, epochs in the sliding window
    dwell : epochs the window test must pass, every one, before rest is entered
    p_enter, p_leave : chi-square probabilities of the pass and fail bounds (p_leave ≥ p_enter)

    Returns
    -------
    segments : [(start_s, end_s)], end_s = inf for a segment still open at the record's end
    events : event dicts (time_s, antenna "", transmitter "", kind, action, velocity_chi2, dof, bound)
    """
    if not 0.5 <= p_enter <= p_leave < 1.0:
        raise CdgpsError(f"detect_rest: expected 0.5 <= p_enter <= p_leave < 1, got {p_enter!r}, {p_leave!r}")
    t = np.asarray(time_s, dtype=float)
    D = window_sums(d, window)
    dof = window * nm
    b_in, b_out = float(chi2_quantile(p_enter, dof)), float(chi2_quantile(p_leave, dof))
    passes = D <= b_in                       # NaN (no full window) → False
    fails = ~(D <= b_out) & ~np.isnan(D)     # inf or above the leave bound
    segments, events = [], []
    win_s = window * (float(t[1] - t[0]) if len(t) > 1 else 0.0)

    def ev(k, kind, action, bound):
        e = {"time_s": float(t[k]), "antenna": "", "transmitter": "", "kind": kind, "action": action,
             "velocity_chi2": float(D[k]), "dof": int(dof), "bound": bound}
        if not np.isfinite(D[k]):
            del e["velocity_chi2"]           # (JSON has no infinity: a non-finite statistic is left out)
        events.append(e)

    k, N = 0, len(t)
    while k < N:
        # outside rest: find the next run of `dwell` consecutive passes
        run_start = None
        while k < N:
            if passes[k]:
                run_start = k if run_start is None else run_start
                if k - run_start + 1 >= dwell:
                    break
            else:
                run_start = None
            k += 1
        if k >= N:
            break
        k0 = run_start
        ev(k0, "rest detected", f"zero-velocity test passed from {t[k0]:g} s to {t[k]:g} s (dwell {dwell} epochs; "
           f"window {win_s:g} s, chi-square {D[k0]:.1f} <= {b_in:.1f} with {dof} dof): static mode from {t[k0]:g} s", b_in)
        # inside rest: until the window fails the leave bound
        k += 1
        while k < N and not fails[k]:
            k += 1
        if k >= N:
            segments.append((float(t[k0]), float("inf")))
            break
        segments.append((float(t[k0]), float(t[k - 1])))
        ev(k, "rest ended", f"zero-velocity test failed (chi-square {D[k]:.1f} > {b_out:.1f} with {dof} dof): "
           f"the structure moves; static mode until {t[k - 1]:g} s", b_out)
        k += 1
    return segments, events


def detection_sigma_m(init: dict, sigma_m: float | None, cfg) -> float:
    """Measurement noise of the detection pass: ``sigma_m`` if given, else the batch's a-posteriori
    σ_INIT·√(cost/dof), else INIT's (or the config's) σ."""
    if sigma_m is not None:
        return float(sigma_m)
    s0 = float(init.get("sigma_m") or cfg.measurement_sigma_m)
    c = init.get("cost_per_dof")
    if isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) and c > 0:
        return s0 * float(np.sqrt(c))
    return s0


def estimate_auto_rest(run, init: dict, opt):
    """``estimate`` with rest segments found from the data (``opt.rest_auto``).

    A forward kinematic pass (no rest, no smoothing, measurement σ from :func:`detection_sigma_m`)
    gives the modal velocities and their covariance; :func:`detect_rest` turns them into segments; the
    estimate is then run with ``opt`` and those segments (static mode there).  The detection events
    come first in the result's events at equal times; ``res.rest_detection`` records the settings,
    the σ used and the segments."""
    from cdgps_cli.estimation.filter import estimate

    if opt.rest_segments_s:
        raise CdgpsError("--rest auto cannot be combined with declared --rest START:END segments")
    cfg = run.cfg
    W, dwell = validate_detector(opt.rest_window_s, opt.rest_dwell_s, cfg.sample_period_s)
    nm = cfg.n_modes
    s_det = detection_sigma_m(init, opt.sigma_m, cfg)
    say = opt.progress or (lambda m: None)
    say(f"  rest detection: kinematic pass with sigma {s_det * 1000:.2f} mm")
    kin = estimate(run, init, replace(opt, rest_auto=False, smooth=False, sigma_m=s_det, channel_sigma_m=None,
                                      rest_segments_s=(),
                                      keep_filtered_covariance="modal", keep_covariance="full"))
    d = velocity_nis_series(kin.x[:, nm:2 * nm], kin.P[:, nm:2 * nm, nm:2 * nm])
    time_s = kin.time_s
    del kin
    segments, det_events = detect_rest(time_s, d, nm, W, dwell)
    say(f"  rest detection: {len(segments)} segment(s)" + "".join(
        f" {a:g}–{'end' if np.isinf(b) else format(b, 'g')} s" for a, b in segments))
    res = estimate(run, init, replace(opt, rest_auto=False, rest_segments_s=tuple(segments)))
    res.events = sorted(det_events + res.events, key=lambda e: e["time_s"])
    res.rest_detection = {"window_s": W * cfg.sample_period_s, "dwell_s": dwell * cfg.sample_period_s,
                          "enter_probability": REST_ENTER_PROBABILITY, "leave_probability": REST_LEAVE_PROBABILITY,
                          "sigma_m": s_det,
                          "segments_s": [[a, None if np.isinf(b) else b] for a, b in segments]}
    return res


def static_mode_coverage(metadata: dict, time_s: np.ndarray) -> dict:
    """Did the estimate run in static mode on the epochs ``time_s`` (a report's segment)?

    ``metadata``: STATES.mcap's ``cdgps.estimate`` record (``rest_active_s``: where static mode ran;
    ``options``: the ``--rest`` options).  Returns ``{"active_fraction", "active_s", "rest_option",
    "statement"}``; ``active_fraction`` is None when the file does not say (written by an older cdgps
    or by a GNSS estimate)."""
    import json

    t = np.asarray(time_s, dtype=float)
    try:
        opts = json.loads(metadata.get("options") or "{}")
    except (TypeError, ValueError):
        opts = {}
    declared = opts.get("rest_segments_s") or []
    option = "auto" if opts.get("rest_auto") else ("declared" if declared else "none")
    raw = metadata.get("rest_active_s")
    try:
        active = json.loads(raw) if raw is not None else None
    except (TypeError, ValueError):
        active = None
    span = f"{t[0]:.1f}–{t[-1]:.1f} s" if t.size else "the segment"
    if active is None:
        if option == "none" and "options" in metadata and "rest_segments_s" in opts:
            active = []                      # an older STATES without --rest: kinematic throughout
        else:
            return {"active_fraction": None, "active_s": None, "rest_option": option,
                    "statement": f"Static mode: the STATES metadata do not record where static mode ran "
                                 f"(--rest {option}); it is not known whether {span} was estimated at rest."}
    on = np.zeros(t.size, dtype=bool)
    for a, b in active:
        on |= (t >= float(a) - 1e-9) & (t <= float(b) + 1e-9)
    frac = float(on.mean()) if t.size else 0.0
    inside = [[float(max(a, t[0])), float(min(b, t[-1]))] for a, b in active
              if t.size and b >= t[0] - 1e-9 and a <= t[-1] + 1e-9]
    how = {"auto": "--rest auto: segments found from the data", "declared": "--rest START:END",
           "none": "no --rest"}[option]
    if option == "none":
        st = (f"Without static mode: the STATES were estimated without --rest, so {span} is the kinematic "
              f"filter's estimate (for a static test estimate with --rest auto or --rest START:).")
    elif frac == 0.0:
        st = (f"Without static mode on this segment: the estimate ran with {how}, but static mode was not "
              f"active anywhere in {span}" + (f" (it ran on {_spans(active)})." if active else " (never entered)."))
    elif frac < 1.0:
        st = (f"Static mode on {100 * frac:.0f} % of this segment only ({_spans(inside)}; {how}); the rest "
              f"of {span} is the kinematic filter's estimate.")
    else:
        st = f"Static mode on the whole segment {span} ({how})."
    return {"active_fraction": frac, "active_s": inside, "rest_option": option, "statement": st}


def _spans(iv) -> str:
    return ", ".join(f"{a:.1f}–{b:.1f} s" for a, b in iv)


# --------------------------------------------------------------------------------------------
# static mode: the driver's hook

REST_NIS_FAILURES = 3                      # NIS failures in a row that break a rest segment
REST_ENTRY_POSITION_INFLATION = 100.0      # entering rest: modal position variances × (1 + this)


def validate_rest_segments(segments, scale, retry_s=0.0) -> list[tuple[float, float]]:
    """Check ``rest_segments_s``, ``rest_process_noise_scale`` and ``rest_retry_s``; returns the
    segments as floats.

    Raises CdgpsError naming every bad segment (not finite, or end before start)."""
    if (isinstance(scale, bool) or not isinstance(scale, (int, float, np.integer, np.floating))
            or not (np.isfinite(scale) and scale > 0)):
        raise CdgpsError(f"--rest-process-noise-scale must be a positive number, got {scale!r}")
    if (isinstance(retry_s, bool) or not isinstance(retry_s, (int, float, np.integer, np.floating))
            or not (np.isfinite(retry_s) and retry_s >= 0)):
        raise CdgpsError(f"--rest-retry-s must be a number of seconds >= 0, got {retry_s!r}")
    out, bad = [], []
    for seg in segments or ():
        try:
            a, b = (float(v) for v in seg)
        except (TypeError, ValueError):
            bad.append(f"{seg!r} (expected START:END in seconds)")
            continue
        if not np.isfinite(a) or np.isnan(b) or b == -np.inf:
            bad.append(f"{a:g}:{b:g} (START must be a finite time, END finite or open)")
        elif b <= a:
            bad.append(f"{a:g}:{b:g} (END must be after START)")
        else:
            out.append((a, b))
    srt = sorted(out)
    bad += [f"{a0:g}:{b0:g} and {a1:g}:{b1:g} overlap" for (a0, b0), (a1, b1) in zip(srt, srt[1:]) if a1 < b0]
    if bad:
        raise CdgpsError("--rest: " + "; ".join(bad))
    return out


def rest_mask(time_s: np.ndarray, segments) -> np.ndarray:
    """(N,) bool: epoch inside any rest segment [start_s, end_s] (both ends included, 1 ns tolerance)."""
    m = np.zeros(len(time_s), dtype=bool)
    for a, b in segments:
        m |= (time_s >= a - 1e-9) & (time_s <= b + 1e-9)
    return m


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[(start, end_exclusive)] of the runs of True in a bool array."""
    m = np.r_[False, np.asarray(mask, dtype=bool), False].astype(np.int8)
    e = np.flatnonzero(np.diff(m))
    return list(zip(e[::2].tolist(), e[1::2].tolist()))


def q_segments(at_rest: np.ndarray, Q: np.ndarray, Q_rest: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """Smoother transitions k → k+1 grouped by the process noise of the prediction into k+1:
    [(k_lo, k_hi, Q)] covering k_lo ≤ k < k_hi, in time order."""
    N = len(at_rest)
    if N < 2:
        return []
    into = at_rest[1:]                     # transition k → k+1 uses the Q of epoch k+1
    cuts = np.flatnonzero(np.diff(into.astype(np.int8))) + 1
    edges = np.r_[0, cuts, N - 1]
    return [(int(a), int(b), Q_rest if into[a] else Q) for a, b in zip(edges[:-1], edges[1:])]


def zero_velocity_update(x: np.ndarray, P: np.ndarray, nm: int, var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with the pseudo-measurement "modal velocities = 0" (variances ``var``, (nm,)).

    x (p,), P (p, p) with the modal velocities at x[nm:2nm]; Joseph form, so P stays symmetric
    positive definite.  Returns the updated (x, P) (new arrays)."""
    v = slice(nm, 2 * nm)
    S = P[v, v] + np.diag(var)
    K = cho_solve(cho_factor(S, check_finite=False), P[v, :], check_finite=False).T     # (p, nm)
    x = x - K @ x[v]
    IKH = np.eye(len(x))
    IKH[:, v] -= K
    P = IKH @ P @ IKH.T + (K * var) @ K.T
    return x, 0.5 * (P + P.T)


def velocity_nis(x: np.ndarray, P: np.ndarray, nm: int, var: np.ndarray) -> float:
    """Normalized innovation squared of the zero-velocity pseudo-measurement: v̂ᵀ (P_vv + diag var)⁻¹ v̂
    with v̂ = x[nm:2nm] (chi-square with nm dof when the structure is at rest)."""
    v = x[nm:2 * nm]
    S = P[nm:2 * nm, nm:2 * nm] + np.diag(var)
    return float(v @ cho_solve(cho_factor(S, check_finite=False), v, check_finite=False))


def rest_motion(x, P, h, Hx, y, bias, usable, n, use_bias_states, r_var, outlier_sigma, bound,
                mp0=None) -> tuple[str, bool]:
    """Does an epoch's data contradict "the structure is at rest"?  Returns (reason, nis_failed).

    ``h, Hx``: the measurement model and its Jacobian at x[:n]; ``r_var`` (C,): each channel's
    measurement variance (m²).

    The reason is non-empty when two or more channels fail the innovation outlier test (one alone
    is a slip, handled as such); ``nis_failed`` when the normalized innovation squared of the other
    channels exceeds ``bound(m)`` (the caller breaks the segment after several in a row)."""
    idx = np.flatnonzero(usable)
    if idx.size == 0:
        return "", False
    H = bias_rows(Hx, idx, len(x), n, use_bias_states, mp0)
    b = x[n + idx] if use_bias_states else bias[idx]
    if mp0 is not None:
        b = b + x[mp0 + idx]
    rho = y[idx] - h[idx] - b
    S = H @ P @ H.T + np.diag(r_var[idx])
    z = rho / np.sqrt(np.diag(S))
    out = np.abs(z) > outlier_sigma
    if out.sum() >= 2:
        return f"{int(out.sum())} channels beyond {outlier_sigma:g} sigma", False
    keep = ~out
    if keep.sum() == 0:
        return "", False
    Sk = S[np.ix_(keep, keep)]
    nis = float(rho[keep] @ cho_solve(cho_factor(Sk, check_finite=False), rho[keep], check_finite=False))
    if nis > bound(int(keep.sum())):
        return f"NIS {nis:.1f} over {int(keep.sum())} channels", True
    return "", False


class StaticMode(Hook):
    """Static mode at epoch k (``before_rows``): enter (zero-velocity update), keep, or leave when the
    data say the structure moves; the first epoch after a rest stretch logs its end.

    Shares the pass's state ``fp`` (:class:`cdgps_cli.estimation.filter._ForwardPass`): ``at_rest``
    (changed here when a stretch is broken: the dynamics read it), ``rest_stretch_end``, ``rest_fail``,
    ``extra_q``, the event log."""

    def __init__(self, fp):
        self.fp = fp

    def before_rows(self, ctx, k: int) -> None:
        fp = self.fp
        if fp.at_rest[k]:
            self._rest(k, fp.Y[k], ~np.isnan(fp.Y[k]))
        elif k > 0 and fp.at_rest[k - 1]:
            fp.rest_fail = 0
            fp.log(k, None, "rest segment end", "process noise back to the kinematic model")

    def _rest(self, k: int, y, present) -> None:
        fp = self.fp
        q_events = list(fp.extra_q.get(k, ()))      # variance raised at this epoch by its lock events
        entering = k >= fp.rest_stretch_end         # (also after a re-initialization inside a stretch)
        if entering:
            off = np.flatnonzero(~fp.at_rest[k:])
            fp.rest_stretch_end = k + (int(off[0]) if off.size else fp.N - k)
            fp.rest_fail = 0
        k_end = fp.rest_stretch_end                 # end of this stretch (exclusive)
        if entering:
            x_kin, vel_nis, vel_bound = self._enter(k, k_end)
        else:
            x_kin = fp.x.copy()
            vel_nis, vel_bound = 0.0, 1.0
        why = self._contradiction(k, y, present, vel_nis, vel_bound)
        if why:
            # (P_kin: the kinematic prior covariance of this stretch's entry)
            self._leave(k, k_end, why, x_kin, fp.P_kin, q_events, refused=vel_nis > vel_bound, vel_nis=vel_nis)

    def _enter(self, k: int, k_end: int):
        """The kinematic prior (kept in case the structure moves), the velocity test, the zero-velocity update."""
        fp = self.fp
        opt, nm, A = fp.opt, fp.nm, fp.A
        x_kin = fp.x.copy()
        P_kin = fp.P_kin = fp.P.copy() if k == 0 else A @ fp.Ps[k - 1] @ A.T + fp.Qd
        # the zero-velocity update's own test: are the estimated modal velocities zero?
        vel_nis = velocity_nis(x_kin, P_kin, nm, fp.zupt_var)
        vel_bound = chi2_quantile(opt.nis_probability, nm)
        if vel_nis <= vel_bound:
            # the rest position is re-estimated from the data: the modal position variances of
            # the prior are raised REST_ENTRY_POSITION_INFLATION-fold (recorded as extra process
            # noise, so the smoother stays exact), so that an estimate lagging the structure's
            # last motion is not carried into the average; then the zero-velocity update
            d = REST_ENTRY_POSITION_INFLATION * np.diag(fp.P)[:nm]
            fp.P[np.arange(nm), np.arange(nm)] += d
            fp.extra_q.setdefault(k, []).extend((i, float(d[i])) for i in range(nm))
            if fp.trace is not None:
                fp.trace.setdefault("zupt", {})[k] = fp.P.copy()     # the prior (after the raise)
            fp.x, fp.P = zero_velocity_update(fp.x, fp.P, nm, fp.zupt_var)
            fp.log(k, None, "rest segment", "modal velocities set to zero (zero-velocity update); process "
                   f"noise × {opt.rest_process_noise_scale:g}² until {fp.grid[k_end - 1]:g} s")
            fp.events[-1]["velocity_nis"] = vel_nis
        return x_kin, vel_nis, vel_bound

    def _contradiction(self, k: int, y, present, vel_nis: float, vel_bound: float) -> str:
        """Why the data contradict rest at epoch k ('' when they do not)."""
        fp = self.fp
        opt = fp.opt
        if vel_nis > vel_bound:
            return f"modal velocities not zero (NIS {vel_nis:.1f} > {vel_bound:.1f})"
        fp.hx_at = fp.x[:fp.n].copy()
        fp.h, fp.Hx = fp.meas.predict(fp.hx_at, fp.all_channels)
        usable = present & ~np.isnan(fp.bias)
        why, nis_failed = rest_motion(fp.x, fp.P, fp.h, fp.Hx, y=y, bias=fp.bias, usable=usable,
                                      mp0=fp.mp0, n=fp.n, use_bias_states=fp.use_bias_states, r_var=fp.r_var,
                                      outlier_sigma=opt.outlier_sigma, bound=lambda m: chi2_quantile(opt.nis_probability, m))
        if nis_failed:
            fp.rest_fail += 1
        elif usable.any():
            fp.rest_fail = 0                          # (an epoch without data leaves the count as it is)
        if nis_failed and fp.rest_fail < REST_NIS_FAILURES:
            return ""                                 # one NIS failure can be chance (1 − nis_probability)
        if nis_failed:
            why += f" ({REST_NIS_FAILURES} epochs in a row)"
        return why

    def _leave(self, k, k_end, why, x_kin, P_kin, q_events, refused: bool, vel_nis: float) -> None:
        """The data say the structure moves: kinematic for the rest of this stretch (or until the retry),
        from the kinematic prior of the stretch's entry."""
        fp = self.fp
        opt, A, n, N = fp.opt, fp.A, fp.n, fp.N
        fp.rest_fail = 0
        k_back = k_end if opt.rest_retry_s <= 0 else min(k + max(int(round(min(opt.rest_retry_s / fp.T, N))), 1), k_end)
        fp.at_rest[k:k_back] = False                  # retried after rest_retry_s, within the segment
        fp.rest_stretch_end = -1
        fp.q_bounds = np.flatnonzero(np.diff(fp.at_rest.astype(np.int8))) + 1
        fp.x = x_kin
        if k == 0:
            fp.P = P_kin.copy()
            fp.extra_q.pop(0, None)           # (the smoother reads no prior at the first epoch)
            if q_events:
                fp.extra_q[0] = q_events
        else:
            # the kinematic prediction, its variances raised to the entry's kinematic prior; the
            # raise is recorded as extra process noise so that the smoother stays exact
            fp.P = A @ fp.Ps[k - 1] @ A.T + fp.Qd
            for i, q in q_events:
                fp.P[i, i] += q
            d = np.maximum(np.diag(P_kin)[:n] - np.diag(fp.P)[:n], 0.0)   # structure states only
            fp.P[np.arange(n), np.arange(n)] += d
            fp.extra_q[k] = q_events + [(int(i), float(d[i])) for i in np.flatnonzero(d)]
        if fp.trace is not None:
            fp.trace.get("zupt", {}).pop(k, None)     # this epoch's prior is the rebuilt one
        fp.log(k, None, "rest segment refused" if refused else "rest segment broken",
               f"{why}: the structure moves; kinematic process noise"
               + (f", rest tried again at {fp.grid[k_back]:g} s" if k_back < k_end else " to the segment's end"))
        if refused:
            fp.events[-1]["velocity_nis"] = vel_nis
