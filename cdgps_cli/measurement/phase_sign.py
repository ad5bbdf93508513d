"""Carrier phases written with the wrong sign.

A receiver's carrier phase and its code both follow the range: a right phase in metres (λΦ) changes as the code does,
so code minus phase changes only with the ionosphere's divergence (twice its delay's rate, under 0.1 m/s), multipath
and the code's noise, whatever the range rate.  A phase written with the wrong sign changes as minus the code: code
minus phase then changes at twice the range rate (up to 1.6 km/s for a GPS satellite) and code plus phase by the
code's noise alone.  Such a phase fits no position: every double difference holding it grows by kilometres per
minute, and a float solution fed with it lands thousands of kilometres off (gnss-sdr 0.0.19 on a MAX2771 front end
wrote the phase and Doppler of some satellites of a run so, jmfriedt/max2771_fx2lp 250103; RTKLIB's outlier
rejection kept 23–42 of 251 epochs of such a pair, 26 m off).

:func:`reversed_phase_channels` finds those channels from the two rates' medians over pairs of epochs at least a
second apart (a clock jump in the code, a slip in the phase, is one pair of hundreds); :func:`without_reversed_phases`
takes them out of a receiver's signal table, with a warning that names them and gives the two rates.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.measurement.slips import table_channels
from cdgps_cli.config.options import (REVERSED_PHASE_LAG_S, REVERSED_PHASE_MIN_PAIRS, REVERSED_PHASE_MIN_RATE_M_S,
                                      REVERSED_PHASE_RATIO)

__all__ = ["reversed_phase_channels", "without_reversed_phases", "without_reversed_l1_phases"]


def reversed_phase_channels(channel, time_s, phase_m, code_m, *, lag_s: float = REVERSED_PHASE_LAG_S,
                            min_pairs: int = REVERSED_PHASE_MIN_PAIRS,
                            min_rate_m_s: float = REVERSED_PHASE_MIN_RATE_M_S,
                            ratio: float = REVERSED_PHASE_RATIO) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Channels whose carrier phase runs opposite to their code.

    Each row is paired with its channel's first row at least ``lag_s`` later; over a channel's pairs, u = Δ(code −
    phase)/Δt and v = Δ(code + phase)/Δt.  A right channel's u is the receiver's common code–carrier drift D (0 for a
    sound receiver; gnss-sdr has written records whose code and phase part at a rate common to every channel) and its
    v twice its range rate; a reversed channel's v is D and its u twice its range rate.  D is the value that the
    most channels' median u or median v lie within ``min_rate_m_s`` of (0 when that is within ``min_rate_m_s`` of 0):
    it needs no majority of right channels.  A channel of at least ``min_pairs`` pairs is reversed when the median of
    |u − D| exceeds ``min_rate_m_s`` and the median of |v − D| is below ``ratio`` times it
    (:data:`~cdgps_cli.config.options.REVERSED_PHASE_LAG_S` and the others).  Channel by channel: the memory beyond
    the sort is one channel's.

    Parameters
    ----------
    channel : ndarray of int (N,)
        Channel (satellite and signal) of each row, one row per epoch.
    time_s : ndarray (N,)
        The rows' epoch times, s.
    phase_m, code_m : ndarray (N,)
        Carrier phase × wavelength and pseudorange, m (NaN: none).
    lag_s, min_pairs, min_rate_m_s, ratio : float, int, float, float
        See above.

    Returns
    -------
    rows : ndarray of bool (N,)
        The rows of the reversed channels.
    minus_rate_m_s, plus_rate_m_s : ndarray (N,)
        Each row's channel's median |u − D| and |v − D|, m/s (NaN: too few pairs).
    """
    channel = np.asarray(channel, dtype=np.int64)
    t, phase, code = (np.asarray(a, dtype=np.float64) for a in (time_s, phase_m, code_m))
    n = channel.size
    minus_rate, plus_rate = np.full(n, np.nan), np.full(n, np.nan)
    rows = np.flatnonzero(np.isfinite(t) & np.isfinite(phase) & np.isfinite(code))
    if rows.size == 0:
        return np.zeros(n, dtype=bool), minus_rate, plus_rate
    rows = rows[np.lexsort((t[rows], channel[rows]))]
    cuts = np.flatnonzero(np.diff(channel[rows])) + 1
    arcs = [a for a in np.split(rows, cuts) if a.size > min_pairs]

    def rates(arc):                    # (u, v) of one channel's pairs, m/s
        tt = t[arc]
        later = np.searchsorted(tt, tt + lag_s)
        i = np.flatnonzero(later < arc.size)
        j = later[i]
        dt = tt[j] - tt[i]
        cm, cp = code[arc] - phase[arc], code[arc] + phase[arc]
        return (cm[j] - cm[i]) / dt, (cp[j] - cp[i]) / dt

    kept, centres, about_0 = [], [], []
    for arc in arcs:
        u, v = rates(arc)
        if u.size >= min_pairs:
            kept.append(arc)
            centres.append((float(np.median(u)), float(np.median(v))))
            about_0.append((np.median(np.abs(u)), np.median(np.abs(v))))
    drift = _common_drift(np.array(centres).reshape(-1, 2), min_rate_m_s)
    for arc, at_0 in zip(kept, about_0):
        if drift == 0.0:                    # (a sound receiver: the rates about 0, from the pass above)
            minus_rate[arc], plus_rate[arc] = at_0
        else:
            u, v = rates(arc)
            minus_rate[arc], plus_rate[arc] = np.median(np.abs(u - drift)), np.median(np.abs(v - drift))
    with np.errstate(invalid="ignore"):
        bad = (minus_rate > min_rate_m_s) & (plus_rate < ratio * minus_rate)
    return bad, minus_rate, plus_rate


def _common_drift(centres: np.ndarray, tol: float) -> float:
    """The receiver's common code–carrier drift D, m/s, from each channel's (median u, median v) (K, 2): the value
    that the most channels hold within ``tol`` in u or in v (ties: the smallest |D|); 0 when that is within ``tol``
    of 0 or there is no channel."""
    if centres.size == 0:
        return 0.0
    candidates = centres.ravel()
    near = np.minimum(np.abs(centres[None, :, 0] - candidates[:, None]),
                      np.abs(centres[None, :, 1] - candidates[:, None])) < tol
    score = near.sum(axis=1)
    best = candidates[score == score.max()]
    d = float(best[np.argmin(np.abs(best))])
    return 0.0 if abs(d) < tol else d


def without_reversed_phases(table, where: str):
    """A receiver's signal table (``time_gps_s``, ``sat``, ``signal``, ``phase_cycles``, ``pseudorange_m``,
    ``wavelength_m`` per row) less the rows of its channels whose phase runs opposite to their code
    (:func:`reversed_phase_channels`), and the warnings naming them (``where``: the receiver, e.g. "rover.obs
    (rover)"; [] when none).  (Single-point positions take the codes of the table given, before this screen.)"""
    if table is None or table.empty:
        return table, []
    phase_m = table["phase_cycles"].to_numpy(dtype=np.float64) * table["wavelength_m"].to_numpy(dtype=np.float64)
    bad, minus, plus = reversed_phase_channels(table_channels(table), table["time_gps_s"].to_numpy(),
                                               phase_m, table["pseudorange_m"].to_numpy(dtype=np.float64))
    if not bad.any():
        return table, []
    said = _said(where, table["signal"].to_numpy()[bad], table["sat"].to_numpy()[bad], minus[bad], plus[bad],
                 "are not used")
    return table[~bad].reset_index(drop=True), [said]


def without_reversed_l1_phases(obs, where: str):
    """A receiver's GPS L1 table (``time_gps_s``, ``sat``, ``phase_l1_cycles``, ``pseudorange_l1_m`` per row, as
    :func:`~cdgps_cli.io.rinex.read_rinex_obs` reads it) with the phase of its GPS channels whose phase runs opposite
    to their code set to NaN (their codes kept), and the warnings naming them ([] when none)."""
    if obs is None or obs.empty:
        return obs, []
    sats = obs["sat"].to_numpy().astype(str)
    gps = np.char.startswith(sats, "G")
    if not gps.any():
        return obs, []
    phase_m = obs["phase_l1_cycles"].to_numpy(dtype=np.float64) * GPS_L1_WAVELENGTH_M
    code_m = obs["pseudorange_l1_m"].to_numpy(dtype=np.float64)
    channel = np.unique(sats, return_inverse=True)[1].ravel()
    bad, minus, plus = reversed_phase_channels(channel, obs["time_gps_s"].to_numpy(),
                                               np.where(gps, phase_m, np.nan), code_m)
    if not bad.any():
        return obs, []
    said = _said(where, np.full(int(bad.sum()), "G:L1"), sats[bad], minus[bad], plus[bad],
                 "are not used (their codes are)")
    out = obs.copy()
    out.loc[bad, "phase_l1_cycles"] = np.nan
    return out, [said]


def _said(where: str, signals, sats, minus, plus, what: str) -> str:
    """The warning naming the channels of reversed phase (one entry per channel, its two median rates)."""
    seen = {}
    for sig, sat, m, p in zip(signals, sats, minus, plus):
        seen.setdefault((str(sig), str(sat)), (float(m), float(p)))
    return (f"{where}: " + ", ".join(f"{s} {n} ({m:.0f} / {p:.1f} m/s)" for (s, n), (m, p) in sorted(seen.items()))
            + ": their carrier phase runs opposite to their code (in brackets, the median rates of code minus phase "
            f"and of code plus phase): the receiver wrote it with the wrong sign; their phases fit no position and {what}")
