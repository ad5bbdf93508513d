"""Steps of the single-difference codes that the phases do not take: a receiver clock jump in the codes alone.

A receiver whose carrier stays continuous when its clock is reset by a millisecond writes codes that step by
c · 1 ms = 299.8 km while its phases do not (session 20's adversarial case D3, the real M8P pair).  Double
differences do not see such a step, common to a signal group; what uses a row's SD code alone does: each new
ambiguity's starting value (phase − code)/λ, in the static engine's prior and in ``rtk``'s filter, put every arc
begun after the step 1.6·10⁶ cycles from those before it (the static float 0.5–1.3 m off; ``rtk`` 431 instead of
1156 fixed epochs).  :func:`code_clock_steps` finds the steps and :func:`without_code_steps` takes them out of the
rows' codes, which leaves every double difference as it was.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cdgps_cli.config.options import CODE_CLOCK_STEP_MIN_M
from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.measurement.epoch_pairing import channel_index

__all__ = ["code_clock_steps", "without_code_steps", "steps_before", "code_steps_warning"]

#: a code step is believed when at least this many arcs of the group took it …
STEP_MIN_CHANNELS = 3
#: … and two thirds of them within this of their median, m (a clock jump moves every code alike; code noise and
#: multipath differ by metres)
STEP_AGREEMENT_M = 10.0


def code_clock_steps(rows, cols=None, min_step_m: float = CODE_CLOCK_STEP_MIN_M) -> dict:
    """Steps of a signal group's SD codes that its phases do not take.

    The change of (code − phase) between consecutive rows of one arc (``cols``, (N,): each row's ambiguity column;
    without it, of one channel at consecutive epochs, the later row not flagged as a slip) is taken per signal group
    and epoch; a step is where at least :data:`STEP_MIN_CHANNELS` arcs changed, two thirds of them within
    :data:`STEP_AGREEMENT_M` of their median, and that median is at least ``min_step_m``.  Rows of a new arc (a
    slip, an outage) are not compared with the arc before: a restart's phase is not tied to its code.

    Parameters
    ----------
    rows : dict
        :func:`~cdgps_cli.measurement.dd_signals.paired_sd_rows` columns: ``ptr`` (n_ep + 1,), ``code`` (N,),
        ``sats`` (N,), ``phase_sd_m``, ``code_sd_m`` (N,) m, and ``slip`` (N,) when ``cols`` is not given.
    cols : ndarray (N,), optional
        Ambiguity column of each row.
    min_step_m : float
        Smallest step, m.

    Returns
    -------
    dict
        ``code`` (k,) signal index, ``epoch`` (k,) the first epoch after each step, ``step_m`` (k,) m; in epoch
        order.
    """
    n = rows["code"].size
    empty = {"code": np.zeros(0, np.int64), "epoch": np.zeros(0, np.int64), "step_m": np.zeros(0)}
    if n < 2:
        return empty
    epoch = np.repeat(np.arange(rows["ptr"].size - 1), np.diff(rows["ptr"]))
    if cols is None:
        chan = channel_index(rows["sats"], rows["code"])
        order = np.lexsort((epoch, chan))
        pair = (chan[order][1:] == chan[order][:-1]) & (epoch[order][1:] == epoch[order][:-1] + 1)
        if "slip" in rows:
            pair &= ~np.asarray(rows["slip"], bool)[order][1:]
    else:
        arc = np.asarray(cols)
        order = np.lexsort((epoch, arc))
        pair = arc[order][1:] == arc[order][:-1]
    d = (rows["code_sd_m"] - rows["phase_sd_m"])[order]
    later = order[1:][pair]
    change = (d[1:] - d[:-1])[pair]
    if not change.size:
        return empty
    n_code = int(rows["code"].max()) + 1
    key = epoch[later].astype(np.int64) * n_code + rows["code"][later]
    by = pd.Series(change).groupby(key)
    med, count = by.median(), by.size()
    big = (np.abs(med.to_numpy()) >= min_step_m) & (count.to_numpy() >= STEP_MIN_CHANNELS)
    if not big.any():
        return empty
    near = np.abs(change - med.reindex(key).to_numpy()) <= STEP_AGREEMENT_M
    agree = pd.Series(near).groupby(key).sum().to_numpy()
    big &= agree >= (2.0 / 3.0) * count.to_numpy()
    keys = med.index.to_numpy()[big]
    return {"code": keys % n_code, "epoch": keys // n_code, "step_m": med.to_numpy()[big]}


def steps_before(steps: dict, rows, idx) -> np.ndarray:
    """Per row of ``idx``, the sum of its signal group's code steps (:func:`code_clock_steps`) at or before its
    epoch, m."""
    out = np.zeros(np.size(idx))
    if not steps["step_m"].size:
        return out
    epoch = np.searchsorted(rows["ptr"], idx, side="right") - 1
    code = rows["code"][idx]
    for k in np.unique(steps["code"]):
        sel = steps["code"] == k
        cum = np.r_[0.0, np.cumsum(steps["step_m"][sel])]
        here = code == k
        out[here] = cum[np.searchsorted(steps["epoch"][sel], epoch[here], side="right")]
    return out


def without_code_steps(rows, cols=None) -> tuple[dict, dict]:
    """``rows`` with each row's SD code less the code steps its group took at or before its epoch, and the steps
    (:func:`code_clock_steps`); the same ``rows`` object when there is none.  Every double difference is unchanged
    (a step is common to its group)."""
    steps = code_clock_steps(rows, cols)
    if not steps["step_m"].size:
        return rows, steps
    return {**rows, "code_sd_m": rows["code_sd_m"] - steps_before(steps, rows, np.arange(rows["code"].size))}, steps


def code_steps_warning(step_m, signals, times_s, n_show: int = 4) -> list:
    """The warning naming the code steps found and taken out (empty list when there is none): each step in km and
    ms, its signal group and time."""
    where = [f"{v / 1e3:+.3f} km ({v / SPEED_OF_LIGHT_M_S * 1e3:+.4f} ms) in {sig} at {gps_time_str(float(t))}"
             for v, sig, t in zip(step_m, signals, times_s)]
    if not where:
        return []
    more = f" and {len(where) - n_show} more" if len(where) > n_show else ""
    return [f"the single-difference codes stepped while the phases did not: {', '.join(where[:n_show])}{more} (a "
            f"receiver clock jump that one receiver's codes took and its carrier did not); the double differences do "
            f"not see it, and it is taken out of the codes before any ambiguity starts from them"]
