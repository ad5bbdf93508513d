"""Pairing a base receiver's epochs with a rover's, as real receivers write them.

The rover's epochs drive the solution: every distinct rover epoch is either paired with one base
epoch or dropped with a stated reason, so nothing is lost silently.  A rover epoch tagged ``t``
takes the base epoch nearest to it in time (the earlier on a tie):

* **simultaneous** when ``|t − t_b| ≤ sync_tol_s`` — the millisecond differences of receivers that
  steer their clocks differently (u-blox tags at .990/.991 s against .991/.992 s; GEONET tags at
  hh:mm:ss.999 against whole seconds);
* **bridged** when ``sync_tol_s < |t − t_b| ≤ max_age_s`` — a base that logs with gaps, or at a
  lower rate (a 1 s or 5 s base under a 10 Hz rover).  The solvers model each receiver's ranges,
  satellite clocks and troposphere at that receiver's own reception instant, so the receiver clocks
  still cancel in the double difference and the satellites' motion over the age is modelled
  exactly; the base's observation minus that model is interpolated to the rover's time between the
  base epochs on both sides where that is safe (:mod:`cdgps_cli.measurement.base_interpolation`),
  else the nearest epoch's is used as recorded.  What is not modelled (the drift of the broadcast
  satellite clock, the atmosphere's change) grows with the age, and the single difference's σ grows
  with it: ``σ_age = age_sigma_m_per_s × |age|`` (RTKLIB's satellite-clock-stability term, same
  default; the age of an interpolated row is |age|(1 − w)).  This is how RTKLIB processes a base with a
  differential age (``rtkpos.c``), here in both time directions because the whole record is there;
* **dropped** otherwise: the rover epoch lies before the base's first epoch, after its last, or
  inside a base gap longer than twice ``max_age_s``; a repeated rover time tag (the same epoch
  written twice) is dropped as a duplicate.

:func:`pair_epochs` returns the pairing and a summary whose counts add up to the rover's epochs;
:func:`carry_base_slips` moves the loss-of-lock flags of base epochs that are not used (or used for
a second rover epoch) to the next use of that satellite, so a slip of the base is seen exactly once.

References: RTKLIB ``rtkpos.c`` (differential age, ``maxtdiff``), ``postpos.c`` (``DTTOL``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pandas as pd

from cdgps_cli.config.options import EPOCH_PAIRING_DEFAULTS

__all__ = ["EpochPairs", "pair_epochs", "age_variance_m2", "carry_base_slips", "rows_for_pairs", "DROP_REASONS",
           "channel_index", "NO_DD", "without_dd"]

#: why a rover epoch is not used, in the order the summary lists them
DROP_REASONS = ("duplicate rover epoch", "before the first base epoch", "after the last base epoch",
                "in a base gap (no base epoch within the maximum age)")


#: why a paired rover epoch has no solution: the filter only predicted through it (its position would be the
#: neighbours' interpolated, labelled float; RTKLIB writes no line for such an epoch either), and a batch has no row
#: of it (every GNSS command counts it so: rtk, baseline, init)
NO_DD = ("without a double difference (fewer than two satellites of one signal with a carrier phase at both "
         "receivers above the mask)")


def without_dd(summary: dict, n: int) -> dict:
    """A pairing summary (:func:`pair_epochs`) with ``n`` of its used epochs that held no double difference moved
    from ``used`` into ``dropped`` under :data:`NO_DD` (the same summary when ``n`` is 0)."""
    if n <= 0:
        return summary
    return {**summary, "used": summary["used"] - n, "dropped": {**summary["dropped"], NO_DD: n}}


class EpochPairs(NamedTuple):
    """A rover–base epoch pairing (:func:`pair_epochs`)."""

    rover_time_s: np.ndarray   # (n,) time tags of the used rover epochs, increasing, GPS s
    rover_index: np.ndarray    # (n,) index of each used epoch among the rover's distinct time tags
    base_index: np.ndarray     # (n,) index of its base epoch among the base's distinct time tags
    age_s: np.ndarray          # (n,) rover time − base time, s (negative: the base epoch is later)
    summary: dict              # counts and limits (see pair_epochs)


def _check(name: str, value: float, low: float = 0.0) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > low):
        raise ValueError(f"{name}: expected a finite number > {low:g} s, got {value!r}")
    return v


def pair_epochs(rover_time_s, base_time_s, *, sync_tol_s: float = EPOCH_PAIRING_DEFAULTS["sync_tol_s"],
                max_age_s: float = EPOCH_PAIRING_DEFAULTS["max_age_s"]) -> EpochPairs:
    """Pair every rover epoch with the nearest base epoch within ``max_age_s``.

    Parameters
    ----------
    rover_time_s, base_time_s : array_like, shape (N,), (M,)
        Time tags (GPS s) of each receiver's epochs, or of its observation rows (repeated tags are
        one epoch); any order.
    sync_tol_s : float
        Largest |rover − base| time-tag difference counted as simultaneous, s (> 0).
    max_age_s : float
        Largest |rover − base| time-tag difference bridged, s (≥ ``sync_tol_s``).

    Returns
    -------
    EpochPairs
        ``summary``: ``rover_epochs`` (distinct rover tags), ``base_epochs``, ``used`` (=
        ``simultaneous`` + ``bridged``), ``dropped`` ({reason: count}, reasons of
        :data:`DROP_REASONS` with a non-zero count; ``used`` + the counts = ``rover_epochs``),
        ``base_epochs_used``, ``max_age_s`` (largest |age| used, s; 0 when none is bridged),
        ``sync_tol_s``, ``max_age_limit_s``.  ``duplicate rover epoch`` counts rover tags closer
        than 1 µs to the previous one (tags are first made distinct with :func:`numpy.unique`,
        so exact repeats never reach the count; they are the caller's rows to drop).

    Raises
    ------
    ValueError
        A limit is not a positive finite number, or ``max_age_s < sync_tol_s``.
    """
    tol = _check("sync_tol_s", sync_tol_s)
    age_max = _check("max_age_s", max_age_s)
    if age_max < tol:
        raise ValueError(f"max_age_s: expected ≥ sync_tol_s ({tol:g} s), got {max_age_s!r}")
    tr = np.unique(np.asarray(rover_time_s, dtype=np.float64))
    tb = np.unique(np.asarray(base_time_s, dtype=np.float64))
    tr, tb = tr[np.isfinite(tr)], tb[np.isfinite(tb)]
    dup = np.r_[False, np.diff(tr) < 1e-6]
    reasons = dict.fromkeys(DROP_REASONS, 0)
    reasons["duplicate rover epoch"] = int(dup.sum())
    if tb.size == 0:
        k_near = np.zeros(tr.size, dtype=np.int64)
        age = np.full(tr.size, np.inf)
    else:
        k = np.searchsorted(tb, tr)
        before = np.clip(k - 1, 0, tb.size - 1)
        after = np.clip(k, 0, tb.size - 1)
        d_before, d_after = np.abs(tr - tb[before]), np.abs(tb[after] - tr)
        k_near = np.where(d_before <= d_after, before, after)
        age = tr - tb[k_near]
    ok = ~dup & (np.abs(age) <= age_max)
    lost = ~dup & ~ok
    if tb.size:
        reasons["before the first base epoch"] = int((lost & (tr < tb[0])).sum())
        reasons["after the last base epoch"] = int((lost & (tr > tb[-1])).sum())
        reasons["in a base gap (no base epoch within the maximum age)"] = int((lost & (tr >= tb[0]) & (tr <= tb[-1])).sum())
    else:
        reasons["after the last base epoch"] = int(lost.sum())
    idx = np.flatnonzero(ok)
    a = age[idx]
    simultaneous = np.abs(a) <= tol
    summary = {
        "rover_epochs": int(tr.size), "base_epochs": int(tb.size), "used": int(idx.size),
        "simultaneous": int(simultaneous.sum()), "bridged": int((~simultaneous).sum()),
        "dropped": {r: n for r, n in reasons.items() if n},
        "base_epochs_used": int(np.unique(k_near[idx]).size),
        "max_age_s": float(np.max(np.abs(a), initial=0.0)) if (~simultaneous).any() else 0.0,
        "sync_tol_s": tol, "max_age_limit_s": age_max,
    }
    return EpochPairs(tr[idx], idx.astype(np.int64), k_near[idx].astype(np.int64), a, summary)


def age_variance_m2(age_s, sync_tol_s: float = EPOCH_PAIRING_DEFAULTS["sync_tol_s"],
                    age_sigma_m_per_s: float = EPOCH_PAIRING_DEFAULTS["age_sigma_m_per_s"]) -> np.ndarray:
    """Variance an SD observation gains from its base age, m²: ``(age_sigma_m_per_s × |age|)²``,
    zero for simultaneous epochs (|age| ≤ ``sync_tol_s``)."""
    a = np.abs(np.asarray(age_s, dtype=np.float64))
    return np.where(a <= sync_tol_s, 0.0, (age_sigma_m_per_s * a) ** 2)


def carry_base_slips(base_epoch, key, lli, use_count) -> np.ndarray:
    """Base loss-of-lock flags as the paired rows must see them: once per slip.

    Parameters
    ----------
    base_epoch : array_like of int, shape (N,)
        Index of each base row's epoch (increasing in time).
    key : array_like, shape (N,)
        The row's channel (satellite, or satellite and signal): flags move along one channel only.
    lli : array_like of int, shape (N,)
        Loss-of-lock indicator of each base row (bit 0: a new ambiguity from this row on).
    use_count : array_like of int, shape (M,)
        How many rover epochs use each base epoch (0: not used).

    Returns
    -------
    ndarray of int64, shape (N,)
        LLI of the rows, with bit 0 of a row whose epoch is not used moved to the channel's next row
        in a used epoch.  A base epoch used by several rover epochs keeps its flag; the caller
        applies it at the first of them only (the pairs are increasing in time).
    """
    ep = np.asarray(base_epoch, dtype=np.int64)
    out = np.asarray(lli, dtype=np.int64).copy()
    if out.size == 0:
        return out
    used = np.asarray(use_count)[ep] > 0
    if used.all():
        return out
    _, ch = np.unique(np.asarray(key).astype(str), return_inverse=True)
    order = np.lexsort((ep, ch.reshape(-1)))
    ch_o, used_o, res = ch.reshape(-1)[order], used[order], out[order]
    kept = np.flatnonzero(used_o)
    src = np.flatnonzero(~used_o & ((res & 1) == 1))
    if kept.size and src.size:
        pos = np.searchsorted(kept, src)
        ok = pos < kept.size
        dst = kept[np.minimum(pos, kept.size - 1)]
        ok &= ch_o[dst] == ch_o[src]
        res[dst[ok]] |= 1
    out[order] = res
    return out


def rows_for_pairs(row_epoch, pair_epoch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of one receiver as each pair needs them: a base epoch serving several rover epochs
    gives its rows to each.

    Parameters
    ----------
    row_epoch : array_like of int, shape (N,)
        The receiver epoch of each row (index among its distinct epochs).
    pair_epoch : array_like of int, shape (n,)
        The receiver epoch of each pair (:attr:`EpochPairs.base_index` or ``rover_index``),
        non-decreasing.

    Returns
    -------
    take : ndarray of int64, shape (M,)
        Row of each copy (rows of epochs no pair uses are left out).
    pair : ndarray of int64, shape (M,)
        The pair each copy belongs to.
    first : ndarray of bool, shape (M,)
        True for the copy in the first pair that uses the row's epoch (where its slip flags belong).
    """
    pe = np.asarray(pair_epoch, dtype=np.int64)
    re = np.asarray(row_epoch, dtype=np.int64)
    if pe.size > 1 and np.any(np.diff(pe) < 0):
        raise ValueError("pair_epoch: expected non-decreasing receiver epochs (pairs in time order)")
    start = np.searchsorted(pe, re, side="left")
    count = np.searchsorted(pe, re, side="right") - start
    take = np.repeat(np.arange(re.size, dtype=np.int64), count)
    offset = np.arange(take.size, dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
    return take, np.repeat(start, count) + offset, offset == 0


def nearest_tags(tags_s: np.ndarray, t_s: np.ndarray, tol_s: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """For each time ``t_s`` the index of the nearest of the sorted ``tags_s`` (ties: the earlier) and whether it
    is within ``tol_s`` — a row belongs to the epoch whose time tag is its own (GPS s; one tag: index 0)."""
    tags = np.asarray(tags_s, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    if tags.size == 0:
        return np.zeros(t.size, dtype=np.int64), np.zeros(t.size, dtype=bool)
    if tags.size == 1:
        i = np.zeros(t.size, dtype=np.int64)
    else:
        i = np.clip(np.searchsorted(tags, t), 1, tags.size - 1)
        i = np.where(np.abs(tags[i - 1] - t) <= np.abs(tags[i] - t), i - 1, i)
    return i, np.abs(tags[i] - t) <= tol_s


def channel_index(sats, code) -> np.ndarray:
    """Channel (N,) of each row: the index of its key ``str(sat) + str(code)`` among the sorted distinct keys
    (what ``np.unique(np.char.add(sats.astype(str), code.astype(str)), return_inverse=True)[1]`` gives), with
    the strings formed for the distinct (satellite, code) pairs only.  ``code`` (N,): ints or strings (e.g.
    signal names)."""
    sats, code = np.asarray(sats).ravel(), np.asarray(code).ravel()
    if sats.size == 0:
        return np.zeros(0, dtype=np.int64)
    s_id, s_names = pd.factorize(sats)
    c_id, c_names = pd.factorize(code)
    n_c = len(c_names)
    pair, inv = np.unique(s_id.astype(np.int64) * n_c + c_id, return_inverse=True)
    keys = np.char.add(np.asarray(s_names)[pair // n_c].astype(str), np.asarray(c_names)[pair % n_c].astype(str))
    return np.unique(keys, return_inverse=True)[1].ravel()[inv.ravel()].astype(np.int64)
