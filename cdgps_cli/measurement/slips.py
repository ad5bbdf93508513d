"""Unflagged cycle slips: a step in one channel's residuals that its lock indicator did not report.

A slip the receiver did not flag adds k·λ (k a whole or, with a half-cycle ambiguity, a half
number of cycles) to every later phase of the channel.  A batch fit that gives the channel one
bias for the whole lock segment cannot follow it: the channel's residuals keep a step of nearly
the slip's size (the other channels hold the structure's state), split around the segment's mean.

:func:`residual_steps` finds such a step per channel with a local two-sample test: at every epoch
k of a contiguous stretch of one bias segment, the mean of up to ``half_width`` residuals from k on
minus the mean of up to ``half_width`` before k, divided by its standard deviation under white
noise.  The channel's noise σ is estimated robustly from its first differences (median absolute
deviation): a step is one difference among hundreds, and slow multipath barely moves the
differences.  A step is reported when both

* its z value exceeds ``z_min`` (white noise alone: the largest of a few thousand correlated
  normal values stays below ≈ 5), and
* its size is at least ``min_cycles`` of a wavelength (a quarter cycle by default: half the
  smallest slip; time-correlated multipath of a few centimetres does not jump that far within the
  test's few seconds).

The largest such step per stretch is returned; the caller splits the segment there, refits and
looks again (several slips on one channel are found one per round).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.config.options import GF_SLIP_THRESHOLD_M, UNLOCKED_CHANNEL_MIN_EPOCHS, UNLOCKED_CHANNEL_SHARE
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.measurement.epoch_fit import grouped_epoch_fit
from cdgps_cli.measurement.multipath import segment_stretches

#: time-differenced carrier phase (:func:`time_differenced_slips`): a channel's epoch-to-epoch change whose residual
#: exceeds this many σ and this many metres is a slip (a quarter cycle at L1 is 4.8 cm; TD multipath at 1–10 Hz stays
#: within a few mm), with at least this many redundant changes in the epoch pair (to tell which channel jumped)
TD_SLIP_SIGMAS, TD_SLIP_MIN_M, TD_SLIP_MIN_REDUNDANCY = 6.0, 0.03, 2
#: the test's half width (s): residuals on each side of a candidate epoch
STEP_HALF_WIDTH_S = 2.0
#: z value a step must exceed
STEP_Z_MIN = 6.0
#: … and its size, in cycles (half the smallest slip, a half cycle)
STEP_MIN_CYCLES = 0.25


def unlocked_channels(channel, lli, *, share: float = UNLOCKED_CHANNEL_SHARE,
                      min_epochs: int = UNLOCKED_CHANNEL_MIN_EPOCHS) -> tuple[np.ndarray, np.ndarray]:
    """Channels whose phase is flagged lost-lock (``lli`` bit 0) at more than ``share`` of their rows.

    Parameters
    ----------
    channel : ndarray of int (N,)
        Channel (satellite and signal) of each row, one row per epoch.
    lli : ndarray of int (N,)
        The rows' loss-of-lock indicators (bit 0: lost lock since the previous epoch).
    share, min_epochs : float, int
        The share of flagged rows above which a channel of at least ``min_epochs`` rows is unlocked
        (:data:`~cdgps_cli.config.options.UNLOCKED_CHANNEL_SHARE`, ``UNLOCKED_CHANNEL_MIN_EPOCHS``).

    Returns
    -------
    rows : ndarray of bool (N,)
        The rows of those channels.
    flagged_share : ndarray (N,)
        Each row's channel's share of flagged rows.
    """
    channel = np.asarray(channel, dtype=np.int64)
    flagged = (np.asarray(lli, dtype=np.int64) & 1) > 0
    n = np.bincount(channel, minlength=int(channel.max()) + 1 if channel.size else 0)
    k = np.bincount(channel, weights=flagged.astype(float), minlength=n.size)
    frac = np.divide(k, n, out=np.zeros(n.size), where=n > 0)
    bad = (n >= min_epochs) & (frac > share)
    return bad[channel], frac[channel]


def geometry_free_slips(epoch, sat, code, phase_m, var_m2=None, *, flagged=None,
                        threshold_m: float = GF_SLIP_THRESHOLD_M, sigmas: float = TD_SLIP_SIGMAS) -> np.ndarray:
    """Slips no flag reported, from the epoch-to-epoch change of each satellite's geometry-free combinations.

    At each epoch a satellite's phases of two signals (m) differ by their ionosphere and their ambiguities only: the
    range, the clocks and the troposphere cancel.  Between consecutive epochs (of the epochs that have rows) that
    difference moves by the change of the ionosphere (millimetres over seconds on a short baseline's single
    differences) and the phase noise; a slip of k cycles on one signal moves it by kλ (19 cm for one GPS L1 cycle), a
    slip of k on each by kλ₁ − kλ₂ (5.4 cm for one cycle on L1 and L2).  Each signal of a satellite is compared with
    its first one (the lowest ``code``); a change beyond ``threshold_m`` (RTKLIB's ``detslp_gf``, ``pos2-slipthres``
    0.05 m) and beyond ``sigmas`` times its σ from the four phases' variances ``var_m2`` (noisier phases than real
    receivers': a simulation's 5 cm steps of noise) flags both rows at that epoch, unless either row is ``flagged`` already (a slip on one signal, known,
    moves the combination too: its partner keeps its ambiguity).  Blind to slips that keep the combination
    (k₁λ₁ = k₂λ₂: 77 and 60 cycles on L1 and L2) and to a satellite with one signal.

    Parameters
    ----------
    epoch, sat, code : ndarray (N,)
        Each row's epoch index (non-decreasing in row order is not needed), satellite and signal index.
    phase_m : ndarray (N,)
        The rows' (single-difference) carrier phases, m.
    var_m2 : ndarray (N,), optional
        Their variances, m² (None: the threshold alone).
    flagged : ndarray of bool (N,), optional
        Rows already starting a new arc (the receivers' flags, slips found otherwise).
    threshold_m, sigmas : float
        Largest change of a geometry-free combination between consecutive epochs that is not a slip, m, and in its σ.

    Returns
    -------
    ndarray of bool (N,)
        The rows at which a slip starts (both rows of the combination that moved).
    """
    n = np.asarray(phase_m).size
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    epoch = np.asarray(epoch, dtype=np.int64)
    s = np.unique(np.asarray(sat), return_inverse=True)[1].ravel().astype(np.int64)
    code = np.asarray(code, dtype=np.int64)
    order = np.lexsort((code, epoch, s))                    # by satellite, epoch, signal
    se = s[order] * (int(epoch.max()) + 2) + epoch[order]
    first = np.r_[True, se[1:] != se[:-1]]                 # each (satellite, epoch)'s first signal
    ref = order[np.maximum.accumulate(np.where(first, np.arange(n), 0))]
    other = order[~first]                                  # rows with a first signal to compare with
    if other.size == 0:
        return out
    gf = np.asarray(phase_m, dtype=np.float64)[other] - np.asarray(phase_m, dtype=np.float64)[ref[~first]]
    # consecutive rows of one combination (satellite, signal): epochs in order within it (the lexsort keeps them so)
    chan = s[other] * (int(code.max()) + 1) + code[other]
    o2 = np.lexsort((epoch[other], chan))
    c2, e2, g2 = chan[o2], epoch[other][o2], gf[o2]
    limit = np.full(c2.size - 1, threshold_m)
    if var_m2 is not None:
        v = np.asarray(var_m2, dtype=np.float64)
        vg = (v[other] + v[ref[~first]])[o2]                     # each combination's variance
        limit = np.maximum(limit, sigmas * np.sqrt(vg[1:] + vg[:-1]))
    step = np.r_[False, (c2[1:] == c2[:-1]) & (e2[1:] == e2[:-1] + 1) & (np.abs(np.diff(g2)) > limit)]
    if flagged is not None:
        known = np.asarray(flagged, dtype=bool)
        step &= ~(known[other[o2]] | known[ref[~first][o2]])
    hit = other[o2][step]
    out[hit] = True
    out[ref[~first][o2][step]] = True
    return out


def slip_events(rows, found, times_s) -> dict:
    """The satellite (str array), signal name and epoch time (GPS s) of each SD row in ``found`` (rows of
    :func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows`: ``ptr``, ``sats``, ``names``, ``code``; ``times_s`` per
    epoch), as ``sat``, ``signal``, ``time_s``."""
    i = np.flatnonzero(found)
    epoch = np.searchsorted(rows["ptr"], i, side="right") - 1
    return {"sat": rows["sats"][i].astype(str), "signal": rows["names"][rows["code"][i]].astype(str),
            "time_s": np.asarray(times_s, float)[epoch]}


def unflagged_slip_text(sat, signal, time_s, n_show: int = 8) -> list[str]:
    """The warning naming slips no receiver flagged that a solver found, each a new ambiguity (satellite, signal name
    "G:L1" and epoch time, GPS s, per slip; [] when there is none): `init`'s and `rtk`'s."""
    where = [f"{s}:{str(g).split(':')[1]} at {gps_time_str(float(t))}" for s, g, t in zip(sat, signal, time_s)]
    if not where:
        return []
    more = f" and {len(where) - n_show} more" if len(where) > n_show else ""
    return [f"{len(where)} cycle slip(s) that no receiver flagged, found in the epoch-to-epoch change of the phases, "
            f"start a new ambiguity: {', '.join(where[:n_show])}{more}"]


def table_channels(table) -> np.ndarray:
    """Channel (N,) of each row of a signal table: one integer per (satellite, signal) pair (not empty)."""
    sat = np.unique(table["sat"].to_numpy(), return_inverse=True)[1].ravel()       # (pandas stays off this module)
    sig = np.unique(table["signal"].to_numpy(), return_inverse=True)[1].ravel()
    return sat * (int(sig.max()) + 1) + sig


def without_unlocked_channels(table, where: str):
    """A receiver's signal table (``sat``, ``signal``, ``lli`` per row) less its :func:`unlocked_channels`, and the
    warnings naming them (``where``: the receiver, e.g. "base.obs (base)"; [] when none): each flag starts a new
    ambiguity, so they carry no phase, and one such channel as its group's reference would leave every DD of the group
    without one (a real rover's BeiDou B2I: no epoch of 601 fixed with it, all 601 without it)."""
    if table is None or table.empty:
        return table, []
    bad, share = unlocked_channels(table_channels(table), table["lli"].to_numpy())
    if not bad.any():
        return table, []
    named = (table.loc[bad, ["signal", "sat"]].assign(pct=100 * share[bad]).drop_duplicates(["signal", "sat"])
             .sort_values(["signal", "sat"]))
    text = (f"{where}: " + ", ".join(f"{s} {n} ({p:.0f} %)" for s, n, p in named.itertuples(index=False))
            + f": their carrier phase is flagged lost-lock at more than {100 * UNLOCKED_CHANNEL_SHARE:.0f} % of their "
            f"epochs (in brackets), each flag a new ambiguity: they carry no phase and are not used")
    return table[~bad].reset_index(drop=True), [text]


@dataclass(frozen=True)
class ResidualStep:
    """A step in one channel's residuals: the first epoch after it and its size."""

    channel: int        # column of the residual matrix
    epoch: int          # row index of the first epoch after the step
    step_m: float       # mean after − mean before (m)
    z: float            # step / its σ under white noise
    sigma_m: float      # the channel's robust white-noise σ (m)


def robust_sigma(e: np.ndarray) -> float:
    """White-noise σ (m) of a residual stretch from its first differences (1.4826 × MAD / √2)."""
    d = np.diff(e)
    if d.size < 2:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def local_steps(e: np.ndarray, half_width: int) -> tuple[np.ndarray, np.ndarray]:
    """(step, scale) for every split k = 1 … L−1 of a stretch ``e`` (L,): step = mean(e[k:k+w]) −
    mean(e[k−w:k]) and scale = sqrt(1/n_before + 1/n_after), w = ``half_width`` (fewer at the ends)."""
    L = e.size
    cs = np.r_[0.0, np.cumsum(e)]
    k = np.arange(1, L)
    lo, hi = np.maximum(k - half_width, 0), np.minimum(k + half_width, L)
    nb, na = k - lo, hi - k
    step = (cs[hi] - cs[k]) / na - (cs[k] - cs[lo]) / nb
    return step, np.sqrt(1.0 / nb + 1.0 / na)


def residual_steps(resid: np.ndarray, segment: np.ndarray, wavelength_m: float, dt_s: float,
                   z_min: float = STEP_Z_MIN, min_cycles: float = STEP_MIN_CYCLES,
                   half_width_s: float = STEP_HALF_WIDTH_S) -> list[ResidualStep]:
    """The largest significant step of each contiguous stretch of one bias segment per channel.

    Parameters
    ----------
    resid : ndarray (N, C)
        Residuals of a batch fit (m), NaN where a channel has no phase.
    segment : ndarray (N, C)
        Bias-segment index of each residual (−1: none).
    wavelength_m : float
        Carrier wavelength (m).
    dt_s : float
        Epoch interval (s).
    z_min, min_cycles, half_width_s : float
        The test's thresholds and half width (module constants by default).

    Returns
    -------
    list of ResidualStep
        By channel, then epoch.
    """
    w = max(int(round(half_width_s / dt_s)), 2)
    out = []
    for c, a, b in segment_stretches(resid, segment, 3):
        e = resid[a:b, c]
        sig = robust_sigma(e)
        if not (np.isfinite(sig) and sig > 0):
            continue
        step, scale = local_steps(e, w)
        z = step / (sig * scale)
        cand = np.abs(step) >= min_cycles * wavelength_m
        if not cand.any():
            continue
        j = int(np.argmax(np.where(cand, np.abs(z), -np.inf)))
        if abs(z[j]) >= z_min:
            out.append(ResidualStep(c, a + j + 1, float(step[j]), float(z[j]), sig))
    return out


#: a channel whose w value is within this fraction of its epoch's largest is flagged with it (a cut arc costs one
#: ambiguity; a slip left in an arc, a wrong fix)
TD_SLIP_TIE = 0.8


def time_differenced_slips(epoch, channel, group, phase_m, range_m, var_m2, los, *, flagged=None, rounds: int = 3,
                           sigmas: float = TD_SLIP_SIGMAS, min_m: float = TD_SLIP_MIN_M,
                           min_redundancy: int = TD_SLIP_MIN_REDUNDANCY) -> tuple[np.ndarray, np.ndarray]:
    """Slips no flag reported, from the epoch-to-epoch change of each channel's single-difference phase.

    Between consecutive epochs of a channel, ``phase − range`` (m) changes by the rover's displacement along the
    line of sight, a term common to each signal group (the receivers' clocks, phase biases) and noise; a slip adds
    k·λ to one channel.  For every epoch the changes of all its channels are fitted by least squares with a
    displacement (3) and one common term per group; the channel with the largest residual beyond both thresholds
    (``sigmas`` × its σ, σ√(1 − h) with h its leverage: the w-test of detection–identification–adaptation, the σ
    scaled up by the record's own spread of those w values when larger than the model says — the robust 1.4826 ×
    median, over the first fit —; and an estimated jump r/(1 − h) over ``min_m``) is flagged and left out, with any
    other whose w value comes within :data:`TD_SLIP_TIE` of it, and the epoch is fitted again, ``rounds`` times at
    most.  An epoch with fewer than ``min_redundancy`` changes to spare is not judged.  Unlike
    :func:`residual_steps` this needs no batch fit, and a rover's motion is a parameter, not a misfit.

    Parameters
    ----------
    epoch : ndarray of int (N,)
        Epoch index of each row (rows of one channel in increasing epochs); a channel's change is taken from the
        epoch numbered one less, so a caller numbers only the epochs that have rows.
    channel, group : ndarray of int (N,)
        Channel (satellite and signal) and signal group of each row.
    phase_m, range_m : ndarray (N,)
        Single-difference phase and the modelled single-difference range at the a-priori rover positions, m.
    var_m2 : ndarray (N,)
        Variance of each single-difference phase, m².
    los : ndarray (N, 3)
        Unit vector from the rover to the satellite (ECEF).
    flagged : ndarray of bool (N,), optional
        Rows already starting a new arc (the receivers' flags): their changes are not fitted.

    Returns
    -------
    flagged : ndarray of bool (N,)
        True at the first row after a detected slip (a new arc from there).
    displacement_m : ndarray (n_epochs, 3)
        Each epoch's fitted displacement from the previous one (0 where the epoch pair was not fitted), ECEF m: a
        caller whose a-priori positions are far off (a moving rover at one position) sums it into a trajectory and
        computes ``range_m`` along it (the line of sight turns by ≈ 10⁻⁴ rad/s: 100 m off, 1 cm per second).
    """
    n = epoch.size
    known = np.zeros(n, dtype=bool) if flagged is None else np.asarray(flagged, dtype=bool)
    flagged = np.zeros(n, dtype=bool)
    n_ep = int(epoch.max()) + 1 if n else 0
    if n == 0:
        return flagged, np.zeros((0, 3))
    i, j = _previous_rows(epoch, channel, n_ep, known)
    if i.size == 0:                                            # one epoch, or no channel seen twice running
        return flagged, np.zeros((n_ep, 3))
    y = (phase_m[i] - range_m[i]) - (phase_m[j] - range_m[j])
    w = 1.0 / (var_m2[i] + var_m2[j])
    g = -los[i]
    grp = np.unique(epoch[i].astype(np.int64) * (int(group.max()) + 1) + group[i], return_inverse=True)[1].ravel()
    ep = epoch[i]
    live = np.ones(i.size, dtype=bool)
    scale = None
    for _ in range(rounds):
        r, redundancy, step, lev = _td_residuals(y, w, g, grp, ep, live, n_ep)
        # each residual over its own σ (σ √(1 − h), h the leverage): the w-test, which names the channel that jumped
        judged = live & (redundancy[ep] >= min_redundancy) & (lev < 1.0 - 1e-9)
        z = np.where(judged, np.abs(r) * np.sqrt(w / np.maximum(1.0 - lev, 1e-9)), 0.0)
        if scale is None:          # the record's own noise when above the model's (a rover on a car: 2–3 times)
            scale = max(1.0, 1.4826 * float(np.median(z[judged]))) if judged.any() else 1.0
        z = z / scale
        # the jump's estimated size is r / (1 − h): a channel of high leverage shows little of its slip in r
        big = (z > sigmas) & (np.abs(r) > min_m * np.maximum(1.0 - lev, 1e-9))
        if not big.any():
            break
        hit = _largest_and_ties(ep, z, big, n_ep)
        live &= ~hit
        flagged[i[hit]] = True
    else:
        step = _td_residuals(y, w, g, grp, ep, live, n_ep)[2]
    return flagged, step


def _previous_rows(epoch, channel, n_ep: int, known) -> tuple[np.ndarray, np.ndarray]:
    """(rows i, rows j): each row i not ``known`` whose channel has a row j at the epoch before."""
    key = channel.astype(np.int64) * (n_ep + 1) + epoch
    order = np.argsort(key, kind="stable")
    pos = np.minimum(np.searchsorted(key[order], key - 1), key.size - 1)
    has_prev = (key[order][pos] == key - 1) & ~known
    return np.flatnonzero(has_prev), order[pos[has_prev]]


def _largest_and_ties(ep, z, big, n_ep) -> np.ndarray:
    """(M,) bool: each epoch's largest ``z`` among ``big``, and every other within :data:`TD_SLIP_TIE` of it: channels
    whose geometry leaves their w-tests correlated (removing either hides the other's jump; three within 2 % were
    seen) are all cut rather than the noise choosing."""
    best = np.full(n_ep, -1.0)
    np.maximum.at(best, ep[big], z[big])
    return big & (z >= TD_SLIP_TIE * best[ep])


def _td_residuals(y, w, g, grp, ep, live, n_ep):
    """Residuals (M,) of each epoch's least-squares fit of the changes ``y`` (rows ``live``) by a displacement and
    one term per group (:func:`~cdgps_cli.measurement.epoch_fit.grouped_epoch_fit`), each epoch's redundancy
    (n_ep,): changes less groups less 3 (0 where not fitted), the displacements (n_ep, 3) and each change's leverage
    (M,) (0 for rows not ``live``)."""
    wl = np.where(live, w, 0.0)
    n_grp = int(grp.max()) + 1
    grp_live = np.bincount(grp, weights=live.astype(float), minlength=n_grp) > 0
    grp_ep = np.zeros(n_grp, dtype=np.int64)
    grp_ep[grp] = ep
    redundancy = (np.bincount(ep, weights=live.astype(float), minlength=n_ep)
                  - np.bincount(grp_ep[grp_live], minlength=n_ep) - 3)
    fit = grouped_epoch_fit(y, wl, g, grp, ep, n_grp, n_ep, usable=redundancy > 0)
    r = fit.yc - np.einsum("ic,ic->i", fit.gc, fit.step[ep])
    # the hat matrix's diagonal (the group term and the displacement are orthogonal once the geometry is centred)
    leverage = wl * (1.0 / fit.group_weight[grp] + np.einsum("ia,iab,ib->i", fit.gc, fit.n_inv[ep], fit.gc))
    return r, np.where(fit.ok, redundancy, 0), fit.step, np.clip(leverage, 0.0, 1.0)
