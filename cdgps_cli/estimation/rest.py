"""Rest segments found from the data: ``cdgps estimate --rest auto``.

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
from cdgps_cli.estimation.chi2 import chi2_quantile

from cdgps_cli.core.errors import CdgpsError

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
