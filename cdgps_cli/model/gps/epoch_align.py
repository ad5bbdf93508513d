"""Epochs that line up: receivers whose time tags are not on whole seconds, at different rates.

Each receiver's epochs are put on the grid of common GPS times of its own nominal rate (1 Hz →
whole seconds, 3 Hz → thirds of a second, 5 s → multiples of 5 s, all counted from GPS time 0,
so grids of different rates share their common instants).  An epoch tagged ``t`` belongs to the
grid time ``T`` nearest to it when its offset ``δ = t − T`` — for u-blox receivers the
millisecond-level offset of their clock, tags at .990–.992 s — is at most a third of the step in the
default ``"geometry"`` mode (nothing is moved), and at most the tolerance (``gnss.sync_tol_s``, 25 ms by
default: RTKLIB's DTTOL) in ``"doppler"`` mode; an epoch farther from the grid is dropped, and of two
epochs on one grid time the nearer is kept.  Receivers are then paired on equal grid
times, whatever their rates.

What happens to the observations of an off-grid epoch (:data:`ALIGN_MODES`):

* ``"geometry"`` (default): nothing.  The solvers compute each receiver's geometry at its own
  reception instant (tag − receiver clock from its pseudoranges, :mod:`cdgps_cli.estimation.baseline`), so
  an offset of a few milliseconds between the two receivers of a double difference is modelled
  exactly and only the pairing changes.
* ``"doppler"``: carrier phase and pseudorange are moved to the grid time, as RTK engines do,
  ``Φ(T) = Φ(t) − δ·Φ̇`` and ``P(T) = P(t) − δ·λ·Φ̇``, where ``Φ̇ = −D`` is the carrier-phase rate
  (the Doppler the receiver's own phase implies, its clock drift included): the derivative, at
  the epoch, of the parabola through it and its two nearest neighbours in the same lock segment
  (no slip flag between them, at most :data:`RATE_MAX_SPAN_INTERVALS` intervals apart).  Its
  error is below 0.1 mm for |δ| ≤ 25 ms at 1 Hz (white phase noise of a few mm over 1–2 s, and
  the neglected curvature ½·Φ̈·δ² ≈ 3·10⁻⁵ cycles).  The epoch's tag becomes ``T``.  A row with
  no such neighbours (a lock segment of fewer than three epochs) has no rate and is dropped.

:func:`align_receiver` does one receiver, :func:`pair_epochs` pairs two aligned receivers;
both report matched, corrected and dropped epochs.

Target folder: ``model/gps/`` (architecture.md: receiver clocks).  The module is flat for now
because ``config.GnssConfig.baseline_options`` imports :mod:`cdgps_cli.estimation.baseline`, which imports
this module: inside ``model/`` that chain would make ``config`` import ``model`` and break the
``target-layers`` import contract that holds today.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.gps_time import nominal_interval_s
# (the receiver's sampling interval and grid live with the other time helpers; imported from here before)
from cdgps_cli.core.gps_time import SAMPLING_MULTIPLES_SHARE, grid_step_s, sampling_interval_s  # noqa: F401

__all__ = ["ALIGN_MODES", "ON_GRID_S", "RATE_MAX_SPAN_INTERVALS", "grid_step_s", "sampling_interval_s", "align_receiver",
           "pair_epochs",
           "carry_slips", "common_epochs", "phase_rate"]

#: How off-grid epochs are handled (see the module docstring); the first is the default.
ALIGN_MODES = ("geometry", "doppler")

#: An epoch within this of its grid time counts as on the grid and is never corrected, s
#: (float64 GPS seconds near 1.4·10⁹ resolve 0.24 µs).
ON_GRID_S = 2e-6

#: The neighbours used for a carrier-phase rate lie at most this many nominal intervals from the epoch.
RATE_MAX_SPAN_INTERVALS = 2.5


def _grid(t_s: np.ndarray, step_s: float):
    k = np.floor(t_s / step_s + 0.5)
    return k * step_s, t_s - k * step_s


def phase_rate(t, sat, phase, lli, interval_s):
    """Carrier-phase rate at every row of one receiver, cycles/s (RINEX sign: −Doppler).

    The derivative, at the row, of the parabola through the row and its two nearest neighbours of
    the same satellite and lock segment (no LLI bit 0 between them, the outer two at most
    :data:`RATE_MAX_SPAN_INTERVALS` × ``interval_s`` apart): centred where possible, else one-sided.
    On the real u-blox RXM-RAWX log of ../shared/data/ubx it agrees with the receiver's own Doppler
    to 0.2 Hz (median).

    Parameters
    ----------
    t : array_like, shape (N,)
        Time tags, s.
    sat : array_like, shape (N,)
        Satellite of each row.
    phase : array_like, shape (N,)
        Carrier phase, cycles (NaN: no phase).
    lli : array_like of int, shape (N,)
        Loss-of-lock indicator (bit 0: a new ambiguity from this row on).
    interval_s : float
        Nominal epoch interval, s.

    Returns
    -------
    ndarray, shape (N,)
        Rate, cycles/s; NaN where the row has no phase or fewer than three points of its segment
        are within reach.
    """
    t = np.asarray(t, dtype=np.float64)
    sat = np.asarray(sat)
    phase = np.asarray(phase, dtype=np.float64)
    lli = np.asarray(lli, dtype=np.int64)
    n = t.size
    rate = np.full(n, np.nan)
    ok = np.isfinite(phase)
    idx = np.flatnonzero(ok)
    if idx.size < 3:
        return rate
    order = idx[np.lexsort((t[idx], sat[idx].astype(str)))]
    ts, ys, ss, ls = t[order], phase[order], sat[order], lli[order]
    max_span = RATE_MAX_SPAN_INTERVALS * (interval_s if math.isfinite(interval_s) else 1.0)
    # a neighbour is usable when it is the same satellite, no slip is flagged between, and it is close
    link = np.r_[False, (ss[1:] == ss[:-1]) & ((ls[1:] & 1) == 0)]          # row j−1 → j continuous
    m = ts.size
    j = np.arange(m)

    def usable(a, b):                       # rows a < b continuous and within reach
        good = (a >= 0) & (b < m)
        a_, b_ = np.clip(a, 0, m - 1), np.clip(b, 0, m - 1)
        cont = np.cumsum(~link)             # lock-segment id along the sorted rows
        return good & (cont[a_] == cont[b_]) & (np.abs(ts[b_] - ts[a_]) <= max_span)

    # choose three points: centred, else the two after, else the two before
    p0 = np.where(usable(j - 1, j + 1), j - 1, np.where(usable(j, j + 2), j, j - 2))
    have = usable(p0, p0 + 2) & (p0 <= j) & (j <= p0 + 2)
    p0 = np.clip(p0, 0, max(m - 3, 0))
    x0, x1, x2 = ts[p0], ts[p0 + 1], ts[p0 + 2]
    ref = ys[j]
    y0, y1, y2 = ys[p0] - ref, ys[p0 + 1] - ref, ys[p0 + 2] - ref
    x = ts
    with np.errstate(divide="ignore", invalid="ignore"):
        w0 = ((x - x1) + (x - x2)) / ((x0 - x1) * (x0 - x2))
        w1 = ((x - x0) + (x - x2)) / ((x1 - x0) * (x1 - x2))
        w2 = ((x - x0) + (x - x1)) / ((x2 - x0) * (x2 - x1))
        r = w0 * y0 + w1 * y1 + w2 * y2
    r[~have] = np.nan
    rate[order] = r
    return rate


def _epoch_grid(tags, tol_s, step_s=None, *, reach_s=None):
    """Grid step, effective tolerance, grid time and offset of each distinct tag, within the
    tolerance, and chosen (within it and the nearest on its grid time).  ``reach_s``: the tolerance
    instead of ``tol_s`` (still at most a third of the step)."""
    step = grid_step_s(sampling_interval_s(tags)) if step_s is None else float(step_s)
    tol = min(float(tol_s if reach_s is None else reach_s), step / 3.0)
    g_tag, d_tag = _grid(tags, step)
    keep_tag = np.abs(d_tag) <= tol
    cand = np.flatnonzero(keep_tag)
    order = cand[np.lexsort((np.abs(d_tag[cand]), g_tag[cand]))]
    first = np.ones(order.size, dtype=bool)
    first[1:] = g_tag[order][1:] != g_tag[order][:-1]
    chosen = np.zeros(tags.size, dtype=bool)
    chosen[order[first]] = True
    return step, tol, g_tag, d_tag, keep_tag, chosen


def common_epochs(t_master_s, t_rover_s, tol_s: float) -> dict:
    """Epoch counts of a master/rover pair on the grid of GPS times (no observation is changed).

    Returns
    -------
    dict
        ``common_epochs``; per receiver (``master``, ``rover``): ``epochs``, ``on_grid``,
        ``off_grid`` (kept, within the tolerance), ``dropped`` (beyond it, or a second epoch on
        one grid time), ``matched`` (with a partner), ``max_offset_ms``, ``grid_s``; and
        ``tolerance_ms``.
    """
    out, grids = {}, {}
    tol_ms = None
    for who, t in (("master", t_master_s), ("rover", t_rover_s)):
        tags = np.unique(np.asarray(t, dtype=np.float64))
        step, tol, g, d, _, chosen = _epoch_grid(tags, tol_s)
        tol_ms = tol * 1e3 if tol_ms is None else min(tol_ms, tol * 1e3)
        grids[who] = np.unique(g[chosen])
        on = chosen & (np.abs(d) <= ON_GRID_S)
        out[who] = {"epochs": int(tags.size), "on_grid": int(on.sum()), "off_grid": int((chosen & ~on).sum()),
                    "dropped": int((~chosen).sum()),
                    "max_offset_ms": float(np.max(np.abs(d[chosen])) * 1e3) if chosen.any() else None,
                    "grid_s": step}
    im, ir = pair_epochs(grids["master"], grids["rover"])
    out["master"]["matched"], out["rover"]["matched"] = int(im.size), int(ir.size)
    return {"common_epochs": int(im.size), **out, "tolerance_ms": tol_ms}


def align_receiver(obs: pd.DataFrame, *, tol_s: float, mode: str = ALIGN_MODES[0], step_s: float | None = None,
                   what: str = "receiver") -> tuple[pd.DataFrame, dict]:
    """Put one receiver's epochs on its grid of GPS times.

    Parameters
    ----------
    obs : DataFrame
        The receiver's observations (:data:`~cdgps_cli.io.rinex.OBS_COLUMNS`: ``time_gps_s`` tag, GPS
        s; ``sat``; ``phase_l1_cycles``; ``lli_l1``; ``pseudorange_l1_m`` …).  Not modified.
    tol_s : float
        Largest offset of an epoch from its grid time, s.
    mode : {"geometry", "doppler"}
        Leave the observations as they are, or move them to the grid time (module docstring).
    step_s : float, optional
        Grid step, s (default :func:`grid_step_s` of the receiver's nominal interval).
    what : str
        The receiver's name, for messages.

    Returns
    -------
    obs : DataFrame
        The kept rows, with columns ``grid_gps_s`` (the grid time of each row's epoch),
        ``tag_gps_s`` (its time tag as recorded) and ``row`` (its position in ``obs``); in
        ``"doppler"`` mode ``time_gps_s``, ``phase_l1_cycles`` and ``pseudorange_l1_m`` of
        off-grid rows are moved to it.
    summary : dict
        ``epochs``, ``on_grid``, ``off_grid_kept`` (corrected in ``"doppler"`` mode, modelled at
        their own instants in ``"geometry"`` mode), ``corrected``, ``dropped_off_grid`` (beyond
        the tolerance), ``dropped_duplicate`` (a nearer epoch on the same grid time),
        ``rows_dropped_no_rate`` (``"doppler"``: no carrier-phase rate), ``max_offset_ms`` (of
        the kept epochs), ``grid_s``, ``tolerance_ms``, ``mode``.
    """
    if mode not in ALIGN_MODES:
        raise ValueError(f"{what}: epoch alignment mode must be one of {', '.join(ALIGN_MODES)}, got {mode!r}")
    if not (math.isfinite(tol_s) and tol_s > 0):
        raise ValueError(f"{what}: the epoch alignment tolerance must be > 0 s, got {tol_s!r}")
    t = obs["time_gps_s"].to_numpy(dtype=np.float64)
    tags = np.unique(t)
    interval = nominal_interval_s(tags)
    # geometry mode changes no observation (each receiver's geometry at its own reception instant): an epoch up to a
    # third of the step off its grid time is labelled with it (a rover tagged 30 ms after the second was dropped
    # whole, "no common epochs", while rtk bridged every epoch); doppler mode moves observations by δ·Φ̇, within tol_s
    step, tol, g_tag, d_tag, keep_tag, chosen = _epoch_grid(tags, tol_s, step_s,
                                                            reach_s=math.inf if mode == "geometry" else None)
    on_grid = chosen & (np.abs(d_tag) <= ON_GRID_S)
    summary = {"epochs": int(tags.size), "on_grid": int(on_grid.sum()),
               "off_grid_kept": int((chosen & ~on_grid).sum()), "corrected": 0,
               "dropped_off_grid": int((~keep_tag).sum()), "dropped_duplicate": int((keep_tag & ~chosen).sum()),
               "rows_dropped_no_rate": 0,
               "max_offset_ms": float(np.max(np.abs(d_tag[chosen])) * 1e3) if chosen.any() else None,
               "grid_s": step, "tolerance_ms": tol * 1e3, "mode": mode}
    k = np.searchsorted(tags, t)
    row_keep = chosen[k]
    out = obs.loc[row_keep]              # a new frame (copy-on-write: setting its columns leaves obs alone)
    kk = k[row_keep]
    out["grid_gps_s"] = g_tag[kk]
    out["tag_gps_s"] = tags[kk]
    out["row"] = np.flatnonzero(row_keep)
    if mode == "doppler":
        delta = d_tag[kk]
        move = np.abs(delta) > ON_GRID_S
        rate = phase_rate(out["time_gps_s"].to_numpy(dtype=np.float64), out["sat"].to_numpy(),
                           out["phase_l1_cycles"].to_numpy(dtype=np.float64),
                           out["lli_l1"].to_numpy(dtype=np.int64), interval)
        bad = move & ~np.isfinite(rate)
        rate = np.where(move, rate, 0.0)
        ph = out["phase_l1_cycles"].to_numpy(dtype=np.float64)
        pr = out["pseudorange_l1_m"].to_numpy(dtype=np.float64)
        out["phase_l1_cycles"] = ph - delta * rate
        out["pseudorange_l1_m"] = pr - delta * GPS_L1_WAVELENGTH_M * rate
        out["time_gps_s"] = np.where(move, g_tag[kk], out["time_gps_s"].to_numpy(dtype=np.float64))
        summary["rows_dropped_no_rate"] = int(bad.sum())
        out = out.loc[~bad]
        moved_epochs = np.unique(out["grid_gps_s"].to_numpy()[move[~bad]])
        summary["corrected"] = int(moved_epochs.size)
    return out.reset_index(drop=True), summary


def pair_epochs(grid_a_s, grid_b_s) -> tuple[np.ndarray, np.ndarray]:
    """Indices of equal grid times in two increasing arrays of distinct grid times (s).

    Grid times of different steps are compared to :data:`ON_GRID_S` (``k·step`` products of
    equal instants differ by float64 rounding only)."""
    a = np.asarray(grid_a_s, dtype=np.float64)
    b = np.asarray(grid_b_s, dtype=np.float64)
    if a.size == 0 or b.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    k = np.clip(np.searchsorted(b, a), 1, max(b.size - 1, 1)) if b.size > 1 else np.zeros(a.size, dtype=np.int64)
    if b.size > 1:
        near = np.where(np.abs(a - b[k - 1]) <= np.abs(a - b[k]), k - 1, k)
    else:
        near = k
    ok = np.abs(a - b[near]) <= ON_GRID_S
    return np.flatnonzero(ok).astype(np.int64), near[ok].astype(np.int64)


def carry_slips(t_s, sat, lli, keep) -> np.ndarray:
    """Loss-of-lock flags of the kept rows, with those of dropped rows carried forward.

    A receiver's epoch that is not differenced (no partner epoch at the other receiver — a 1 Hz
    rover beside a 5 s base —, off the grid, or a row without a rate) may carry the only flag of
    a cycle slip; its LLI bit 0 is moved to the next kept row of the same satellite, so the new
    ambiguity still starts there.

    Parameters
    ----------
    t_s, sat, lli : array_like, shape (N,)
        Time tags (s), satellites and LLI of all rows of one receiver.
    keep : array_like of bool, shape (N,)
        Rows that are used.

    Returns
    -------
    ndarray of int64, shape (N,)
        LLI with bit 0 set on each kept row that follows (same satellite, later in time) a
        dropped row flagged since the previous kept row; dropped rows unchanged.
    """
    t = np.asarray(t_s, dtype=np.float64)
    sat = np.asarray(sat)
    out = np.asarray(lli, dtype=np.int64).copy()
    keep = np.asarray(keep, dtype=bool)
    if out.size == 0 or keep.all():
        return out
    order = np.lexsort((t, sat.astype(str)))
    s_o, k_o = sat[order], keep[order]
    res = out[order]
    kp = np.flatnonzero(k_o)
    src = np.flatnonzero(~k_o & ((res & 1) == 1))          # flagged rows that are dropped
    if kp.size and src.size:
        pos = np.searchsorted(kp, src)                      # the next kept row after each
        ok = pos < kp.size
        dst = kp[np.minimum(pos, kp.size - 1)]
        ok &= s_o[dst] == s_o[src]                          # … of the same satellite
        res[dst[ok]] |= 1
    out[order] = res
    return out
