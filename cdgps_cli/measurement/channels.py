"""Carrier-phase channels: the one lock-segment rule.

A *channel* is one continuously tracked carrier phase — (antenna, transmitter) of a pseudolite run,
(receiver pair, satellite) of a GNSS run.  Its phase carries one constant bias (an ambiguity) for
as long as the receiver keeps lock; a new bias parameter starts with every *lock segment*.
:func:`lock_segments` is the rule every part of cdgps uses to cut a channel's rows into segments:
the batch initialization's bias parameters (``cdgps init``), the filter's lock events
(``cdgps estimate``), the counts of ``cdgps ingest`` and ``cdgps info``, the GNSS double-difference
ambiguities (:func:`cdgps_cli.measurement.differencing.ambiguity_segments`) and the u-blox lock
time turned into loss-of-lock bits (:func:`ubx_restarts`).

The rule, for the rows of one channel in time order: a new segment starts

* at the channel's first row (:data:`FIRST`);
* where the receiver reports a restart (:data:`RESTART`): a loss-of-lock flag (RINEX LLI bit 0), a
  reset of every channel (e.g. RINEX epoch flag 1, power failure), or a lock indicator that did not
  continue — a lock *count* (epochs since lock) of 0 or below the previous one, a lock *time* that
  grew less than the time since the previous row (:class:`LockTime`);
* after a gap — a step of more than ``max_step`` since the channel's previous row — unless the
  lock indicator shows that lock was kept through it (a count that advanced by exactly the number
  of epochs, a lock time that grew by the gap) (:data:`REACQUIRED`; a restart after a gap is a
  re-acquisition too).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdgps_cli.core.constants import LOCK_TIME_CAP_MS
from cdgps_cli.core.gps_time import nominal_interval_s

__all__ = ["FIRST", "RESTART", "REACQUIRED", "LockTime", "LockSegments", "lock_segments", "ubx_restarts", "ubx_loss_of_lock"]

FIRST = 1          # the channel's first row
RESTART = 2        # the receiver restarted lock (flag, reset, lock indicator) without a gap
REACQUIRED = 3     # after a gap that the lock indicator does not bridge


@dataclass(frozen=True)
class LockTime:
    """A lock indicator that is the time in lock (u-blox RXM-RAWX ``locktime``), capped.

    Attributes
    ----------
    per_step : float
        Lock-time units per unit of step (1000 for a lock time in ms and steps in s).
    cap : float
        Largest lock time the receiver reports (lock-time units); at the cap it only has to stay.
    tolerance : float
        Shortfall accepted before it counts as a restart (lock-time units; e.g. half an epoch).
    """

    per_step: float
    cap: float
    tolerance: float


@dataclass
class LockSegments:
    """Result of :func:`lock_segments`, per row in the order given and per segment.

    Attributes
    ----------
    cause : ndarray (n,) int8
        0 where the row continues its segment, else :data:`FIRST`, :data:`RESTART` or :data:`REACQUIRED`.
    segment : ndarray (n,) int64
        Segment of each row, numbered by (channel, first step).
    first, last : ndarray (S,) int64
        Row index (in the order given) of each segment's first and last row.
    channel : ndarray (S,)
        Each segment's channel.
    """

    cause: np.ndarray
    segment: np.ndarray
    first: np.ndarray
    last: np.ndarray
    channel: np.ndarray

    @property
    def n_rows(self) -> np.ndarray:
        """(S,) rows of each segment."""
        return np.bincount(self.segment, minlength=self.first.size).astype(np.int64)


def lock_segments(channel, step, *, lock=None, lock_time: LockTime | None = None, slip=None,
                  max_step: float = 1.0, reset=None) -> LockSegments:
    """Cut rows into lock segments (the rule of the module docstring).

    Parameters
    ----------
    channel : array_like (n,)
        Channel of each row (any sortable key: int codes, satellite numbers).
    step : array_like (n,)
        Epoch index, or time (s), of each row; rows in any order.
    lock : array_like (n,), optional
        The receiver's lock indicator: epochs since lock (a count, ``step`` in epochs), or with
        ``lock_time`` the time in lock.  None: no indicator (every gap starts a segment).
    lock_time : LockTime, optional
        ``lock`` is a lock time (see :class:`LockTime`), not a count.
    slip : array_like (n,) bool, optional
        Loss-of-lock flag of each row (RINEX LLI bit 0).
    max_step : float, default 1
        Largest step within a segment without a lock indicator bridging it (1 epoch; for times,
        e.g. 1.5 × the epoch interval; ``inf``: gaps alone never cut).
    reset : array_like (n,) bool, optional
        Rows at which every channel restarts (e.g. the rows of a power-failure epoch).

    Returns
    -------
    LockSegments
    """
    ch = np.asarray(channel)
    st = np.asarray(step)
    n = st.size
    order = _channel_step_order(ch, st)
    c_o, s_o = ch[order], st[order]
    same = np.zeros(n, dtype=bool)
    same[1:] = c_o[1:] == c_o[:-1]
    d = np.zeros(n, dtype=st.dtype if st.dtype.kind in "if" else np.float64)
    d[1:] = s_o[1:] - s_o[:-1]
    gap = same & (d > max_step)
    restart = np.zeros(n, dtype=bool) if slip is None else np.asarray(slip, dtype=bool)[order].copy()
    if reset is not None:
        restart |= np.asarray(reset, dtype=bool)[order]
    bridged = np.zeros(n, dtype=bool)
    if lock is not None:
        ind_restart, bridged = _indicator(np.asarray(lock)[order], d, lock_time)
        restart |= ind_restart
    cause_o = np.zeros(n, dtype=np.int8)
    cause_o[same & restart & ~gap] = RESTART
    cause_o[gap & (restart | ~bridged)] = REACQUIRED
    cause_o[~same] = FIRST
    start = cause_o > 0
    seg_o = np.cumsum(start) - 1
    cause = np.empty(n, dtype=np.int8)
    cause[order] = cause_o
    segment = np.empty(n, dtype=np.int64)
    segment[order] = seg_o
    first_o = np.flatnonzero(start)
    last_o = np.append(first_o[1:], n)[:first_o.size] - 1
    return LockSegments(cause, segment, order[first_o].astype(np.int64), order[last_o].astype(np.int64), c_o[first_o])


def _channel_step_order(ch: np.ndarray, st: np.ndarray) -> np.ndarray:
    """Row order by (channel, step); rows already in that order (the usual case) are not sorted."""
    if ch.size > 1 and bool(np.all((ch[1:] > ch[:-1]) | ((ch[1:] == ch[:-1]) & (st[1:] >= st[:-1])))):
        return np.arange(ch.size)
    return np.lexsort((st, ch))


def _indicator(lk: np.ndarray, d: np.ndarray, lock_time: LockTime | None) -> tuple[np.ndarray, np.ndarray]:
    """(restart, bridged) per sorted row from the lock indicator (row 0 of a channel: ignored by the caller)."""
    prev = np.empty_like(lk)
    prev[1:] = lk[:-1]
    if len(lk):
        prev[0] = lk[0]
    if lock_time is None:                       # epochs since lock
        restart = (lk == 0) | (lk < prev)
        bridged = lk == prev + d
        return restart, bridged
    expected = np.minimum(prev + d * lock_time.per_step, lock_time.cap)
    restart = lk < expected - lock_time.tolerance
    return restart, ~restart


def ubx_restarts(sat, time_s, lock_time_ms, interval_s: float, cap_ms: float) -> np.ndarray:
    """(n,) bool: rows where a u-blox receiver's carrier lock time restarted.

    The lock time must grow by the time since the satellite's previous row (up to the cap) less half
    an epoch interval; rows may come in any order (:func:`lock_segments` with :class:`LockTime`,
    gaps alone never restart: the lock time says whether lock was kept).

    Parameters
    ----------
    sat : array_like (n,)
        Satellite of each row.
    time_s : array_like (n,)
        GPS time of each row, s.
    lock_time_ms : array_like (n,)
        RXM-RAWX lock time, ms.
    interval_s : float
        Nominal epoch interval, s (NaN: 1 s).
    cap_ms : float
        The receiver's lock-time cap, ms.
    """
    tol_ms = 0.5 * 1e3 * (interval_s if np.isfinite(interval_s) else 1.0)
    seg = lock_segments(sat, np.asarray(time_s, dtype=np.float64), lock=np.asarray(lock_time_ms, dtype=np.float64),
                        lock_time=LockTime(1e3, cap_ms, tol_ms), max_step=np.inf)
    return seg.cause == RESTART


def ubx_loss_of_lock(t, channel, phase, lock_time_ms, half, interval_s: float | None = None) -> np.ndarray:
    """Loss-of-lock bits of u-blox rows (see :func:`cdgps_cli.pipeline.gnss_ingest.processing_obs`): bit 0 where the lock time of the
    row's channel (satellite, or satellite and signal) restarted or the half-cycle ambiguity became
    resolved, bit 1 while it is unresolved; 0 on rows without a phase.

    Parameters
    ----------
    t : array_like (n,)  time tags, GPS s
    channel : array_like (n,)  satellite (or satellite-signal) of each row
    phase : array_like (n,)  carrier phase (NaN: none)
    lock_time_ms : array_like (n,)  RXM-RAWX lock times, ms
    half : array_like of bool (n,)  half-cycle ambiguity unresolved
    interval_s : float, optional  nominal epoch interval, s (default: from the tags)
    """
    t = np.asarray(t, dtype=np.float64)
    sat = np.asarray(channel)
    half = np.asarray(half, dtype=bool)
    lli = np.zeros(t.size, dtype=np.int64)
    ok = np.flatnonzero(np.isfinite(np.asarray(phase, dtype=np.float64)))
    o = ok[np.lexsort((t[ok], sat[ok]))]                 # by channel, then time
    dt_nom = interval_s if interval_s else nominal_interval_s(t)
    restart = ubx_restarts(sat[o], t[o], np.asarray(lock_time_ms, dtype=np.float64)[o], dt_nom, LOCK_TIME_CAP_MS)
    same = np.r_[False, sat[o][1:] == sat[o][:-1]]
    h_o = half[o]
    resolved_now = same & ~h_o & np.r_[False, h_o[:-1]]
    lli[o] = np.where(restart | resolved_now, 1, 0) | np.where(h_o, 2, 0)
    return lli
